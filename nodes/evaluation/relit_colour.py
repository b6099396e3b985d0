"""Colour under another light: spectra relit under CIE illuminants and their CIEDE2000.

A reconstructed cube is spectral radiance under the gantry's light ``L`` (the calibration's
``illuminant``, relative spectral radiance on the band wavelengths). What a user of the
spectra wants is the colour of the material under *another* light, e.g. CIE A (tungsten) or
FL11 (a narrow-band fluorescent lamp), where two spectra that match under ``L`` may not
(metamerism). This module relights a cube and measures the colour difference of a
reconstruction relit that way against its ground truth relit the same way.

Relighting (per pixel ``p``, band ``k`` at wavelength ``lambda_k``)
    ``R_k(p) = S_k(p) / max(L_k, f max_j L_j)``: a reflectance-like factor (reflectance
    times shading, plus the specular term's ``1``), with ``f`` the *light floor*
    (``light_floor``). Then ``S'_k(p) = R_k(p) E_k``, with ``E_k`` the new light's relative
    spectral power averaged over band ``k`` (a box of the band spacing centred on
    ``lambda_k``, from the CIE table interpolated linearly, constant beyond it) and
    normalised so that a perfect reflector (``R = 1``) relit has ``Y = 1``.
Colour
    ``XYZ(p) = sum_k S'_k(p) w_k``, with ``w_k`` the CIE 1931 2 degree colour-matching
    functions at the band centres (colour-science's integration,
    :func:`~.colorimetry.xyz_weights` with equal energy), so a perfect reflector relit has
    ``Y = 1`` and the chromaticity of the new light's white on these bands.
Exposure
    The band radiance is in the units of the measured illuminant (the band radiance of a
    white diffuser), so ``R`` is a reflectance factor and ``Y = 1`` the white diffuser,
    CIE 015's relative colorimetry of reflecting objects (``white_percentile=None``). A
    BTF image's factors also hold the shading of its geometry, so by default each image
    is exposed as it would be displayed, once, from its truth: the XYZ of truth *and*
    estimate are multiplied by ``1 / P(Y_truth)``, the truth's ``white_percentile``-th
    percentile of ``Y`` over the image's pixels (one factor per image and light, stored),
    as :func:`~.colorimetry.render_srgb` exposes a render.
CIEDE2000
    CIELAB relative to the new light's white (``Y = 1``), then
    ``colour.delta_E(..., method="CIE 2000")`` per pixel. Pixels whose exposed truth has
    ``Y < dark_floor`` are left out (NaN): default :data:`DARK_FLOOR`, the veiling flare
    of sRGB's reference viewing condition, below which a displayed colour is the flare's
    rather than its own.

Band averaging matters for line spectra: the emission lines of FL11 in the CIE table lie
between the centres of the paper's bands, which point sampling would miss.

**The light floor.** Where ``L`` is near zero (white LEDs emit little at the ends of the
band range), the capture carries almost no signal, and ``S / L`` multiplies the estimate's
noise by ``1 / L``. The floor ``f`` (default :data:`LIGHT_FLOOR`, a hundredth of ``L``'s
peak) caps that gain at ``1 / f``: at those bands
the relit factor is damped, for truth and estimate alike, so the measure compares them
under the same damping; it does not say what the material's colour under the new light
would be at wavelengths the gantry's light never reached.

References
----------
Fast Capture of Spectral Image Series (the reconstructed spectra and their use for the
colour-correct reproduction of materials). CIE 015:2018 Colorimetry (standard illuminants A,
FL11 and D65; CIE 1931 standard observer; CIELAB). Sharma, G., Wu, W. and Dalal, E. N.
(2005). The CIEDE2000 color-difference formula: implementation notes, supplementary test
data, and mathematical observations. Color Research & Application 30(1), 21-30.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import xarray as xr

from spectralize.schemas import ParameterError, Problem, SchemaError

from .colorimetry import (
    OBSERVER,
    Illuminant,
    _illuminant_name,
    _spectral_shape,
    illuminant_sd,
    xyz_weights,
)
from .cubes import check_pair
from .pixel_metrics import _ciede2000

# colour-science is imported inside the functions that use it (its import is slow).

__all__ = [
    "LIGHTS",
    "LIGHT_FLOOR",
    "DARK_FLOOR",
    "WHITE_PERCENTILE",
    "light_on_bands",
    "reflectance_factor",
    "relight",
    "relit_delta_e",
    "relit_statistics",
]

#: The lights a reconstruction is relit under by default: CIE A (tungsten), CIE FL11 (a
#: narrow-band, three-line fluorescent lamp) and CIE D65 (daylight).
LIGHTS: tuple[str, ...] = ("A", "FL11", "D65")

#: Light floor ``f``: ``L`` below ``f`` times its peak is raised to it before dividing, so
#: the estimate's noise at bands the light hardly reaches is amplified at most ``1 / f``
#: times (see the module's notes).
LIGHT_FLOOR: float = 0.01

#: Pixels whose exposed truth has a relit luminance ``Y`` below this are left out of the
#: colour difference: sRGB's reference viewing flare (IEC 61966-2-1, a hundredth of white),
#: below which a displayed colour is the flare's rather than its own.
DARK_FLOOR: float = 0.01

#: The percentile of the truth's relit ``Y`` over an image's pixels that is exposed as white
#: (``Y = 1``), as the sRGB renders expose an image (:func:`~.colorimetry.auto_exposure`).
WHITE_PERCENTILE: float = 99.0


def _wavelengths(array: xr.DataArray, name: str) -> np.ndarray:
    if "wavelength" not in array.dims or "wavelength" not in array.coords:
        raise SchemaError(
            "cannot relight the spectra:",
            [
                Problem(
                    f"{name}:wavelength",
                    "a 'wavelength' dim with coordinates [nm]",
                    f"dims {tuple(array.dims)} and coords {list(array.coords)}",
                )
            ],
        )
    wavelength = np.asarray(array["wavelength"].values, dtype=np.float64)
    _spectral_shape(wavelength)  # evenly spaced, increasing, or a SchemaError
    return wavelength


def light_on_bands(target: Illuminant, wavelength: npt.ArrayLike) -> xr.DataArray:
    """The relative spectral power ``E_k`` of ``target`` averaged over each band.

    Band ``k`` is a box of the band spacing ``d`` centred on ``lambda_k``; the CIE table is
    interpolated linearly (no overshoot at the lines of a fluorescent lamp) and held
    constant beyond its ends. The result is normalised so that a perfect reflector relit
    under it has ``Y = 1`` (``sum_k E_k w_k^Y = 1``, CIE 1931 2 degree observer).

    Parameters
    ----------
    target
        A key of ``colour.SDS_ILLUMINANTS`` (e.g. ``"A"``, ``"FL11"``, ``"D65"``), ``"E"``
        or ``None`` (equal energy), or a ``colour.SpectralDistribution``.
    wavelength
        Band centres [nm], evenly spaced.

    Returns
    -------
    xarray.DataArray
        float64 (wavelength,) [1], with the light's white chromaticity on these bands in
        ``attrs["white_xy"]``.

    Raises
    ------
    ParameterError
        If ``target`` is not a known illuminant.
    SchemaError
        If the wavelengths are not evenly spaced and increasing.

    References
    ----------
    CIE 015:2018 Colorimetry (standard illuminants; extrapolation by the nearest value).
    """
    import colour

    shape = _spectral_shape(wavelength)
    centres = np.asarray(shape.wavelengths, dtype=np.float64)
    sd = illuminant_sd(target)
    if sd is None:
        power = np.ones_like(centres)
    else:
        table_wl = np.asarray(sd.wavelengths, dtype=np.float64)
        table = np.asarray(sd.values, dtype=np.float64)
        half = shape.interval / 2.0
        power = np.empty_like(centres)
        for k, centre in enumerate(centres):
            low, high = centre - half, centre + half
            inside = table_wl[(table_wl > low) & (table_wl < high)]
            points = np.concatenate([[low], inside, [high]])
            power[k] = np.trapezoid(np.interp(points, table_wl, table), points) / (high - low)
    weights = xyz_weights(centres, illuminant=None).values
    white = power @ weights
    power = power / white[1]
    white_xy = colour.XYZ_to_xy(white / white[1])
    return xr.DataArray(
        power,
        dims="wavelength",
        coords={"wavelength": centres},
        name="light",
        attrs={
            "units": "1",
            "long_name": f"relative spectral power of {_illuminant_name(target)}, band averages "
            "(a perfect reflector relit has Y = 1)",
            "light": _illuminant_name(target),
            "observer": OBSERVER,
            "white_xy": [float(white_xy[0]), float(white_xy[1])],
        },
    )


def _checked_light(
    illuminant_L: xr.DataArray | npt.ArrayLike, wavelength: np.ndarray, light_floor: float
) -> xr.DataArray:
    """``L`` on the cube's bands with the floor applied, or every problem at once."""
    if not (np.isfinite(light_floor) and 0.0 < light_floor < 1.0):
        raise ParameterError.single("light_floor", "a fraction of L's peak in (0, 1)", repr(light_floor))
    problems = []
    if isinstance(illuminant_L, xr.DataArray):
        if illuminant_L.dims != ("wavelength",):
            problems.append(Problem("illuminant_L", "dims ('wavelength',)", f"dims {illuminant_L.dims}"))
        elif "wavelength" in illuminant_L.coords and (
            illuminant_L.size != wavelength.size
            or not np.allclose(illuminant_L["wavelength"].values, wavelength, rtol=0, atol=1e-6)
        ):
            problems.append(
                Problem(
                    "illuminant_L:wavelength",
                    f"the cube's wavelengths {wavelength.tolist()} nm",
                    f"{np.asarray(illuminant_L['wavelength'].values).tolist()} nm",
                )
            )
    values = np.asarray(illuminant_L, dtype=np.float64)
    if not problems and values.shape != wavelength.shape:
        problems.append(
            Problem("illuminant_L", f"{wavelength.size} values, one per band", f"shape {values.shape}")
        )
    if not problems and (not np.all(np.isfinite(values)) or np.any(values < 0) or values.max() <= 0):
        problems.append(
            Problem(
                "illuminant_L",
                "finite, non-negative relative radiance with a positive peak",
                f"min {np.nanmin(values):.4g}, max {np.nanmax(values):.4g}, "
                f"{int(np.sum(~np.isfinite(values)))} not finite",
            )
        )
    if problems:
        raise SchemaError("cannot relight the spectra:", problems)
    floored = np.maximum(values, light_floor * values.max())
    return xr.DataArray(floored, dims="wavelength", coords={"wavelength": wavelength})


