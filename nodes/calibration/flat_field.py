"""Flat field: each camera's lens falloff measured on its own white-reference frames.

A lens darkens towards the corners of its image and a tunable filter adds an off-axis loss
that depends on the wavelength, so the sensitivity in eq. 5 is a map, ``Q_lambda F(p)``, not a
number. The capture contract has every camera photograph the white reference, an even diffuse
target; its frames, linearised through the camera's response and averaged over the exposure
series, are ``F`` up to a scale and the noise. An RGB camera's recovered response ripples where
the scene gave it few samples, and a ripple over the codes between the frame's centre and its
corners reads as falloff; its white reference is linearised through a smooth response fitted
jointly with the flat field on the white reference's own series
(:mod:`~spectralize.nodes.calibration.flat_field_response`), the spectral camera's band
series through one smooth response fitted on the ratios between its exposures.

- :func:`fit_flat_field`, :class:`FlatField`, :func:`from_calibration` (from
  :mod:`~spectralize.nodes.calibration.flat_field_maps`, which the HDR merge, the band
  radiance and the targets' fits import): one frame of the white reference -> a smooth map
  ``F`` (a low-order Legendre polynomial in the frame coordinates, 1 at the frame centre),
  its noise floor and the measures of an uneven target; the maps of several cameras or
  bands, divided out of images or band shots block by block.
- :func:`rgb_flat_field`: the RGB cameras' maps from their white reference's series through
  its own smooth response.
- :func:`spectral_flat_field`: the spectral camera's map per band from the white
  reference's band series (dark subtracted, linearised through one smooth response fitted
  on the series itself, time-weighted over the exposures), smoothed across the bands in
  wavelength (:func:`~.smooth_across_bands`).
- :func:`flat_field_variables`: the maps' variables of ``calibration/spectral``.

Why a polynomial, not a Gaussian filter: falloff is smooth across the whole frame and
steepest in the corners, where a filter window runs off the frame (mirrored or padded
edges bias the corners, exactly where the correction matters most); a polynomial fit of
block means extrapolates the smooth falloff into the corners, averages the noise of the
whole frame into few coefficients (its noise floor follows from the fit's covariance), stores
as a handful of numbers per camera whatever the frame size, and what it cannot explain (a
shadow, a smudge) is left in its residuals, which is what the evenness check measures. Total
degree :data:`DEGREE` follows a strong ``cos^4``-type falloff more closely than a white
reference's noise allows it to be measured (``docs/benchmarks_notes.md``, calibration_oracle).
The map is normalised to 1 at the frame centre (the optical axis of a centred lens), not to
its mean: it then reads as the falloff itself (a corner value is the share of the centre's
light that reaches the corner), the radiance at the centre is what it was without a flat
field, and the
scale divides out anyway (``Q`` and ``C`` are fitted to flat-fielded targets). Per-pixel
response non-uniformity is left in: the fit is smooth by design, so the white reference's
own noise is not written into every image.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("taking images of a white diffuse
   reference surface") and eq. 5 (``I = f^-1(x t Q_lambda)``, here with ``Q_lambda F(p)``).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from spectralize.nodes.calibration.band_shots import linearise, saturated_by_band, series_pieces
from spectralize.nodes.calibration.camera_matrices import (
    _camera_names,
    _rgb_series,
    camera_saturation,
    target_cameras,
)
from spectralize.nodes.calibration.dark import dark_frames_at
from spectralize.nodes.calibration.exposure_series import target_spectral_series
from spectralize.nodes.calibration.flat_field_maps import (
    BAND_BANDWIDTH,
    BLOCKS,
    DEGREE,
    FlatField,
    FlatFieldFit,
    fit_flat_field,
    flat_field_basis,
    from_calibration,
    legendre_powers,
    smooth_across_bands,
)
from spectralize.nodes.calibration.flat_field_response import (
    band_block_statistics,
    band_series_response,
    white_reference_frames,
    white_reference_response,
)
from spectralize.nodes.calibration.hdr import merge_hdr
from spectralize.schemas import CalibrationError

__all__ = [
    "DEGREE",
    "BLOCKS",
    "MIN_SNR",
    "FlatFieldFit",
    "FlatField",
    "legendre_powers",
    "flat_field_basis",
    "fit_flat_field",
    "rgb_flat_field",
    "camera_flat_fields",
    "spectral_flat_field",
    "flat_field_variables",
    "from_calibration",
]

MIN_SNR = 10.0
"""Smallest mean signal over the noise of a white-reference band exposure averaged into the
spectral camera's flat field."""


