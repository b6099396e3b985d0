"""Materials of the hard benchmark scenes: every reflectance collection colour-science ships,
mixed non-linearly, plus metamer pairs and a sharp-peaked LED.

A scene's materials start from the measured or published reflectances that colour-science
ships (:func:`reflectance_collections`): the ColorCheckers (BabelColor average, N Ohta,
ISO 17321-1), the CIE test colour samples (CIE 1995 and 2024), the NIST CQS samples (7.4 and
9.0), the Otsu et al. (2018) cluster means, Smits' (1999) basis spectra and the 190 RAW to
ACES training reflectances. Real materials are not linear mixtures of these: dyes and inks
mix subtractively (transmittances multiply), dyes have narrow absorption bands, thin films
interfere. :func:`material_library` draws materials with such effects, so that the scene's
spectra do not all lie in a low-dimensional subspace of the collections
(:func:`subspace_basis`).

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 5 and 6 (metamers, highlights).
.. [2] Otsu, H., Yamamoto, M., Hachisuka, T. (2018). Reproducing Spectral Reflectances From
   Tristimulus Colours. Computer Graphics Forum 37(6).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import numpy.typing as npt

__all__ = [
    "COLLECTIONS",
    "reflectance_collections",
    "all_reflectances",
    "material_library",
    "metameric_pair",
    "sharp_led",
    "subspace_basis",
]

COLLECTIONS: tuple[str, ...] = (
    "colourchecker:BabelColor Average",
    "colourchecker:ColorChecker N Ohta",
    "colourchecker:ISO 17321-1",
    "tcs:CIE 1995",
    "tcs:CIE 2024",
    "cqs:NIST CQS 7.4",
    "cqs:NIST CQS 9.0",
    "otsu2018:cluster means",
    "smits1999",
    "rawtoaces:training",
)
"""Every reflectance collection the scenes draw from (``kind:key``)."""


def _resample(grid: np.ndarray, values: np.ndarray, wavelength: np.ndarray) -> np.ndarray:
    """``values`` (n, len(grid)) linearly interpolated onto ``wavelength`` (held at the ends)."""
    return np.stack([np.interp(wavelength, grid, v) for v in values])


def _sds(sds, wavelength: np.ndarray) -> np.ndarray:
    rows = []
    for sd in sds:
        grid = np.asarray(sd.wavelengths, dtype=np.float64)
        rows.append(np.interp(wavelength, grid, np.asarray(sd.values, dtype=np.float64)))
    return np.stack(rows)


@lru_cache(maxsize=8)
def _collections(wavelength: tuple[float, ...]) -> dict[str, np.ndarray]:
    import colour
    from colour.quality.datasets import SDS_TCS, SDS_VS
    from colour.recovery.datasets.otsu2018 import CLUSTER_MEANS_OTSU2018, SPECTRAL_SHAPE_OTSU2018

    wl = np.asarray(wavelength, dtype=np.float64)
    out: dict[str, np.ndarray] = {}
    for name in COLLECTIONS:
        kind, _, key = name.partition(":")
        if kind == "colourchecker":
            values = _sds(colour.SDS_COLOURCHECKERS[key].values(), wl)
        elif kind == "tcs":
            values = _sds(SDS_TCS[key].values(), wl)
        elif kind == "cqs":
            values = _sds(SDS_VS[key].values(), wl)
        elif kind == "otsu2018":
            grid = np.asarray(SPECTRAL_SHAPE_OTSU2018.wavelengths, dtype=np.float64)
            values = _resample(grid, np.asarray(CLUSTER_MEANS_OTSU2018), wl)
        elif kind == "smits1999":
            values = _sds(colour.recovery.SDS_SMITS1999.values(), wl)
        else:
            data = colour.characterisation.read_training_data_rawtoaces_v1()
            grid = np.asarray(data.wavelengths, dtype=np.float64)
            values = _resample(grid, np.asarray(data.values, dtype=np.float64).T, wl)
        out[name] = np.clip(values, 0.0, 1.0)
    return out


def reflectance_collections(wavelength: npt.ArrayLike) -> dict[str, np.ndarray]:
    """Every collection of :data:`COLLECTIONS` on ``wavelength``: name -> (n, n_wavelength)."""
    wl = tuple(float(v) for v in np.asarray(wavelength, dtype=np.float64).ravel())
    return {name: values.copy() for name, values in _collections(wl).items()}


def all_reflectances(wavelength: npt.ArrayLike) -> np.ndarray:
    """All reflectances of all collections stacked, ``(n, n_wavelength)``."""
    return np.concatenate(list(reflectance_collections(wavelength).values()))


def subspace_basis(wavelength: npt.ArrayLike, illuminant: npt.ArrayLike, rank: int = 8) -> np.ndarray:
    """Orthonormal ``(rank, n_wavelength)`` basis of the best ``rank``-dimensional subspace
    of the shipped reflectances lit by ``illuminant`` (radiance space, by SVD)."""
    radiance = all_reflectances(wavelength) * np.asarray(illuminant, dtype=np.float64)[None]
    _, _, vt = np.linalg.svd(radiance, full_matrices=False)
    return vt[:rank]


def _smooth_noise(rng: np.random.Generator, wavelength: np.ndarray, width: float) -> np.ndarray:
    """A random smooth function of wavelength (sum of Gaussians of ``width`` nm), in [-1, 1]."""
    centres = rng.uniform(wavelength[0] - 20, wavelength[-1] + 20, size=8)
    heights = rng.normal(size=8)
    f = np.sum(heights[:, None] * np.exp(-0.5 * ((wavelength[None] - centres[:, None]) / width) ** 2), 0)
    return f / max(float(np.abs(f).max()), 1e-12)


def material_library(
    wavelength: npt.ArrayLike, n_materials: int, rng: np.random.Generator
) -> tuple[np.ndarray, list[str]]:
    """``n_materials`` reflectances drawn from every collection, with real-material effects.

    Every material starts from a reflectance of a collection (collections taken in turn, so
    all of them appear) and gets, at random, one or more of: a subtractive mixture with a
    second reflectance (``rho_1 ** a * rho_2 ** b``: dyes and inks multiply), a narrow dye
    absorption band (Gaussian in optical density, 8-20 nm wide; always, when no mixture was
    drawn), a thin-film interference
    modulation (``1 + m cos(4 pi n d / lambda)``) or a fluorescent-brightener-like blue
    excess. Clipped to [0.005, 0.98].

    Returns
    -------
    (numpy.ndarray, list of str)
        ``(n_materials, n_wavelength)`` reflectances and a description per material.
    """
    wl = np.asarray(wavelength, dtype=np.float64)
    collections = reflectance_collections(wl)
    names = list(collections)
    pool = np.concatenate(list(collections.values()))
    out = np.empty((n_materials, wl.size))
    notes: list[str] = []
    for j in range(n_materials):
        source = names[j % len(names)]
        rows = collections[source]
        rho = rows[rng.integers(len(rows))].copy()
        note = [source]
        if rng.random() < 0.7:
            other = pool[rng.integers(len(pool))]
            a, b = rng.uniform(0.6, 1.5, size=2)
            rho = np.clip(rho, 1e-3, 1) ** a * np.clip(other, 1e-3, 1) ** b
            rho = rho / max(float(rho.max()), 1e-6) * rng.uniform(0.4, 0.95)
            note.append("subtractive mix")
        if rng.random() < 0.6 or len(note) == 1:
            centre, width = rng.uniform(430, 690), rng.uniform(8, 20)
            density = rng.uniform(0.8, 2.5) * np.exp(-0.5 * ((wl - centre) / width) ** 2)
            rho = rho * 10.0**-density
            note.append(f"dye band {centre:.0f} nm")
        if rng.random() < 0.3:
            thickness = rng.uniform(300, 900)  # optical path n d in nm
            rho = rho * (1 + rng.uniform(0.3, 0.6) * np.cos(4 * np.pi * thickness / wl))
            note.append("thin film")
        if rng.random() < 0.15:
            rho = rho + rng.uniform(0.1, 0.3) * np.exp(-0.5 * ((wl - 440) / 15) ** 2)
            note.append("brightener")
        if rng.random() < 0.8:
            rho = rho * (1 + rng.uniform(0.2, 0.5) * _smooth_noise(rng, wl, 12.0))
            note.append("ripple")
        out[j] = np.clip(rho, 0.005, 0.98)
        notes.append(", ".join(note))
    return out, notes


def metameric_pair(
    reflectance: npt.ArrayLike,
    camera_matrix: npt.ArrayLike,
    illuminant: npt.ArrayLike,
    rng: np.random.Generator,
    *,
    strength: float = 0.25,
) -> np.ndarray:
    """A metamer of ``reflectance`` for the camera under ``illuminant``.

    ``rho + t b`` with ``b`` a smooth metameric black: a random smooth spectrum projected
    onto the null space of ``C diag(L)``, so both have the same camera RGB; ``t`` is the
    largest step up to ``strength`` (of the spectrum's maximum) that keeps the metamer in
    [0.005, 0.98].
    """
    rho = np.asarray(reflectance, dtype=np.float64)
    m = np.asarray(camera_matrix, dtype=np.float64) * np.asarray(illuminant, dtype=np.float64)[None]
    wl = np.arange(rho.size, dtype=np.float64) * 10.0
    black = _smooth_noise(rng, wl, 25.0)
    black = black - np.linalg.pinv(m) @ (m @ black)
    black /= max(float(np.abs(black).max()), 1e-12)
    room = np.where(
        black > 0, (0.98 - rho) / np.maximum(black, 1e-12), (rho - 0.005) / np.maximum(-black, 1e-12)
    )
    t = min(strength * float(rho.max()), float(room.min()))
    return rho + max(t, 0.0) * black


def sharp_led(wavelength: npt.ArrayLike) -> np.ndarray:
    """A white LED with a narrow blue peak, normalised to max 1.

    A 450 nm pump of 18 nm FWHM and a broad phosphor hump (560 nm, 110 nm FWHM, 0.45 of the
    peak): almost no light below 425 nm or above 690 nm, like the gantry's LEDs.
    """
    wl = np.asarray(wavelength, dtype=np.float64)
    fwhm = 2 * np.sqrt(2 * np.log(2))
    pump = np.exp(-0.5 * ((wl - 450.0) / (18.0 / fwhm)) ** 2)
    phosphor = 0.45 * np.exp(-0.5 * ((wl - 565.0) / (110.0 / fwhm)) ** 2)
    spd = pump + phosphor + 0.0003
    return spd / spd.max()