def reflectance_factor(
    radiance: xr.DataArray,
    illuminant_L: xr.DataArray | npt.ArrayLike,
    *,
    light_floor: float = LIGHT_FLOOR,
) -> xr.DataArray:
    """``R = S / max(L, f max L)``: the light taken out of a radiance cube (lazy if it is).

    Parameters
    ----------
    radiance
        Relative spectral radiance with a ``wavelength`` dim (coordinates in nm, evenly
        spaced), e.g. ``radiance`` (image, wavelength, y, x) of ``spectra``.
    illuminant_L
        The light ``L`` the cube was captured under, on its bands: a DataArray
        (wavelength,) whose coordinates equal the cube's, or one value per band.
    light_floor
        ``f`` in (0, 1): ``L`` is raised to at least ``f`` times its peak.

    Returns
    -------
    xarray.DataArray
        float64, the dims of ``radiance`` [1].

    Raises
    ------
    SchemaError
        If the cube has no evenly spaced wavelengths, or ``L`` is not one finite,
        non-negative value per band with a positive peak (the message names the array).
    ParameterError
        If ``light_floor`` is not in (0, 1).

    References
    ----------
    Fast Capture of Spectral Image Series (radiance relative to the measured illuminant).
    """
    wavelength = _wavelengths(radiance, "radiance")
    light = _checked_light(illuminant_L, wavelength, light_floor)
    light = light.assign_coords(wavelength=radiance["wavelength"])
    factor = radiance.astype(np.float64) / light
    factor.attrs = {
        "units": "1",
        "long_name": "reflectance-like factor S / max(L, light_floor max L)",
        "light_floor": float(light_floor),
    }
    return factor


