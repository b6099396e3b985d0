"""Spectral ground truth from real measured spectra (paper sec. 5, "Simulated Data").

The textures are built from spectra that colour-science ships:

- material reflectances: ColorChecker patches (``colour.SDS_COLOURCHECKERS``: the N Ohta
  measurements and the BabelColor averages);
- illuminants: the CIE LED illuminants (``colour.SDS_ILLUMINANTS['LED-B3']`` etc.);
- camera sensitivities are in :mod:`spectralize.nodes.simulation.camera_model`.

A :class:`SpectralTexture` is procedural: several materials laid out by smooth random
fields, mixed by a softmax whose sharpness varies over the image (sharp *and* smooth
material boundaries), a fine albedo detail, a bump (height) field for shading and a
specular lobe per material whose highlights have the illuminant's spectrum (the paper's
hardest case, sec. 5 and 6).  It can be evaluated on any tile and at sub-pixel shifted
coordinates, so a huge image can be generated chunk by chunk without materialising it and
a known misregistration is exact, not interpolated.

Reflectance model (isotropic, in the sample's frame; ``E = pi``, so a white diffuse target
lit at normal incidence has radiance ``L``)::

    radiance(lambda) = L(lambda) * (rho(lambda) * max(n.l, 0)
                                    + k_s * (m + 8) / 8 * max(n.h, 0) ** m * max(n.l, 0))

References
----------
Fast Capture of Spectral Image Series, sec. 5 and Figures 5, 6 (materials with highlights).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import numpy.typing as npt
import xarray as xr

from spectralize.nodes.simulation.camera_model import (
    ShapeMismatchError,
    SimulationParameterError,
    as_generator,
    check_positive,
    check_wavelength,
)

__all__ = [
    "WAVELENGTHS",
    "wavelength_grid",
    "colourchecker_reflectances",
    "illuminant_spd",
    "direction",
    "SpectralTexture",
    "ColourCheckerChart",
    "spectral_texture",
    "shading",
    "render",
    "spectral_scene",
]

#: The paper's 32 bands: 410..720 nm in 10 nm steps.
WAVELENGTHS: np.ndarray = np.arange(410.0, 721.0, 10.0)

_CHROMATIC_PATCHES = (
    "dark skin",
    "light skin",
    "blue sky",
    "foliage",
    "blue flower",
    "bluish green",
    "orange",
    "purplish blue",
    "moderate red",
    "purple",
    "yellow green",
    "orange yellow",
    "blue",
    "green",
    "red",
    "yellow",
    "magenta",
    "cyan",
)


def wavelength_grid(start: float = 410.0, stop: float = 720.0, step: float = 10.0) -> np.ndarray:
    """Band centres ``start..stop`` (inclusive) in ``step`` nm steps; default 32 bands."""
    check_positive([start, stop, step], "start, stop, step")
    if stop < start:
        raise SimulationParameterError(
            f"stop must be >= start; received start={start:g}, stop={stop:g} nm."
        )
    n = int(round((stop - start) / step)) + 1
    return start + step * np.arange(n, dtype=np.float64)


def _wl_coord(wl: np.ndarray) -> xr.Variable:
    return xr.Variable(("wavelength",), wl, {"units": "nm", "long_name": "wavelength"})


@lru_cache(maxsize=16)
def _chart_values(chart: str, wl: tuple[float, ...]) -> tuple[tuple[str, ...], np.ndarray]:
    import colour

    try:
        sds = colour.SDS_COLOURCHECKERS[chart]
    except KeyError:
        raise SimulationParameterError(
            f"chart {chart!r} is not shipped by colour-science; known: "
            f"{sorted(colour.SDS_COLOURCHECKERS)}."
        ) from None
    names = tuple(sds)
    first = sds[names[0]]
    if wl[0] < first.shape.start or wl[-1] > first.shape.end:
        raise SimulationParameterError(
            f"wavelength must lie in {first.shape.start:g}..{first.shape.end:g} nm for "
            f"{chart!r}; received {wl[0]:g}..{wl[-1]:g} nm."
        )
    values = np.stack([np.asarray(sds[n][np.asarray(wl)], dtype=np.float64) for n in names])
    return names, np.clip(values, 0.0, 1.0)


def colourchecker_reflectances(
    wavelength: npt.ArrayLike = WAVELENGTHS, *, chart: str = "ColorChecker N Ohta"
) -> xr.DataArray:
    """Measured ColorChecker reflectances (patch, wavelength) from colour-science.

    ``chart`` is a key of ``colour.SDS_COLOURCHECKERS`` (default the N Ohta measurement,
    380..780 nm in 5 nm steps, so the default 10 nm grid is sampled without interpolation).
    """
    wl = check_wavelength(wavelength)
    names, values = _chart_values(chart, tuple(float(v) for v in wl))
    return xr.DataArray(
        values.copy(),
        dims=("patch", "wavelength"),
        coords={
            "patch": np.arange(len(names)),
            "patch_name": ("patch", list(names)),
            "wavelength": _wl_coord(wl),
        },
        name="reflectance",
        attrs={
            "units": "1",
            "long_name": "spectral reflectance",
            "source": f"colour.SDS_COLOURCHECKERS[{chart!r}]",
        },
    )


def illuminant_spd(wavelength: npt.ArrayLike = WAVELENGTHS, *, name: str = "LED-B3") -> xr.DataArray:
    """A CIE illuminant's relative spectral power (wavelength), normalised to max 1.

    ``name`` is a key of ``colour.SDS_ILLUMINANTS`` (e.g. ``'LED-B3'``, a phosphor-converted
    white LED like the gantry's, weak below 430 nm and above 680 nm).
    """
    import colour

    wl = check_wavelength(wavelength)
    try:
        sd = colour.SDS_ILLUMINANTS[name]
    except KeyError:
        raise SimulationParameterError(
            f"illuminant {name!r} is not shipped by colour-science; LED ones: "
            f"{sorted(k for k in colour.SDS_ILLUMINANTS if 'LED' in k)}."
        ) from None
    if wl[0] < sd.shape.start or wl[-1] > sd.shape.end:
        raise SimulationParameterError(
            f"wavelength must lie in {sd.shape.start:g}..{sd.shape.end:g} nm for {name!r}."
        )
    v = np.clip(np.asarray(sd[wl], dtype=np.float64), 0.0, None)
    return xr.DataArray(
        v / v.max(),
        dims=("wavelength",),
        coords={"wavelength": _wl_coord(wl)},
        name="illuminant",
        attrs={
            "units": "1",
            "long_name": f"relative spectral radiance of {name}",
            "source": f"colour.SDS_ILLUMINANTS[{name!r}]",
        },
    )


def direction(theta: npt.ArrayLike, phi: npt.ArrayLike) -> np.ndarray:
    """Unit vector(s) (..., 3) for polar angle ``theta`` and azimuth ``phi`` [degree]."""
    t = np.deg2rad(np.asarray(theta, dtype=np.float64))
    p = np.deg2rad(np.asarray(phi, dtype=np.float64))
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


# --------------------------------------------------------------------------------------
# procedural fields
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Fourier:
    """Sum of random cosines, ``sum_j a_j cos(2 pi (fy_j v + fx_j u) + phase_j)``.

    ``u, v`` are normalised image coordinates ((x + 0.5) / size). Evaluated per tile as a
    complex matrix product (separable per feature), so cost is O(h w J) multiply-adds.
    Stacks ``F`` fields: arrays have a leading field axis.
    """

    fy: np.ndarray  # (F, J) cycles per image
    fx: np.ndarray  # (F, J)
    coef: np.ndarray  # (F, J) complex amplitude a_j exp(i phase_j)

    @classmethod
    def random(
        cls, rng: np.random.Generator, n_fields: int, n_features: int, fmin: float, fmax: float
    ) -> _Fourier:
        f = np.exp(rng.uniform(np.log(fmin), np.log(fmax), size=(n_fields, n_features)))
        ang = rng.uniform(0, 2 * np.pi, size=(n_fields, n_features))
        ph = rng.uniform(0, 2 * np.pi, size=(n_fields, n_features))
        a = math.sqrt(2.0 / n_features)
        return cls(f * np.sin(ang), f * np.cos(ang), a * np.exp(1j * ph))

    def __call__(self, v: np.ndarray, u: np.ndarray, *, derivative: str | None = None) -> np.ndarray:
        """Fields (F, len(v), len(u)); ``derivative`` 'u' or 'v' gives d/du or d/dv."""
        ey = np.exp(2j * np.pi * self.fy[:, None, :] * v[None, :, None])  # (F, h, J)
        ex = np.exp(2j * np.pi * self.fx[:, None, :] * u[None, :, None])  # (F, w, J)
        c = self.coef
        if derivative == "u":
            c = c * (2j * np.pi * self.fx)
        elif derivative == "v":
            c = c * (2j * np.pi * self.fy)
        return np.real(np.matmul(ey * c[:, None, :], np.swapaxes(ex, 1, 2)))


@dataclass(frozen=True)
class TextureTile:
    """A texture evaluated on one tile (all arrays float32 except ``material``)."""

    weights: np.ndarray  # (K, h, w) material mixing weights, sum 1
    albedo: np.ndarray  # (h, w) multiplicative albedo detail
    normal: np.ndarray  # (3, h, w) unit normals in the sample frame
    specular_albedo: np.ndarray  # (h, w)
    shininess: np.ndarray  # (h, w)

    @property
    def material(self) -> np.ndarray:
        """(h, w) int16 index of the dominant material."""
        return np.argmax(self.weights, axis=0).astype(np.int16)


@dataclass(frozen=True, eq=False)
class SpectralTexture:
    """Procedural spectral texture of several measured materials; see :func:`spectral_texture`."""

    size: int
    wavelength: np.ndarray
    reflectance: np.ndarray  # (K, n) per-material diffuse reflectance
    material_names: tuple[str, ...]
    specular_albedo: np.ndarray  # (K,)
    shininess: np.ndarray  # (K,)
    layout: _Fourier
    sharpness: _Fourier
    detail: _Fourier
    height: _Fourier
    sharp_range: tuple[float, float] = (0.7, 60.0)
    detail_amplitude: float = 0.12
    bump: float = 0.008
    _cache: dict = field(default_factory=dict, compare=False, repr=False)

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_cache"] = {}
        return state

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)

    @property
    def n_materials(self) -> int:
        return int(self.reflectance.shape[0])

    def coordinates(self, start: int, stop: int, shift: float = 0.0) -> np.ndarray:
        """Normalised coordinates of pixel centres ``start..stop-1`` minus ``shift`` px."""
        return (np.arange(start, stop, dtype=np.float64) + 0.5 - shift) / self.size

    def evaluate(
        self, rows: slice, cols: slice, *, shift: tuple[float, float] = (0.0, 0.0)
    ) -> TextureTile:
        """Evaluate on pixel ``rows`` x ``cols``; the content moves by ``shift`` (dy, dx) px.

        Pixel (y, x) of the result shows the texture point (y - dy, x - dx).  Results are
        cached per tile (a few dozen entries).
        """
        key = (rows.start, rows.stop, cols.start, cols.stop, float(shift[0]), float(shift[1]))
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        v = self.coordinates(rows.start, rows.stop, shift[0])
        u = self.coordinates(cols.start, cols.stop, shift[1])
        g = self.layout(v, u)  # (K, h, w)
        s = 1.0 / (1.0 + np.exp(-3.0 * self.sharpness(v, u)[0]))
        lo, hi = np.log(self.sharp_range[0]), np.log(self.sharp_range[1])
        beta = np.exp(lo + (hi - lo) * s)
        z = beta[None] * g
        z -= z.max(axis=0, keepdims=True)
        w = np.exp(z)
        w /= w.sum(axis=0, keepdims=True)
        albedo = 1.0 + self.detail_amplitude * np.tanh(self.detail(v, u)[0])
        hu = self.height(v, u, derivative="u")[0]
        hv = self.height(v, u, derivative="v")[0]
        n = np.stack([-self.bump * hu, -self.bump * hv, np.ones_like(hu)])
        n /= np.linalg.norm(n, axis=0, keepdims=True)
        ks = np.tensordot(self.specular_albedo, w, axes=1)
        m = np.exp(np.tensordot(np.log(self.shininess), w, axes=1))
        tile = TextureTile(
            weights=w.astype(np.float32),
            albedo=albedo.astype(np.float32),
            normal=n.astype(np.float32),
            specular_albedo=ks.astype(np.float32),
            shininess=m.astype(np.float32),
        )
        return self.remember(key, tile)

    def remember(self, key: tuple, value):
        """Keep ``value`` in the per-tile cache (bounded: cleared beyond 24 entries)."""
        if len(self._cache) >= 24:
            self._cache.clear()
        self._cache[key] = value
        return value

    def diffuse_reflectance(self, tile: TextureTile) -> np.ndarray:
        """Per-pixel diffuse reflectance (n_wavelength, h, w) float32 of a tile."""
        rho = np.tensordot(self.reflectance.T.astype(np.float32), tile.weights, axes=1)
        return rho * tile.albedo[None]

    def dataset(self) -> xr.Dataset:
        """The whole texture as a Dataset (small sizes only): reflectance, normals, gloss."""
        tile = self.evaluate(slice(0, self.size), slice(0, self.size))
        return xr.Dataset(
            {
                "diffuse_reflectance": (
                    ("wavelength", "y", "x"),
                    self.diffuse_reflectance(tile),
                    {"units": "1", "long_name": "diffuse reflectance"},
                ),
                "material": (
                    ("y", "x"),
                    tile.material,
                    {"units": "1", "long_name": "index of the dominant material"},
                ),
                "normal": (
                    ("component", "y", "x"),
                    tile.normal,
                    {"units": "1", "long_name": "surface normal (sample frame)"},
                ),
                "specular_albedo": (
                    ("y", "x"),
                    tile.specular_albedo,
                    {"units": "1", "long_name": "specular albedo k_s"},
                ),
                "shininess": (
                    ("y", "x"),
                    tile.shininess,
                    {"units": "1", "long_name": "Blinn-Phong exponent m"},
                ),
                "material_reflectance": (
                    ("material_index", "wavelength"),
                    self.reflectance,
                    {"units": "1", "long_name": "material reflectance"},
                ),
            },
            coords={
                "wavelength": _wl_coord(self.wavelength),
                "component": ["x", "y", "z"],
                "material_index": np.arange(self.n_materials),
                "material_name": ("material_index", list(self.material_names)),
            },
        )


def spectral_texture(
    size: int,
    *,
    wavelength: npt.ArrayLike = WAVELENGTHS,
    seed: int = 0,
    n_materials: int = 6,
    glossy_fraction: float = 0.5,
    chart: str = "ColorChecker N Ohta",
) -> SpectralTexture:
    """A deterministic procedural texture of ``n_materials`` measured reflectances.

    Parameters
    ----------
    size
        Image size in pixels (square); the pattern scales with it.
    wavelength
        Band centres [nm], strictly increasing.
    seed
        Seed; the same seed gives the same texture at any size.
    n_materials
        Number of materials (2..18), drawn from the chromatic ColorChecker patches.
    glossy_fraction
        Fraction of materials with a strong specular lobe (the rest are matte with a
        weak sheen).
    chart
        Source of the reflectances in ``colour.SDS_COLOURCHECKERS``.
    """
    if isinstance(size, bool) or not isinstance(size, int | np.integer) or size < 4:
        raise SimulationParameterError(f"size must be an int >= 4 px; received {size!r}.")
    wl = check_wavelength(wavelength)
    if not 2 <= n_materials <= len(_CHROMATIC_PATCHES):
        raise SimulationParameterError(
            f"n_materials must be in 2..{len(_CHROMATIC_PATCHES)}; received {n_materials}."
        )
    if not 0.0 <= glossy_fraction <= 1.0:
        raise SimulationParameterError(f"glossy_fraction must be in [0, 1]; received {glossy_fraction}.")
    rng = as_generator(np.random.SeedSequence(seed, spawn_key=(0x7E,)))
    refl = colourchecker_reflectances(wl, chart=chart)
    names = list(refl["patch_name"].values)
    chosen = rng.choice(len(_CHROMATIC_PATCHES), size=n_materials, replace=False)
    chosen_names = tuple(_CHROMATIC_PATCHES[i] for i in chosen)
    values = np.stack([refl.values[names.index(n)] for n in chosen_names])
    n_glossy = int(round(glossy_fraction * n_materials))
    glossy = np.zeros(n_materials, dtype=bool)
    glossy[rng.choice(n_materials, size=n_glossy, replace=False)] = True
    ks = np.where(glossy, rng.uniform(0.25, 0.6, n_materials), rng.uniform(0.0, 0.04, n_materials))
    m = np.where(glossy, rng.uniform(40, 150, n_materials), rng.uniform(5, 15, n_materials))
    return SpectralTexture(
        size=int(size),
        wavelength=wl,
        reflectance=values,
        material_names=chosen_names,
        specular_albedo=ks,
        shininess=m,
        layout=_Fourier.random(rng, n_materials, 10, 1.0, 4.0),
        sharpness=_Fourier.random(rng, 1, 6, 0.4, 1.2),
        detail=_Fourier.random(rng, 1, 24, 8.0, 24.0),
        height=_Fourier.random(rng, 1, 24, 2.0, 8.0),
    )


@dataclass(frozen=True)
class ColourCheckerChart:
    """A 4 x 6 ColorChecker chart filling the image, patches on a black frame.

    ``patch_index`` is -1 on the frame. Used for the colour-checker calibration shots;
    the frame's reflectance is the chart's ``black`` patch.
    """

    size: int
    wavelength: np.ndarray
    chart: str = "ColorChecker N Ohta"
    rows: int = 4
    cols: int = 6
    gap: float = 0.2  # frame width relative to the patch pitch

    def reflectances(self) -> xr.DataArray:
        return colourchecker_reflectances(self.wavelength, chart=self.chart)

    def patch_index(
        self, rows: slice, cols: slice, *, shift: tuple[float, float] = (0.0, 0.0)
    ) -> np.ndarray:
        """(h, w) int16 patch index of pixel ``rows`` x ``cols``, content moved by ``shift``."""
        v = (np.arange(rows.start, rows.stop) + 0.5 - shift[0]) / self.size
        u = (np.arange(cols.start, cols.stop) + 0.5 - shift[1]) / self.size
        # patches laid out on a (rows + gap) x (cols + gap) pitch grid, margin = gap / 2
        pv = v * (self.rows + self.gap) - self.gap / 2
        pu = u * (self.cols + self.gap) - self.gap / 2
        iv, fv = np.floor(pv), pv - np.floor(pv)
        iu, fu = np.floor(pu), pu - np.floor(pu)
        inside_v = (fv < 1 - self.gap) & (iv >= 0) & (iv < self.rows)
        inside_u = (fu < 1 - self.gap) & (iu >= 0) & (iu < self.cols)
        idx = iv[:, None] * self.cols + iu[None, :]
        ok = inside_v[:, None] & inside_u[None, :]
        return np.where(ok, idx, -1).astype(np.int16)

    def diffuse_reflectance(self, patch_index: np.ndarray) -> np.ndarray:
        """(n_wavelength, h, w) float32 reflectance for a patch-index tile."""
        refl = self.reflectances()
        table = np.concatenate([refl.values, refl.values[-1:]], axis=0).astype(np.float32)
        return np.moveaxis(table[patch_index], -1, 0)


def shading(
    normal: np.ndarray,
    light: np.ndarray,
    view: np.ndarray,
    *,
    specular_albedo: np.ndarray,
    shininess: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Diffuse and specular factors (h, w) of the reflectance model for unit directions.

    Returns ``(d, s)`` with ``radiance = L * (rho * d + s)``: ``d = max(n.l, 0)`` and
    ``s = k_s (m + 8) / 8 max(n.h, 0)**m max(n.l, 0)`` (normalised Blinn-Phong), zero where
    the surface faces away from the viewer.
    """
    light = np.asarray(light, dtype=np.float32)
    view = np.asarray(view, dtype=np.float32)
    half = light + view
    half = half / np.linalg.norm(half)
    nl = np.maximum(np.tensordot(light, normal, axes=1), 0.0)
    nh = np.maximum(np.tensordot(half, normal, axes=1), 0.0)
    nv = np.tensordot(view, normal, axes=1)
    spec = specular_albedo * (shininess + 8.0) / 8.0 * nh**shininess * nl
    spec = np.where(nv > 0, spec, 0.0)
    return nl.astype(np.float32), spec.astype(np.float32)


def render(
    texture: SpectralTexture,
    illuminant: xr.DataArray | npt.ArrayLike,
    *,
    theta_i: float,
    phi_i: float,
    theta_o: float,
    phi_o: float,
    rows: slice | None = None,
    cols: slice | None = None,
    shift: tuple[float, float] = (0.0, 0.0),
) -> xr.DataArray:
    """Spectral radiance (wavelength, y, x) float32 of a texture lit and viewed as given.

    Angles in degrees in the sample frame (``theta`` from the normal). The specular term
    has the illuminant's spectrum.
    """
    ell = np.asarray(
        illuminant.values if isinstance(illuminant, xr.DataArray) else illuminant, dtype=np.float32
    )
    if ell.shape != texture.wavelength.shape:
        raise ShapeMismatchError(
            f"illuminant has {ell.size} values but the texture has "
            f"{texture.wavelength.size} wavelengths."
        )
    check_positive(ell, "illuminant", allow_zero=True)
    rows = slice(0, texture.size) if rows is None else rows
    cols = slice(0, texture.size) if cols is None else cols
    tile = texture.evaluate(rows, cols, shift=shift)
    d, s = shading(
        tile.normal,
        direction(theta_i, phi_i),
        direction(theta_o, phi_o),
        specular_albedo=tile.specular_albedo,
        shininess=tile.shininess,
    )
    rad = ell[:, None, None] * (texture.diffuse_reflectance(tile) * d[None] + s[None])
    return xr.DataArray(
        rad.astype(np.float32),
        dims=("wavelength", "y", "x"),
        coords={"wavelength": _wl_coord(texture.wavelength)},
        name="radiance",
        attrs={
            "units": "1",
            "long_name": "spectral radiance (relative)",
            "theta_i": float(theta_i),
            "phi_i": float(phi_i),
            "theta_o": float(theta_o),
            "phi_o": float(phi_o),
        },
    )


def spectral_scene(
    size: int = 64,
    *,
    wavelength: npt.ArrayLike = WAVELENGTHS,
    illuminant: str = "LED-B3",
    seed: int = 0,
    n_materials: int = 6,
    light: Sequence[float] = (40.0, 180.0),
    view: Sequence[float] = (40.0, 0.0),
) -> xr.Dataset:
    """Single-image spectral ground truth (the paper's "full correspondences" case).

    Returns a Dataset with ``radiance`` (wavelength, y, x) float32 [relative], the
    ``illuminant`` (wavelength) and the texture's ``material`` (y, x) map; by default the
    light is in the mirror direction of the view, so glossy materials show highlights.
    """
    tex = spectral_texture(size, wavelength=wavelength, seed=seed, n_materials=n_materials)
    ell = illuminant_spd(tex.wavelength, name=illuminant)
    rad = render(tex, ell, theta_i=light[0], phi_i=light[1], theta_o=view[0], phi_o=view[1])
    tile = tex.evaluate(slice(0, size), slice(0, size))
    return xr.Dataset(
        {
            "radiance": rad,
            "illuminant": ell,
            "material": (("y", "x"), tile.material, {"units": "1", "long_name": "dominant material"}),
        },
        attrs={"materials": ", ".join(tex.material_names), "seed": int(seed)},
    )