def rgb_flat_field(
    white_reference: xr.Dataset, oecf_rgb: xr.Dataset, *, own_response: bool = True
) -> tuple[FlatField, list]:
    """Each RGB camera's flat field from its HDR of the white reference.

    Each camera's exposure series of the white reference is merged to HDR (codes at or
    above its saturation left out, :func:`~spectralize.nodes.calibration.hdr.merge_hdr`:
    Robertson's time-weighted average over the series) through the smooth response fitted
    jointly with the flat field on that series
    (:func:`~spectralize.nodes.calibration.flat_field_response.white_reference_response`:
    the camera's recovered response ripples, and a ripple over the codes between the
    frame's centre and its corners reads as falloff), with ``own_response`` false (or where
    that fit has too few block means) through the camera's recovered response, and each
    channel fitted by :func:`fit_flat_field`; the camera's map is
    the mean of its channels' (stored for every channel): a lens's falloff is geometric, the
    same in every channel, while a map per channel would carry each channel's own response
    error into the colour of every image's corners (and into ``C``, fitted through it).

    Returns
    -------
    tuple
        The :class:`FlatField` (rows: the cameras of ``raw/white_reference``, (camera,
        channel, term)) and the :class:`FlatFieldFit` of every camera and channel.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 4 and 5 (Robertson's HDR merge).
    """
    group = "raw/white_reference"
    cameras = target_cameras(white_reference)
    coefficients, fits = [], []
    for camera in cameras:
        saturation = camera_saturation(oecf_rgb, camera)
        response = oecf_rgb["response"]
        if "camera" in response.dims:
            known = response["camera"].values.tolist()
            response = response.sel(camera=camera if camera in known else known[0])
        raw = _rgb_series(white_reference, group, camera, saturation).drop_vars("camera")
        radiance = _white_reference_frames(raw, response, oecf_rgb, camera, saturation)
        if radiance is None or not own_response:
            hdr = merge_hdr(
                raw, response.assign_attrs(oecf_rgb.attrs | response.attrs), saturation=saturation
            )
            radiance = np.asarray(hdr["radiance"].isel(image=0).transpose("y", "x", "channel").values)
        per_channel = [fit_flat_field(radiance[..., c]) for c in range(radiance.shape[-1])]
        mean = np.mean([f.coefficients for f in per_channel], axis=0)  # one map: achromatic
        coefficients.append(np.stack([mean] * len(per_channel)))
        fits.append(per_channel)
    frame = (white_reference.sizes["y"], white_reference.sizes["x"])
    flat = FlatField(np.stack(coefficients), legendre_powers(), frame, np.asarray(cameras))
    return flat, fits


def _white_reference_frames(
    raw: xr.Dataset, response: xr.DataArray, oecf_rgb: xr.Dataset, camera: int, saturation: int | None
) -> np.ndarray | None:
    """(y, x, channel) camera ``camera``'s white-reference series ``raw`` through its own smooth
    response (:func:`white_reference_response`, :func:`white_reference_frames`); None where
    that fit declines (too few block means, a pixel without a weighted code) or the
    response has no channel dimension."""
    if "channel" not in response.dims:
        return None
    black = camera_black_level(oecf_rgb, camera)
    n_codes = response.sizes["code"]
    top = n_codes - 1 if saturation is None else int(saturation)
    weighting = oecf_rgb.attrs.get("weighting", response.attrs.get("weighting", "gaussian"))
    counts = np.asarray(raw["counts"].isel(image=0).transpose("exposure", "y", "x", "channel").values)
    times = np.asarray(raw["exposure_time"].isel(image=0).values, dtype=np.float64)
    table = white_reference_response(counts, times, black, top, n_codes, weighting=weighting)
    if table is None:
        return None
    return white_reference_frames(counts, times, table, black, top, weighting=weighting)


def camera_black_level(oecf_rgb: xr.Dataset, camera: int) -> int:
    """Camera ``camera``'s black level in ``calibration/oecf_rgb`` (its ``black_level`` over
    ``camera``, else the group's attr, else 0) [DN]."""
    per_camera = oecf_rgb.get("black_level")
    if per_camera is not None and "camera" in per_camera.dims:
        known = per_camera["camera"].values.tolist()
        return int(per_camera.sel(camera=camera if camera in known else known[0]))
    return int(oecf_rgb.attrs.get("black_level", 0))


