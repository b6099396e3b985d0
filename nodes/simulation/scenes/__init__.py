"""Hard benchmark scenes: many real materials mixed below a pixel, dim, noisy, glossy.

One module per scene family, each returning a
:class:`~spectralize.nodes.simulation.scenes.layout.SceneLayout`; :data:`SCENES` lists them
and :func:`get_scene` renders and captures one, as a single image with all band shots or as
a BTF-like set of 20 rectified images (10 at the spectral camera's 45 deg view with the 32
band shots spread over them, 10 from other views without any).

What makes them hard (the properties :func:`scene_properties` measures):

- materials from every reflectance collection colour-science ships, mixed subtractively,
  with dye bands and thin films (:mod:`.materials`), so the truth does not lie in a
  low-dimensional subspace (the best 8-dimensional basis of the collections leaves a
  per-pixel nRMSE p95 above 0.1);
- materials mixed at sub-pixel scale (yarns, print dots, grain);
- large dark regions, a low mean intensity, highlights in a sharp-peaked LED's spectrum;
- metamer pairs (same camera RGB) placed apart;
- band signal of a few DN: per-pixel band SNR at or below 1;
- in a set, light and view change each texel's brightness by factors of several.

The layout is fixed per scene (``layout_seed``); ``seed`` draws the capture noise.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 5 and 6.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from ..camera_model import SimulationParameterError, camera_sensitivities, spectral_quantum_efficiency
from ..ground_truth import WAVELENGTHS
from .capture import READ_NOISE_DN, band_plan, capture_bands, capture_rgb
from .dark_still_life import dark_still_life
from .glossy_mosaic import glossy_mosaic
from .halftone_print import halftone_print
from .layout import SceneLayout, render_layout
from .materials import sharp_led, subspace_basis
from .woven_fabric import woven_fabric

__all__ = [
    "SCENES",
    "SceneFamily",
    "SceneCapture",
    "get_scene",
    "set_geometry",
    "subspace_residual",
    "scene_properties",
    "SINGLE_VIEW",
]

SINGLE_VIEW = {"theta_i": 40.0, "phi_i": 160.0, "theta_o": 45.0, "phi_o": 0.0}
"""Light and view of the single image (and of a set's reference image): near the mirror
direction, so highlights appear."""


@dataclass(frozen=True)
class SceneFamily:
    """One entry of :data:`SCENES`."""

    name: str
    build: Callable[..., SceneLayout]
    description: str


SCENES: dict[str, SceneFamily] = {
    f.name: f
    for f in (
        SceneFamily("woven-fabric", woven_fabric, "tartan of dyed yarns ~2 px apart, fold shadow"),
        SceneFamily("halftone-print", halftone_print, "6-ink halftone below a pixel, rich black"),
        SceneFamily("glossy-mosaic", glossy_mosaic, "grained glossy tiles, grout, deep shadow"),
        SceneFamily("dark-still-life", dark_still_life, "glossy beads on black velvet, vignetting"),
    )
}
"""Every hard scene by name."""


@dataclass
class SceneCapture:
    """A captured hard scene and its truth, in the form the reconstruction API takes."""

    rgb: xr.DataArray  # (image, y, x, channel)
    bands: xr.DataArray  # (shot, y, x): coords wavelength, image, filter_size, exposure_time
    camera_matrix: xr.DataArray  # (channel, wavelength)
    truth: xr.DataArray  # (image, wavelength, y, x)
    plan: xr.Dataset
    layout: SceneLayout
    band_signal_dn: np.ndarray = field(repr=False)  # (shot, y, x) noiseless band signal
    properties: dict = field(default_factory=dict)

    @property
    def images_with_bands(self) -> np.ndarray:
        """Indices of the images that have band shots."""
        return np.unique(self.bands["image"].values)


def set_geometry(n_images: int, images_with_bands: int) -> list[dict]:
    """Light and view of every image of a set (degrees, and a light intensity).

    The first ``images_with_bands`` are seen from the spectral camera's 45 deg view under
    LEDs at elevations 10-75 deg round the hemisphere (image 0 is :data:`SINGLE_VIEW`); the
    rest from the other cameras (0 .. 75 deg) under similar LEDs. LED intensity at the
    sample varies 0.6-1.4 (distance): with grazing light a texel's brightness changes by
    factors of several.
    """
    out = []
    elevations = (40.0, 15.0, 60.0, 30.0, 75.0, 10.0, 50.0, 65.0, 25.0, 70.0)
    views = (0.0, 15.0, 30.0, 60.0, 75.0)
    for m in range(n_images):
        if m == 0:
            out.append({**SINGLE_VIEW, "intensity": 1.0})
            continue
        j = m % len(elevations)
        theta_o = 45.0 if m < images_with_bands else views[m % len(views)]
        phi_o = 0.0 if m < images_with_bands else 180.0 * (m % 2)
        out.append(
            {
                "theta_i": elevations[j],
                "phi_i": (37.0 * m + 160.0) % 360.0,
                "theta_o": theta_o,
                "phi_o": phi_o,
                "intensity": 0.6 + 0.8 * ((m * 7) % 10) / 9,
            }
        )
    return out


def subspace_residual(truth: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Per-pixel nRMSE ``(image, y, x)`` of projecting ``truth`` ``(image, wavelength, y, x)``
    onto the span of ``basis`` ``(rank, wavelength)`` (orthonormal rows); normalised by the
    image's mean truth, like the benchmark's metric."""
    t = np.asarray(truth, dtype=np.float64)
    coefficients = np.einsum("kw,mwyx->mkyx", basis, t)
    residual = t - np.einsum("kw,mkyx->mwyx", basis, coefficients)
    rmse = np.sqrt(np.mean(residual**2, axis=1))
    return rmse / t.mean(axis=(1, 2, 3))[:, None, None]


def scene_properties(capture: SceneCapture, illuminant: np.ndarray) -> dict:
    """Measured hardness of a capture: mean intensity, band signal and SNR, dark fraction,
    brightness range over a set, subspace residual."""
    truth = capture.truth.values.astype(np.float64)
    white = float(np.mean(illuminant))
    signal = capture.band_signal_dn
    noise = np.sqrt(READ_NOISE_DN**2 + np.maximum(signal, 0) / 19.5 + 1 / 12)
    per_pixel_mean = truth.mean(axis=1)
    residual = subspace_residual(
        truth, subspace_basis(capture.camera_matrix["wavelength"].values, illuminant)
    )
    out = {
        "mean_intensity_rel_white": float(truth.mean() / white),
        "dark_fraction_under_10pct_of_mean": float(np.mean(per_pixel_mean < 0.1 * truth.mean())),
        "median_band_signal_dn": float(np.median(signal)),
        "median_band_snr": float(np.median(signal / noise)),
        "fraction_band_snr_le_1": float(np.mean(signal / noise <= 1)),
        "subspace8_nrmse_p95": float(np.percentile(residual, 95)),
        "subspace8_nrmse_median": float(np.median(residual)),
        "filter_size_px": [round(float(v), 2) for v in capture.bands["filter_size"].values],
        "n_materials": int(len(capture.layout.reflectance)),
    }
    if truth.shape[0] > 1:
        brightness = truth.mean(axis=1)
        ratio = brightness.max(axis=0) / np.maximum(brightness.min(axis=0), 1e-9)
        lit = brightness.mean(axis=0) > 0.1 * brightness.mean()
        out["texel_brightness_ratio_median"] = float(np.median(ratio[lit]))
    return out


def get_scene(
    name: str,
    *,
    size: int = 128,
    seed: int = 0,
    n_images: int = 1,
    images_with_bands: int | None = None,
    layout_seed: int = 0,
) -> SceneCapture:
    """Render and capture hard scene ``name``.

    Parameters
    ----------
    name
        A key of :data:`SCENES`.
    size
        Image height and width [px].
    seed
        Seed of the capture noise.
    n_images
        1: a single image with all 32 band shots; more: a BTF-like set (:func:`set_geometry`).
    images_with_bands
        Images that get band shots, the 32 bands spread round-robin over them (default: 1
        for a single image, half of a set).
    layout_seed
        Seed of the layout (materials, placement); fixed per benchmark scene.

    Returns
    -------
    SceneCapture
        Inputs of the reconstruction API, the truth and :func:`scene_properties`.
    """
    if name not in SCENES:
        raise SimulationParameterError(f"unknown scene {name!r}; known scenes: {', '.join(SCENES)}")
    if n_images < 1 or size < 16:
        raise SimulationParameterError(
            f"expected n_images >= 1 and size >= 16, found {n_images}, {size}"
        )
    wavelength = np.asarray(WAVELENGTHS, dtype=np.float64)
    illuminant = sharp_led(wavelength)
    camera = camera_sensitivities(wavelength)
    c = camera.values
    quantum_efficiency = spectral_quantum_efficiency(wavelength).values
    layout_rng = np.random.default_rng([layout_seed, sum(map(ord, name))])
    layout = SCENES[name].build(size, layout_rng, wavelength, c, illuminant)
    geometry = set_geometry(n_images, images_with_bands or (1 if n_images == 1 else n_images // 2))
    truth = np.stack([render_layout(layout, illuminant, **g) for g in geometry])
    reference = truth[0] if n_images == 1 else render_layout(layout, illuminant, **set_geometry(1, 1)[0])
    plan = band_plan(
        reference, quantum_efficiency, illuminant, wavelength, max_filter_size=(size - 1) / 2 - 1.0
    )
    with_bands = images_with_bands or (1 if n_images == 1 else n_images // 2)
    shot_band = np.arange(wavelength.size)
    shot_image = shot_band % with_bands
    rng = np.random.default_rng([seed, 7919])
    rgb = capture_rgb(truth, c, illuminant, rng)
    shots, signal = capture_bands(
        truth, shot_band, shot_image, quantum_efficiency, plan["exposure_time"].values, rng
    )
    wl_attrs = {"units": "nm", "long_name": "wavelength"}
    image = np.arange(n_images)
    angles = {
        k: ("image", np.array([g[k] for g in geometry]))
        for k in ("theta_i", "phi_i", "theta_o", "phi_o")
    }
    capture = SceneCapture(
        rgb=xr.DataArray(
            rgb.astype(np.float32),
            dims=("image", "y", "x", "channel"),
            coords={"image": image, "channel": ["R", "G", "B"], **angles},
            attrs={"units": "1", "long_name": "relative RGB radiance"},
        ),
        bands=xr.DataArray(
            shots.astype(np.float32),
            dims=("shot", "y", "x"),
            coords={
                "wavelength": ("shot", wavelength[shot_band], wl_attrs),
                "image": ("shot", shot_image),
                "filter_size": ("shot", plan["filter_size"].values[shot_band], {"units": "px"}),
                "exposure_time": ("shot", plan["exposure_time"].values[shot_band], {"units": "s"}),
            },
            attrs={"units": "1", "long_name": "relative band radiance"},
        ),
        camera_matrix=xr.DataArray(
            c,
            dims=("channel", "wavelength"),
            coords={"channel": ["R", "G", "B"], "wavelength": ("wavelength", wavelength, wl_attrs)},
        ),
        truth=xr.DataArray(
            truth.astype(np.float32),
            dims=("image", "wavelength", "y", "x"),
            coords={"image": image, "wavelength": ("wavelength", wavelength, wl_attrs)},
            attrs={"units": "1", "long_name": "relative spectral radiance", "scene": name},
        ),
        plan=plan,
        layout=layout,
        band_signal_dn=signal,
    )
    capture.properties = scene_properties(capture, illuminant)
    return capture