def relight(
    radiance: xr.DataArray,
    illuminant_L: xr.DataArray | npt.ArrayLike,
    target: Illuminant = "A",
    *,
    light_floor: float = LIGHT_FLOOR,
) -> xr.DataArray:
    """The radiance cube as it would be under ``target`` instead of ``L``: ``R E``.

    ``R`` is :func:`reflectance_factor` and ``E`` the band averages of ``target``
    (:func:`light_on_bands`), normalised so that a perfect reflector relit has ``Y = 1``
    when the cube is integrated as it is (e.g. ``render_srgb(relit)``, whose equal-energy
    white then shows the new light's colour, as the capture's render shows ``L``'s).

    Parameters
    ----------
    radiance, illuminant_L, light_floor
        See :func:`reflectance_factor`.
    target
        The new light: a key of ``colour.SDS_ILLUMINANTS``, ``"E"``, or a
        ``colour.SpectralDistribution``.

    Returns
    -------
    xarray.DataArray
        float64, the dims of ``radiance`` [1], named ``radiance``; ``attrs`` state the
        light, the floor and the normalisation.

    Raises
    ------
    SchemaError
        See :func:`reflectance_factor`.
    ParameterError
        If ``target`` is unknown or ``light_floor`` is not in (0, 1).

    References
    ----------
    CIE 015:2018 Colorimetry (standard illuminants).
    """
    factor = reflectance_factor(radiance, illuminant_L, light_floor=light_floor)
    light = light_on_bands(target, factor["wavelength"].values)
    relit = factor * light.assign_coords(wavelength=factor["wavelength"])
    relit.name = "radiance"
    relit.attrs = {
        "units": "1",
        "long_name": f"relative spectral radiance relit under {light.attrs['light']}",
        "light": light.attrs["light"],
        "light_floor": float(light_floor),
        "white_xy": light.attrs["white_xy"],
        "normalisation": "S / max(L, light_floor max L) times the light's band averages; a "
        "perfect reflector relit has Y = 1 (CIE 1931 2 degree, integrated as it is)",
    }
    return relit