def camera_flat_fields(
    white_reference: xr.Dataset, oecf_rgb: xr.Dataset, cameras: list[int]
) -> FlatField:
    """:func:`rgb_flat_field` for the RGB cameras ``cameras`` (raw/rgb's): a camera without
    white-reference frames takes the map of the camera whose calibration it borrows (same
    model, ``calibration_borrowed``), else none (ones)."""
    flat, _ = rgb_flat_field(white_reference, oecf_rgb)
    _, lender_of = _camera_names(white_reference, target_cameras(white_reference))
    return flat.select(cameras, lender_of)


def spectral_flat_field(
    white_reference: xr.Dataset,
    dark: xr.Dataset,
    oecf_spectral: xr.Dataset | None,
    *,
    own_response: bool = True,
    bandwidth: float = BAND_BANDWIDTH,
) -> tuple[FlatField, list[FlatFieldFit]]:
    """The spectral camera's flat field per band from the white reference's band series.

    Per band, every exposure without a saturated pixel whose mean signal is at least
    :data:`MIN_SNR` times the dark noise (else the longest unsaturated one) is dark
    subtracted and linearised (:func:`~.linearise`), and the exposures averaged weighted by
    their exposure time (``sum f(I - dark) / sum t`` per pixel: each exposure's signal per
    second, weighted by its signal); an exposure whose saturated pixels are all hot ones
    enters without them (:func:`_entering_pixels`). The average is fitted by
    :func:`fit_flat_field`. The response
    ``f`` is the one smooth response fitted on the band series itself
    (:func:`~spectralize.nodes.calibration.flat_field_response.band_series_response`: the
    camera's recovered OECF ripples where its samples are few, and a ripple over the codes
    between a band's centre and its corners reads as falloff), with ``own_response`` false
    (or where that fit has too few blocks) ``oecf_spectral``. The bands' maps are then fitted
    as a smooth function of wavelength (:func:`~.smooth_across_bands`, a Gaussian kernel of
    ``bandwidth`` nm; 0: each band its own map): the white reference gives the bands at the
    ends of the range little light, and their own maps are noisy. Read in the pieces of
    :func:`~.series_pieces`: a batch of bands (one band of a large sensor) and the dark
    frames are in memory at a time (the series read twice with ``own_response``).

    Returns
    -------
    tuple
        The :class:`FlatField` (rows: the bands, (wavelength, term)) and the
        :class:`FlatFieldFit` of every band (its noise floor the smoothed map's).

    Raises
    ------
    CalibrationError
        A band saturated at every exposure or darker than the noise in its longest
        unsaturated one (naming ``raw/white_reference:spectral_counts``), dark frames missing.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 5 and Fig. 3.
    """
    group = "raw/white_reference"
    counts, depth = target_spectral_series(white_reference, group)
    unsaturated = ~saturated_by_band(counts, depth)
    times = np.asarray(counts["spectral_exposure_time"].values, dtype=np.float64)
    frame = (counts.sizes["y"], counts.sizes["x"])
    darks = dark_frames_at(dark, times, used_by=group, dim="shot", frame_shape=frame)
    darks = darks.drop_vars("exposure_time").transpose("shot", "y", "x").load()
    # the dark noise of each exposure (the mean of its std frame; 1 DN without one)
    noise = [
        float(darks["std"].isel(shot=e).mean()) if "std" in darks else 1.0 for e in range(times.size)
    ]
    response = oecf_spectral
    if own_response:
        table = _band_series_table(counts, darks, times, unsaturated, np.asarray(noise), depth)
        response = oecf_spectral if table is None else table
    coefficients, fits = [], []
    # per band: sum f(I - dark) and sum t per pixel, and the exposure time summed so far
    sums: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}
    # the frames of a piece of band_shots.series_pieces at once; each band's exposures
    # summed in their order, and the band fitted after its last one
    for part, positions, shots in series_pieces(counts, range(times.size)):
        mean = darks["mean"].isel(shot=positions).rename(shot="spectral_exposure")
        above = np.asarray((shots.astype(np.float64) - mean).mean(("y", "x")).values)
        signal = np.asarray(linearise(shots, mean, response, group).values)
        codes, dark_means = np.asarray(shots.values), np.asarray(mean.values)
        for b, k in enumerate(range(counts.sizes["wavelength"])[part]):
            wavelength = float(counts["wavelength"][k])
            if positions[0] == 0 and not unsaturated[k].any():
                raise CalibrationError(
                    f"{group}:spectral_counts: every exposure of band "
                    f"{wavelength} nm has saturated pixels; add shorter exposures"
                )
            total, weight, used = sums.get(k, (np.zeros(frame), np.zeros(frame), 0.0))
            fallback = int(np.flatnonzero(unsaturated[k])[-1])
            for i, e in enumerate(positions):
                enter = _entering_pixels(codes[b, i], dark_means[i], 2**depth - 1)
                if enter is None:
                    continue
                level = float(above[b, i])
                if e == fallback and used == 0 and level < max(noise[e], 1e-12):
                    raise CalibrationError(
                        f"{group}:spectral_counts: white reference band "
                        f"{wavelength} nm is darker than the noise: mean signal "
                        f"{level:.3g} DN above dark vs noise {noise[e]:.3g} DN in its longest "
                        "unsaturated exposure; use a longer exposure or more light"
                    )
                if level < MIN_SNR * max(noise[e], 1e-12) and not (used == 0 and e == fallback):
                    continue
                total = total + np.where(enter, signal[b, i] * times[e], 0.0)
                weight, used = weight + enter * times[e], used + times[e]
            sums[k] = (total, weight, used)
            if positions[-1] == times.size - 1:
                fit = fit_flat_field(total / weight)
                coefficients.append(fit.coefficients)
                fits.append(fit)
    wavelengths = np.asarray(counts["wavelength"].values, dtype=float)
    smoothed, fits = smooth_across_bands(np.stack(coefficients), fits, wavelengths, bandwidth=bandwidth)
    return FlatField(smoothed, legendre_powers(), frame, wavelengths), fits


def _entering_pixels(codes: np.ndarray, dark_mean: np.ndarray, top: int) -> np.ndarray | None:
    """(y, x) the pixels of one white-reference band frame ``codes`` that enter its band's
    average: every pixel of a frame without a saturated one; of a frame whose saturated
    pixels are all hot (their dark level ``dark_mean`` plus the frame's signal, that of its
    brightest percent of pixels, reaches the ``top`` code, the frame's median dark level plus
    it does not: dark current, not light, saturated them) the others; None where light
    saturates a pixel. A weak band's longest exposure, its best measure of the falloff, is
    then not lost to a few hot pixels."""
    saturated = codes >= top
    if not saturated.any():
        return np.ones(codes.shape, dtype=bool)
    light = float(np.percentile(codes - dark_mean, 99.0))
    hot = dark_mean + light >= top
    if float(np.median(dark_mean)) + light >= top or (saturated & ~hot).any():
        return None
    return ~saturated


def _band_series_table(
    counts: xr.DataArray,
    darks: xr.Dataset,
    times: np.ndarray,
    unsaturated: np.ndarray,
    noise: np.ndarray,
    depth: int,
) -> xr.Dataset | None:
    """The spectral camera's smooth response (:func:`band_series_response`) from the white
    reference's band series ``counts`` (wavelength, spectral_exposure, y, x) and its dark
    frames ``darks`` (shot per exposure), as a response over dark-subtracted codes for
    :func:`~.linearise`; the frames that enter are those without a saturated pixel whose mean
    signal is at least :data:`MIN_SNR` times the dark ``noise`` (a hot pixel's block mean is
    not the light's, so its frame stays out here). None where that fit declines."""
    n_bands = counts.sizes["wavelength"]
    means = variances = sizes = None
    for part, positions, shots in series_pieces(counts, range(times.size)):
        mean = darks["mean"].isel(shot=positions).rename(shot="spectral_exposure")
        above = (shots.astype(np.float64) - mean).transpose("wavelength", "spectral_exposure", "y", "x")
        block_means, block_variances, sizes = band_block_statistics(np.asarray(above.values))
        if means is None:
            means = np.zeros((n_bands, times.size, sizes.size))
            variances = np.zeros_like(means)
        cell = np.ix_(range(n_bands)[part], positions)
        means[cell], variances[cell] = block_means, block_variances
    if means is None or variances is None or sizes is None:
        return None
    level = (means * sizes).sum(axis=-1) / sizes.sum()
    usable = unsaturated & (level >= MIN_SNR * np.maximum(noise, 1e-12)[None, :])
    table = band_series_response(means, variances, sizes, times, usable, 2**depth)
    if table is None:
        return None
    return xr.Dataset(
        {
            "response": (
                "code",
                table,
                {
                    "units": "1",
                    "long_name": "the spectral camera's smooth response fitted on the white "
                    "reference's band series (relative exposure per dark-subtracted code)",
                    "dark_subtracted": True,
                },
            )
        },
        coords={"code": np.arange(2**depth, dtype=np.float64)},
    )