def _check_options(
    white_percentile: float | None, dark_floor: float, targets: Sequence[Illuminant]
) -> None:
    problems = []
    if white_percentile is not None and not 0.0 < white_percentile <= 100.0:
        problems.append(Problem("white_percentile", "a percentile in (0, 100]", repr(white_percentile)))
    if not (np.isfinite(dark_floor) and 0.0 <= dark_floor < 1.0):
        problems.append(Problem("dark_floor", "a relative luminance in [0, 1)", repr(dark_floor)))
    names = [_illuminant_name(t) for t in targets]
    if not names or len(set(names)) != len(names):
        problems.append(Problem("targets", "one or more distinct lights", repr(names)))
    if problems:
        raise ParameterError("cannot measure the relit colour difference:", problems)


def _exposure(luminance: xr.DataArray, percentile: float | None) -> np.ndarray:
    """(image,) ``1 / P(Y)`` of (image, y, x) luminance; NaN where no positive level; ones
    for ``percentile=None`` (the white diffuser is white; nothing is computed)."""
    if percentile is None:
        return np.ones(luminance.sizes["image"])
    flat = np.asarray(luminance.transpose("image", "y", "x").values)
    flat = flat.reshape(flat.shape[0], -1)
    scale = np.full(flat.shape[0], np.nan)
    for i, values in enumerate(flat):
        values = values[np.isfinite(values)]
        level = float(np.percentile(values, percentile)) if values.size else 0.0
        if level > 0:
            scale[i] = 1.0 / level
    return scale