def _measures(prefix: str, dims: tuple, values: dict[str, np.ndarray], what: str) -> dict:
    """The noise floor and evenness measures of :class:`FlatFieldFit` as variables."""
    unit = {"units": "1"}
    long_names = {
        "noise": f"noise floor of {what}",
        "unevenness": f"largest local deviation of the white reference from {what} (a shadow, a smudge)",
        "unevenness_floor": "what the noise alone gives the unevenness",
        "gradient": f"largest odd part of {what} about the frame centre (a tilted or unevenly "
        "lit target)",
        "corner": f"corner value of {what} farthest from 1",
    }
    return {
        f"{prefix}_{name}": (dims, values[name], unit | {"long_name": long_name})
        for name, long_name in long_names.items()
    }


def _fit_values(fits: list, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """Each :class:`FlatFieldFit` measure over ``fits`` (nested lists of fits, or None where a
    camera has no map of its own: NaN) as an array of ``shape``."""
    names = ("noise", "unevenness", "unevenness_floor", "gradient", "corner")
    flat = np.asarray(fits, dtype=object).reshape(-1)
    return {
        name: np.array([np.nan if f is None else getattr(f, name) for f in flat]).reshape(shape)
        for name in names
    }


def flat_field_variables(
    rgb: FlatField,
    rgb_fits: list[list[FlatFieldFit]],
    spectral: FlatField,
    spectral_fits: list[FlatFieldFit],
    cameras: list[int],
    lender_of: dict[int, int] | None = None,
) -> xr.Dataset:
    """The flat fields' variables of ``calibration/spectral``.

    Coefficients, noise floor and evenness measures per RGB camera of ``cameras`` and channel
    (``flat_field_rgb*``, (camera, channel)): a camera without white-reference frames takes
    its lender's map (:meth:`FlatField.select`; its measures NaN), and per band
    (``flat_field*``, (wavelength,)); the Legendre orders as coords (``flat_power_y``,
    ``flat_power_x`` over ``flat_term``), the frame and the degree in the attrs.
    """
    unit = {"units": "1"}
    own = {int(k): row for k, row in zip(np.asarray(rgb.keys).tolist(), rgb_fits, strict=True)}
    per_camera = rgb.select(cameras, lender_of)
    n_channel = rgb.coefficients.shape[1]
    camera_fits = [own.get(int(k), [None] * n_channel) for k in cameras]
    rgb_dims, band_dims = ("camera", "channel"), ("wavelength",)
    return xr.Dataset(
        {
            "flat_field_rgb": (
                (*rgb_dims, "flat_term"),
                per_camera.coefficients,
                unit
                | {
                    "long_name": "Legendre coefficients of each RGB camera's flat field "
                    "(1 at the frame centre)"
                },
            ),
            **_measures(
                "flat_field_rgb",
                rgb_dims,
                _fit_values(camera_fits, (len(cameras), n_channel)),
                "the RGB flat field",
            ),
            "flat_field": (
                (*band_dims, "flat_term"),
                spectral.coefficients,
                unit
                | {
                    "long_name": "Legendre coefficients of the spectral camera's flat "
                    "field per band (1 at the frame centre)"
                },
            ),
            **_measures(
                "flat_field",
                band_dims,
                _fit_values(spectral_fits, (len(spectral_fits),)),
                "the band's flat field",
            ),
        },
        coords={
            "camera": ("camera", np.asarray(cameras, dtype=np.int64)),
            "wavelength": ("wavelength", np.asarray(spectral.keys, dtype=float)),
            "flat_power_y": ("flat_term", rgb.powers[:, 0]),
            "flat_power_x": ("flat_term", rgb.powers[:, 1]),
        },
        attrs={"flat_field_frame": [int(v) for v in rgb.frame], "flat_field_degree": DEGREE},
    )