def _relit_delta_e_numpy(
    s: np.ndarray,
    t: np.ndarray,
    scale: np.ndarray,
    weights: np.ndarray,
    white: np.ndarray,
    dark_floor: float,
) -> np.ndarray:
    """(..., wavelength) estimate and truth, (...) exposure -> (...) float32 CIEDE2000."""
    xyz_s = (np.asarray(s, dtype=np.float64) @ weights) * scale[..., None]
    xyz_t = (np.asarray(t, dtype=np.float64) @ weights) * scale[..., None]
    delta = _ciede2000(xyz_s, xyz_t, white)
    with np.errstate(invalid="ignore"):
        dark = ~(xyz_t[..., 1] >= dark_floor)
    return np.where(dark, np.float32(np.nan), delta).astype(np.float32)


def relit_delta_e(
    estimate: xr.DataArray | xr.Dataset,
    truth: xr.DataArray | xr.Dataset,
    illuminant_L: xr.DataArray | npt.ArrayLike,
    *,
    targets: Sequence[Illuminant] = LIGHTS,
    light_floor: float = LIGHT_FLOOR,
    white_percentile: float | None = WHITE_PERCENTILE,
    dark_floor: float = DARK_FLOOR,
) -> xr.Dataset:
    """Per-pixel CIEDE2000 of the estimate against the truth, both relit under each light.

    Both cubes are relit (:func:`relight`: ``S / max(L, f max L)`` times the light's band
    averages), converted to CIE XYZ (CIE 1931 2 degree observer), exposed with one factor
    per image and light taken from the truth (its ``white_percentile``-th percentile of
    ``Y`` becomes ``Y = 1``; see the module's notes), converted to CIELAB relative to the
    light's white and compared with ``colour.delta_E(method="CIE 2000")``. Lazy over images
    when the cubes are dask-backed (the truth's luminance is computed once for the exposure).

    Parameters
    ----------
    estimate, truth
        ``radiance`` (image, wavelength, y, x) of the reconstruction and the ground truth,
        or Datasets holding it; images are matched by label.
    illuminant_L
        The light both were captured under, on their bands (see :func:`reflectance_factor`).
    targets
        The lights to relight under (default :data:`LIGHTS`: A, FL11, D65).
    light_floor
        ``f``: see :data:`LIGHT_FLOOR`.
    white_percentile
        Percentile of the truth's relit ``Y`` over an image that is exposed as white;
        ``None``: no exposure, the white diffuser (``R = 1``) is white.
    dark_floor
        Pixels whose exposed truth has ``Y`` below this are NaN; 0 keeps every pixel.

    Returns
    -------
    xarray.Dataset
        ``delta_e`` (light, image, y, x) float32 [1], NaN where left out (dark, or a
        spectrum holding NaN); ``exposure_scale`` (light, image) float64 [1], the factor
        both XYZ were multiplied by; ``white_xy`` (light, xy), the white of CIELAB. Attrs
        state the observer, the floors and the normalisation.

    Raises
    ------
    SchemaError
        If the cubes do not fit together (dims, shapes, wavelengths, labels) or ``L`` is
        not one finite, non-negative value per band with a positive peak.
    ParameterError
        If a light is unknown or an option is out of range.

    References
    ----------
    CIE 015:2018 Colorimetry (illuminants A, FL11, D65; CIELAB). Sharma, G., Wu, W. and
    Dalal, E. N. (2005). The CIEDE2000 color-difference formula: implementation notes,
    supplementary test data, and mathematical observations. Color Research & Application
    30(1), 21-30. Fast Capture of Spectral Image Series (the spectra compared).
    """
    s, t = check_pair(estimate, truth)
    _check_options(white_percentile, dark_floor, targets)
    wavelength = _wavelengths(t, "truth")
    light = _checked_light(illuminant_L, wavelength, light_floor).values
    cmfs = xyz_weights(wavelength, illuminant=None).values
    if s.chunks is not None or t.chunks is not None:
        s, t = s.chunk({"wavelength": -1}), t.chunk({"wavelength": -1})
    maps, scales, whites, names = [], [], [], []
    for target in targets:
        power = light_on_bands(target, wavelength)
        weights = (power.values / light)[:, None] * cmfs  # radiance -> relit XYZ
        luminance = xr.dot(t.astype(np.float64), xr.DataArray(weights[:, 1], dims="wavelength"))
        scale = _exposure(luminance, white_percentile)
        white = np.asarray(power.attrs["white_xy"])
        scale_da = xr.DataArray(
            scale, dims="image", coords={"image": t["image"]} if "image" in t.coords else {}
        )
        maps.append(
            xr.apply_ufunc(
                _relit_delta_e_numpy,
                s,
                t,
                scale_da,
                kwargs={"weights": weights, "white": white, "dark_floor": float(dark_floor)},
                input_core_dims=[["wavelength"], ["wavelength"], []],
                dask="parallelized",
                output_dtypes=[np.float32],
            ).transpose("image", "y", "x")
        )
        scales.append(scale)
        whites.append(white)
        names.append(power.attrs["light"])
    return _relit_dataset(maps, scales, whites, names, t, light_floor, white_percentile, dark_floor)


def _relit_dataset(
    maps: list[xr.DataArray],
    scales: list[np.ndarray],
    whites: list[np.ndarray],
    names: list[str],
    truth: xr.DataArray,
    light_floor: float,
    white_percentile: float | None,
    dark_floor: float,
) -> xr.Dataset:
    light = xr.DataArray(names, dims="light", attrs={"long_name": "light relit under"})
    delta_e = xr.concat(maps, dim=light)
    exposure = (
        "1 (the white diffuser, R = 1, is white)"
        if white_percentile is None
        else f"1 / the truth's {white_percentile:g}th percentile of the relit luminance Y over the image"
    )
    image_coords = {"image": truth["image"]} if "image" in truth.coords else {}
    return xr.Dataset(
        {
            "delta_e": delta_e.assign_attrs(
                units="1",
                long_name="CIEDE2000 of the spectra relit under the light against the truth "
                "relit the same way",
            ),
            "exposure_scale": xr.DataArray(
                np.stack(scales),
                dims=("light", "image"),
                coords={"light": light, **image_coords},
                attrs={"units": "1", "long_name": f"factor on both XYZ: {exposure}"},
            ),
            "white_xy": xr.DataArray(
                np.stack(whites),
                dims=("light", "xy"),
                coords={"light": light, "xy": ["x", "y"]},
                attrs={"units": "1", "long_name": "chromaticity of the light's white on the bands"},
            ),
        },
        attrs={
            "observer": OBSERVER,
            "light_floor": float(light_floor),
            "white_percentile": "none" if white_percentile is None else float(white_percentile),
            "dark_floor": float(dark_floor),
            "normalisation": "both cubes relit as S / max(L, light_floor max L) times the "
            "light's band averages (a perfect reflector: Y = 1), then both XYZ multiplied by "
            f"one factor per image and light, {exposure}; CIELAB relative to the light's "
            "white (Y = 1)",
            "excluded": f"pixels whose exposed truth has Y < {dark_floor:g}, or that hold NaN",
        },
    )


def relit_statistics(relit: xr.Dataset) -> dict[str, dict[str, float]]:
    """Median and 95th percentile of ``delta_e`` per light, over the pixels not left out.

    Parameters
    ----------
    relit
        The output of :func:`relit_delta_e` (computed here if lazy).

    Returns
    -------
    dict
        ``{light: {"median", "p95", "excluded"}}``; ``excluded`` is the fraction of pixels
        left out (dark or NaN); median and p95 are NaN when every pixel is.

    References
    ----------
    Sharma, G., Wu, W. and Dalal, E. N. (2005), Color Research & Application 30(1).
    """
    out = {}
    for name in relit["light"].values:
        values = np.asarray(relit["delta_e"].sel(light=name).values, dtype=np.float64).ravel()
        kept = values[np.isfinite(values)]
        median, p95 = np.percentile(kept, [50, 95]) if kept.size else (np.nan, np.nan)
        out[str(name)] = {
            "median": float(median),
            "p95": float(p95),
            "excluded": float(1.0 - kept.size / values.size) if values.size else 1.0,
        }
    return out
