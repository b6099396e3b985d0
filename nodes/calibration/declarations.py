"""Radiometric calibration nodes (paper section 4): OECFs, QE, camera matrix C, HDR, bands.

The numerics live in :mod:`~spectralize.nodes.calibration.oecf` (Robertson and the low-SNR extension),
:mod:`~spectralize.nodes.calibration.hdr` (HDR merge) and :mod:`~spectralize.nodes.calibration.spectral`
(QE, C, cross-validation); this module wires them to the run store:

==========================  ===============================================================
node                        groups
==========================  ===============================================================
``recover_rgb_oecf``        raw/rgb -> calibration/oecf_rgb
``recover_spectral_oecf``   raw/white_reference, dark -> calibration/oecf_spectral
``calibrate_spectral``      raw/white_reference, raw/colour_checker, dark,
                            calibration/oecf_rgb, calibration/oecf_spectral
                            -> calibration/spectral (QE, C, cross-validation, Fig. 4)
``hdr_merge``               raw/rgb, calibration/oecf_rgb -> hdr
``calibrate_bands``         raw/spectral, dark, calibration/oecf_spectral,
                            calibration/spectral, registration -> bands
==========================  ===============================================================

Units: the RGB response is normalised to 1 at its mid code, so HDR radiance is "relative
exposure per second". The spectral response is scaled onto its own full-range Robertson
response, and ``Q`` divides the white reference's band signal by its reflectance times the
*measured illuminant*: band radiance is therefore relative to the measured illuminant (a white
diffuser of reflectance 1 under it has band radiance ``L(lambda)``). ``C`` is fitted from the
colour checker's HDR RGB against patch reflectance times the same illuminant, so it maps band
radiance units to HDR units, which is what the reconstruction needs (``RGB = C @ spectrum``).
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from pydantic import Field
from scipy import ndimage

from spectralize.engine import Node, Parameters
from spectralize.nodes.calibration.hdr import merge_hdr
from spectralize.nodes.calibration.oecf import combine_responses, recover_oecf, recover_oecf_low_snr
from spectralize.nodes.calibration.registration import register_frames
from spectralize.nodes.calibration.spectral import (
    band_signal,
    camera_matrix,
    cross_validate,
    patch_means,
    quantum_efficiency,
)
from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "RgbOecfParameters",
    "SpectralOecfParameters",
    "SpectralCalibrationParameters",
    "HdrMergeParameters",
    "BandsParameters",
    "recover_rgb_oecf",
    "recover_spectral_oecf",
    "calibrate_spectral",
    "merge_hdr_node",
    "calibrate_bands",
    "RECOVER_RGB_OECF",
    "RECOVER_SPECTRAL_OECF",
    "CALIBRATE_SPECTRAL",
    "HDR_MERGE",
    "CALIBRATE_BANDS",
]


# -- helpers ------------------------------------------------------------------------------
def _require(ds: xr.Dataset, group: str, variables: tuple[str, ...] = (),
             coords: tuple[str, ...] = ()) -> None:
    problems = [Problem(f"{group}:{name}", "a variable", "nothing")
                for name in variables if name not in ds.data_vars]
    problems += [Problem(f"{group}:{name}", "a coordinate", "nothing")
                 for name in coords if name not in ds.coords]
    if problems:
        raise SchemaError(f"{group} breaks the contract:", problems)


def _bits(ds: xr.Dataset, name: str, group: str) -> int:
    value = ds.attrs.get(name)
    if value is None or int(value) != value or not 8 <= int(value) <= 16:
        raise SchemaError(f"{group} breaks the contract:", [Problem(
            f"{group}.attrs[{name!r}]", "an ADC bit depth 8..16", repr(value))])
    return int(value)


def _spectral_series(target: xr.Dataset, group: str) -> tuple[xr.DataArray, int]:
    """``spectral_counts`` (wavelength, spectral_exposure, y, x) as an in-memory array."""
    _require(target, group, ("spectral_counts",), ("spectral_exposure_time", "wavelength"))
    depth = _bits(target, "spectral_bit_depth", group)
    counts = target["spectral_counts"].transpose("wavelength", "spectral_exposure", "y", "x")
    counts = counts.assign_coords(
        spectral_exposure_time=("spectral_exposure",
                                np.asarray(target["spectral_exposure_time"].values, float)))
    return counts.load(), depth


def _shot_frames(counts: xr.DataArray, picks: np.ndarray, depth: int,
                 group: str) -> xr.DataArray:
    """One frame per band: ``counts[band, picks[band]]`` as (shot, y, x) band shots."""
    times = counts["spectral_exposure_time"].values[picks]
    frames = counts.isel(wavelength=xr.DataArray(np.arange(picks.size), dims="shot"),
                         spectral_exposure=xr.DataArray(picks, dims="shot"))
    frames = frames.drop_vars([c for c in frames.coords if c not in ()])
    return frames.assign_coords(
        wavelength=("shot", counts["wavelength"].values.astype(float), {"units": "nm"}),
        exposure_time=("shot", times, {"units": "s"}),
    ).assign_attrs(bit_depth=depth, source=f"{group}:spectral_counts")


def _longest_unsaturated(counts: xr.DataArray, depth: int, group: str) -> np.ndarray:
    """Per band, the index of the longest exposure without a saturated pixel."""
    top = np.asarray(counts.max(("y", "x")).values) < 2**depth - 1      # (wavelength, exp)
    bad = np.flatnonzero(~top.any(axis=1))
    if bad.size:
        wl = counts["wavelength"].values[bad].tolist()
        raise CalibrationError(
            f"{group}:spectral_counts: every exposure of band(s) {wl} nm has saturated pixels "
            f"(value {2**depth - 1}); add shorter exposures")
    return np.asarray([int(np.flatnonzero(row)[-1]) for row in top])


def _dark_level(dark: xr.Dataset, times: np.ndarray, group: str) -> np.ndarray:
    """Mean dark level [DN] per exposure time; error naming the missing one."""
    _require(dark, "dark", ("mean",), ("exposure_time",))
    available = np.asarray(dark["exposure_time"].values, dtype=float)
    levels = []
    for t in np.atleast_1d(times):
        match = np.flatnonzero(np.isclose(available, t, rtol=1e-6, atol=0.0))
        if match.size == 0:
            raise CalibrationError(
                f"dark:mean has no frame for exposure_time {float(t)} s used by {group}; dark "
                f"frames exist for {available.tolist()} s. Record dark frames at every "
                "exposure time used")
        levels.append(float(dark["mean"].isel(exposure_time=int(match[0])).mean()))
    return np.asarray(levels)


def _rename_errors(error: Exception, prefix: str) -> CalibrationError:
    return CalibrationError(f"{prefix}: {error}")


# -- 1. RGB OECF --------------------------------------------------------------------------
class RgbOecfParameters(Parameters):
    """Parameters of :func:`recover_rgb_oecf`."""

    per_camera: bool = Field(False, description="one response per RGB camera (True) or one "
                             "response per channel pooled over all cameras (False)")
    black_level: int | None = Field(None, ge=0, description="codes at or below it get weight 0 "
                                    "[DN]; None: the 0.1 % quantile of the shortest exposures "
                                    "plus 3")
    weighting: str = Field("gaussian", pattern="^(gaussian|hat|uniform)$",
                           description="Robertson weighting function")
    tolerance: float = Field(1e-6, gt=0, lt=1e-2, description="convergence: largest relative "
                             "change of the response per Robertson update")
    max_pixels: int | None = Field(200_000, ge=100, description="pixel positions used per "
                                   "image (reproducible random subset); None: all")


def recover_rgb_oecf(
    raw_rgb: xr.Dataset,
    *,
    per_camera: bool = False,
    black_level: int | None = None,
    weighting: str = "gaussian",
    tolerance: float = 1e-6,
    max_pixels: int | None = 200_000,
) -> xr.Dataset:
    """RGB camera response per channel (Robertson 2003) from the raw/rgb exposure series.

    The raw/rgb images (textured sample, many light directions, exposure series with unequal
    ratios) cover the whole code range densely; the uniform white reference only gives one
    cluster of codes per exposure, so raw/rgb is used (measured on the demo run: median
    0.1 % against 1.5 % with the colour checker's series).

    Parameters
    ----------
    raw_rgb
        Group ``raw/rgb``.
    per_camera
        Recover one response per camera; otherwise pool all cameras (same sensor model) and
        copy the response to every camera.
    black_level
        Under-exposed codes (weight 0); default: the 0.1 % quantile of the shortest
        exposure's codes plus 3 DN (the ADC offset plus noise).
    weighting, tolerance, max_pixels
        See :func:`spectralize.nodes.calibration.oecf.recover_oecf`.

    Returns
    -------
    xarray.Dataset
        Group ``calibration/oecf_rgb``: ``response`` (camera, channel, code) float64
        [1], relative exposure per code normalised to 1 at the mid code; ``samples``
        (camera, channel, code). Attrs ``bit_depth``, ``black_level``, ``saturation``,
        ``weighting``, ``per_camera``, ``converged``, ``iterations``.

    Raises
    ------
    SchemaError, CalibrationError
        See :func:`~spectralize.nodes.calibration.oecf.recover_oecf` (mismatched shapes, unsorted or
        duplicate exposure times, all-saturated or all-dark frames).
    """
    _require(raw_rgb, "raw/rgb", ("counts",), ("exposure_time", "camera", "channel"))
    depth = _bits(raw_rgb, "bit_depth", "raw/rgb")
    counts = raw_rgb["counts"]
    cameras = np.asarray(raw_rgb["camera"].values)
    if black_level is None:
        shortest = counts.isel(exposure=0)
        if shortest.sizes["image"] > 8:
            shortest = shortest.isel(image=slice(0, None, shortest.sizes["image"] // 8))
        black_level = int(np.quantile(np.asarray(shortest.values), 0.001)) + 3
    data = raw_rgb[["counts"]].assign_attrs(bit_depth=depth)
    if not per_camera:
        data = data.drop_vars("camera")
    result = recover_oecf(data, black_level=black_level, weighting=weighting,  # type: ignore[arg-type]
                          tolerance=tolerance, max_pixels=max_pixels)
    response = result["response"]
    samples = response["samples"].drop_vars("samples", errors="ignore")
    response = response.drop_vars("samples")
    if not per_camera:
        unique = np.unique(cameras)
        response = response.expand_dims(camera=unique)
        samples = samples.expand_dims(camera=unique)
    response = response.transpose("camera", "channel", "code")
    samples = samples.transpose("camera", "channel", "code")
    attrs = dict(response.attrs)
    out = xr.Dataset(
        {"response": response.assign_attrs(attrs),
         "samples": samples.assign_attrs(
             units="1", long_name="samples per code (0: interpolated)")},
        attrs={"bit_depth": depth, "black_level": int(black_level),
               "saturation": int(attrs.get("saturation", 2**depth - 1)),
               "weighting": weighting, "per_camera": bool(per_camera),
               "converged": bool(attrs.get("converged", True)),
               "iterations": int(attrs.get("iterations", 0)),
               "source": "raw/rgb"},
    )
    out["camera"].attrs.update(long_name="RGB camera index")
    return out


# -- 2. spectral OECF ---------------------------------------------------------------------
class SpectralOecfParameters(Parameters):
    """Parameters of :func:`recover_spectral_oecf`."""

    band: float | None = Field(None, description="wavelength [nm] of the white reference's "
                               "exposure series used for the low-SNR extension; None: the band "
                               "with the most unsaturated exposures at low signal")
    low_signal_fraction: float = Field(0.15, gt=0, le=1, description="exposures whose mean "
                                       "signal above dark is at most this fraction of the "
                                       "code range form the low-SNR series")
    filter_size: float = Field(25.0, gt=0, description="Gaussian filter size of the "
                               "low-SNR extension [px] (sigma = size / 5)")
    full_exposures: int = Field(4, ge=2, description="longest unsaturated exposures per band "
                                "used for the full-range Robertson response")
    tolerance: float = Field(1e-6, gt=0, lt=1e-2, description="Robertson convergence tolerance")


def _low_snr_choice(counts: xr.DataArray, dark: xr.Dataset, depth: int, band: float | None,
                    fraction: float) -> tuple[int, np.ndarray]:
    group = "raw/white_reference"
    times = counts["spectral_exposure_time"].values
    level = _dark_level(dark, times, group)
    mean = np.asarray(counts.mean(("y", "x")).values) - level[None, :]
    unsaturated = np.asarray(counts.max(("y", "x")).values) < 2**depth - 1
    low = unsaturated & (mean <= fraction * (2**depth - 1 - level.mean()))
    wavelengths = counts["wavelength"].values
    if band is None:
        score = [(int(low[j].sum()), float(mean[j][low[j]].max()) if low[j].any() else -1.0)
                 for j in range(low.shape[0])]
        j = max(range(len(score)), key=lambda k: score[k])
    else:
        hit = np.flatnonzero(np.isclose(wavelengths, band, atol=1e-6))
        if hit.size == 0:
            raise CalibrationError(f"{group}:wavelength has no band at {band} nm; bands: "
                                   f"{wavelengths.tolist()}")
        j = int(hit[0])
    picks = np.flatnonzero(low[j])
    if picks.size < 2:
        raise CalibrationError(
            f"{group}:spectral_counts: band {wavelengths[j]} nm has {picks.size} unsaturated "
            f"exposure(s) with signal below {fraction:g} of the range (mean signal above dark "
            f"{np.round(mean[j], 2).tolist()} DN); the low-SNR extension needs at least 2")
    return j, picks


def recover_spectral_oecf(
    white_reference: xr.Dataset,
    dark: xr.Dataset,
    *,
    band: float | None = None,
    low_signal_fraction: float = 0.15,
    filter_size: float = 25.0,
    full_exposures: int = 4,
    tolerance: float = 1e-6,
) -> xr.Dataset:
    """Spectral camera response: the paper's low-SNR extension joined to a full-range one.

    1. Low end: :func:`~spectralize.nodes.calibration.oecf.recover_oecf_low_snr` on the white
       reference's exposure series of one band (``band``, default the band with the most
       unsaturated exposures whose mean signal is below ``low_signal_fraction`` of the
       range): dark subtracted (negative values kept), Gaussian-filtered, stretched, Robertson.
       Only unsaturated exposures are passed.
    2. Full range: :func:`~spectralize.nodes.calibration.oecf.recover_oecf` over raw codes on the
       ``full_exposures`` longest unsaturated exposures of every band (each band one
       "image" with its own exposure times): the bands' different brightness spreads the
       samples over the whole code range.
    3. :func:`~spectralize.nodes.calibration.oecf.combine_responses` scales the low-SNR response onto
       the full one and cross-fades them (default overlap: 50..90 % of the low interval).

    Returns
    -------
    xarray.Dataset
        Group ``calibration/oecf_spectral``: ``response`` (code) [1], ``code`` = pixel value
        above the dark frame [DN] (fractional, may be negative), variable attrs
        ``dark_subtracted=True`` and ``dark_level``; plus the parts ``low_snr_response``
        (low_snr_code) and ``full_response`` (raw_code) for diagnostics. Group attrs
        ``band``, ``low_snr_exposure_time``, ``filter_size``, ``overlap``, ``scale``.

    Raises
    ------
    CalibrationError
        A dark frame missing for an exposure time (naming ``dark:mean`` and the time), too
        few low-signal exposures, bands saturated in every exposure.
    """
    group = "raw/white_reference"
    counts, depth = _spectral_series(white_reference, group)
    j, picks = _low_snr_choice(counts, dark, depth, band, low_signal_fraction)
    series = counts.isel(wavelength=j, spectral_exposure=picks).rename(
        spectral_exposure="exposure").rename(spectral_exposure_time="exposure_time")
    series = series.drop_vars([c for c in series.coords if c != "exposure_time"])
    series = series.assign_attrs(bit_depth=depth)
    mean_dark = dark["mean"].load()
    try:
        low = recover_oecf_low_snr(series, mean_dark, filter_size=filter_size,
                                   tolerance=tolerance)
    except CalibrationError as error:
        raise _rename_errors(error, f"{group}:spectral_counts (band "
                             f"{float(counts['wavelength'][j])} nm)") from None

    # full range: the longest `full_exposures` unsaturated exposures of every band
    top = np.asarray(counts.max(("y", "x")).values) < 2**depth - 1
    rows, times = [], []
    all_times = counts["spectral_exposure_time"].values
    for k in range(counts.sizes["wavelength"]):
        ok = np.flatnonzero(top[k])
        if ok.size >= full_exposures:
            chosen = ok[-full_exposures:]
            rows.append(counts.isel(wavelength=k, spectral_exposure=chosen).values)
            times.append(all_times[chosen])
    if len(rows) == 0:
        raise CalibrationError(
            f"{group}:spectral_counts: no band has {full_exposures} unsaturated exposures "
            "for the full-range response")
    _dark_level(dark, np.unique(np.concatenate(times)), group)
    full_in = xr.DataArray(np.stack(rows), dims=("image", "exposure", "y", "x"),
                           coords={"exposure_time": (("image", "exposure"), np.stack(times))},
                           attrs={"bit_depth": depth})
    try:
        full = recover_oecf(full_in, tolerance=tolerance)
    except CalibrationError as error:
        raise _rename_errors(error, f"{group}:spectral_counts (full range)") from None
    combined = combine_responses(low, full)
    response = combined["response"]
    low_r = low["response"].rename(code="low_snr_code").rename("low_snr_response")
    full_r = full["response"].rename(code="raw_code").rename("full_response")
    out = xr.Dataset(
        {"response": response.drop_vars("samples"),
         "low_snr_response": low_r.drop_vars("samples").assign_attrs(
             long_name="low-SNR response (paper's extension), before scaling"),
         "full_response": full_r.drop_vars("samples").assign_attrs(
             long_name="full-range Robertson response over raw codes")},
        attrs={"bit_depth": depth, "band": float(counts["wavelength"][j]),
               "low_snr_exposure_time": [float(t) for t in series["exposure_time"].values],
               "filter_size": float(filter_size), "full_exposures": int(full_exposures),
               "full_bands": len(rows), "dark_level": float(response.attrs["dark_level"]),
               "overlap": [float(v) for v in response.attrs["overlap"]],
               "scale": float(response.attrs["scale"]),
               "converged": bool(response.attrs.get("converged", True)),
               "source": group},
    )
    out["code"].attrs.update(units="DN", long_name="pixel value above the dark frame")
    out["low_snr_code"].attrs.update(units="DN", long_name="pixel value above the dark frame")
    out["raw_code"].attrs.update(units="DN", long_name="raw pixel value")
    return out


# -- 3. QE, C and cross-validation --------------------------------------------------------
class SpectralCalibrationParameters(Parameters):
    """Parameters of :func:`calibrate_spectral`."""

    smoothness: float = Field(1e-3, ge=0, description="relative weight of the second-difference "
                              "penalty of C")
    nonnegative: bool = Field(True, description="constrain C >= 0")
    patch_margin: int = Field(2, ge=0, description="pixels removed at every patch border "
                              "(misregistration, blur) before patch means; less where a "
                              "patch would vanish")
    min_snr: float = Field(1.0, gt=0, description="smallest accepted per-pixel SNR of the "
                           "white reference in a band")


def _rgb_series(target: xr.Dataset, group: str) -> xr.Dataset:
    """The target's RGB exposure series as a one-image raw/rgb Dataset (usable exposures)."""
    _require(target, group, ("rgb_counts",), ("rgb_exposure_time", "channel"))
    depth = _bits(target, "rgb_bit_depth", group)
    counts = target["rgb_counts"].transpose("rgb_exposure", "y", "x", "channel").load()
    sat = 2**depth - 1
    usable = (np.asarray((counts < sat).any(("y", "x")).values).all(axis=1)
              & np.asarray((counts > 0).any(("y", "x")).values).all(axis=1))
    if usable.sum() < 1:
        raise CalibrationError(f"{group}:rgb_counts: every exposure is saturated or dark")
    counts = counts.isel(rgb_exposure=np.flatnonzero(usable))
    times = np.asarray(target["rgb_exposure_time"].values, dtype=float)[usable]
    camera = int(target.attrs.get("rgb_camera", 0))
    data = counts.rename(rgb_exposure="exposure").drop_vars(
        [c for c in counts.coords if c != "channel"]).expand_dims(image=[0])
    return xr.Dataset({"counts": data},
                      coords={"exposure_time": (("image", "exposure"), times[None]),
                              "camera": ("image", [camera])},
                      attrs={"bit_depth": depth})


def _eroded_labels(labels: np.ndarray, margin: int) -> np.ndarray:
    if margin <= 0:
        return labels
    out = np.full_like(labels, -1)
    for k in np.unique(labels[labels >= 0]):
        patch = labels == k
        for iterations in range(margin, -1, -1):   # small patches: erode less, keep pixels
            inner = ndimage.binary_erosion(patch, iterations=iterations) if iterations else patch
            if inner.any():
                break
        out[inner] = k
    return out


def calibrate_spectral(
    white_reference: xr.Dataset,
    colour_checker: xr.Dataset,
    dark: xr.Dataset,
    oecf_rgb: xr.Dataset,
    oecf_spectral: xr.Dataset,
    *,
    smoothness: float = 1e-3,
    nonnegative: bool = True,
    patch_margin: int = 2,
    min_snr: float = 1.0,
) -> xr.Dataset:
    """Quantum efficiency, camera matrix C and the cross-validation of paper Fig. 4.

    - ``Q`` per band: the white reference's longest unsaturated exposure of each band,
      linearised with the spectral response, per second, divided by the target reflectance
      times the measured illuminant (:func:`~spectralize.nodes.calibration.spectral.
      quantum_efficiency`).
    - ``C``: the colour checker's RGB exposure series merged to HDR with the RGB response
      (:func:`~spectralize.nodes.calibration.hdr.merge_hdr`), patch means, against patch reflectance
      times the measured illuminant (:func:`~spectralize.nodes.calibration.spectral.
      camera_matrix`, non-negative, smooth).
    - Cross-validation: the spectral camera's capture of the checker (longest unsaturated
      exposure per band, band signal / Q, patch means) through ``C`` against the measured
      HDR RGB (:func:`~spectralize.nodes.calibration.spectral.cross_validate`).

    Returns
    -------
    xarray.Dataset
        Group ``calibration/spectral``: ``quantum_efficiency`` (wavelength) [1],
        ``camera_matrix`` (channel, wavelength) [1], ``measured_rgb`` / ``predicted_rgb``
        (patch, channel) [1], ``relative_error`` (patch) [1], ``patch_spectra`` (patch,
        wavelength) [1] (from the spectral camera), ``qe_snr`` (wavelength) [1].
        Attrs ``mean_relative_error``, ``max_relative_error``, ``worst_patch``,
        ``c_relative_rms_residual``.

    Raises
    ------
    CalibrationError
        A white reference darker than the noise (naming ``raw/white_reference:
        spectral_counts``, band and values), dark frames missing for an exposure time, RGB
        series without a usable exposure.
    """
    # -- Q from the white reference
    white_counts, depth = _spectral_series(white_reference, "raw/white_reference")
    _require(white_reference, "raw/white_reference", ("illuminant", "target_reflectance"))
    picks = _longest_unsaturated(white_counts, depth, "raw/white_reference")
    shots = _shot_frames(white_counts, picks, depth, "raw/white_reference")
    _dark_level(dark, shots["exposure_time"].values, "raw/white_reference")
    illuminant = white_reference["illuminant"].load()
    try:
        qe = quantum_efficiency(shots, dark, illuminant,
                                reflectance=white_reference["target_reflectance"].load(),
                                response=oecf_spectral, min_snr=min_snr)
    except CalibrationError as error:
        raise _rename_errors(error, "raw/white_reference:spectral_counts") from None
    q = qe["quantum_efficiency"]

    # -- C from the colour checker's HDR RGB
    group = "raw/colour_checker"
    _require(colour_checker, group, ("patch_reflectance", "patch_index", "illuminant"))
    rgb_raw = _rgb_series(colour_checker, group)
    response = oecf_rgb["response"]
    camera = int(rgb_raw["camera"].values[0])
    if "camera" in response.dims:
        if camera not in response["camera"].values.tolist():
            camera = int(response["camera"].values[0])
        response = response.sel(camera=camera)
    rgb_raw = rgb_raw.drop_vars("camera")
    hdr = merge_hdr(rgb_raw, response.assign_attrs(oecf_rgb.attrs | response.attrs))
    labels = _eroded_labels(np.asarray(colour_checker["patch_index"].values), patch_margin)
    names = [str(v) for v in colour_checker["patch_name"].values] \
        if "patch_name" in colour_checker.coords else None
    measured = patch_means(hdr["radiance"].isel(image=0), labels).compute()
    spectra = (colour_checker["patch_reflectance"] * colour_checker["illuminant"]).load()
    spectra = spectra.assign_coords(patch=measured["patch"].values)
    cm = camera_matrix(measured, spectra.transpose("patch", "wavelength"),
                       smoothness=smoothness, nonnegative=nonnegative)

    # -- cross-validation: the spectral camera's capture of the checker through C
    checker_counts, cdepth = _spectral_series(colour_checker, group)
    cpicks = _longest_unsaturated(checker_counts, cdepth, group)
    cshots = _shot_frames(checker_counts, cpicks, cdepth, group)
    _dark_level(dark, cshots["exposure_time"].values, group)
    signal = band_signal(cshots, dark, response=oecf_spectral)
    q_shot = q.sel(wavelength=cshots["wavelength"].values).values
    band_radiance = (signal / xr.DataArray(q_shot, dims="shot")).compute()
    band_radiance = band_radiance.swap_dims(shot="wavelength").drop_vars(
        [c for c in band_radiance.coords if c != "wavelength"])
    patch_spectra = patch_means(band_radiance, labels).assign_coords(
        patch=measured["patch"].values)
    table = cross_validate(measured, patch_spectra, cm)

    unit = {"units": "1"}
    out = xr.Dataset(
        {
            "quantum_efficiency": q.assign_attrs(
                **unit, long_name="relative quantum efficiency Q (band signal per unit of the "
                "measured illuminant)"),
            "qe_snr": qe["snr"].assign_attrs(**unit, long_name="per-pixel SNR of the white "
                                             "reference"),
            "camera_matrix": cm["camera_matrix"].assign_attrs(
                **unit, long_name="RGB camera matrix C (HDR units per band radiance unit)"),
            "measured_rgb": table["measured"].assign_attrs(
                **unit, long_name="HDR RGB radiance of the patch, measured"),
            "predicted_rgb": table["predicted"].assign_attrs(
                **unit, long_name="RGB predicted through C from the spectral capture"),
            "relative_error": table["relative_error"].assign_attrs(
                **unit, long_name="|predicted - measured| / |measured| per patch"),
            "patch_spectra": patch_spectra.transpose("patch", "wavelength").assign_attrs(
                **unit, long_name="patch band radiance from the spectral camera"),
        },
        attrs={"mean_relative_error": table.attrs["mean_relative_error"],
               "max_relative_error": table.attrs["max_relative_error"],
               "worst_patch": table.attrs["worst_patch"],
               "c_relative_rms_residual": cm.attrs["relative_rms_residual"],
               "smoothness": float(smoothness), "nonnegative": bool(nonnegative),
               "patch_margin": int(patch_margin), "rgb_camera": camera,
               "units_note": "band radiance relative to the measured illuminant; C maps it to "
                             "HDR units (RGB = C @ spectrum)"},
    )
    out = out.drop_vars([c for c in out.coords if c not in
                         ("wavelength", "channel", "patch")])
    if names is not None:
        out = out.assign_coords(patch_name=("patch", names))
    out["wavelength"].attrs.update(units="nm", long_name="band centre wavelength")
    return out


# -- 4. HDR merge -------------------------------------------------------------------------
class HdrMergeParameters(Parameters):
    """Parameters of :func:`merge_hdr_node`."""

    black_level: int | None = Field(None, ge=0, description="under-exposed codes [DN]; None: "
                                    "the response's black_level")
    saturation: int | None = Field(None, ge=1, description="saturated codes [DN]; None: the "
                                   "response's")


def merge_hdr_node(
    raw_rgb: xr.Dataset,
    oecf_rgb: xr.Dataset,
    *,
    black_level: int | None = None,
    saturation: int | None = None,
) -> xr.Dataset:
    """HDR RGB radiance of every raw/rgb image (Robertson's estimator), lazy per chunk.

    Returns
    -------
    xarray.Dataset
        Group ``hdr``: ``radiance`` (image, y, x, channel) float32 [1] and the per-image
        coords of raw/rgb.
    """
    _require(oecf_rgb, "calibration/oecf_rgb", ("response",))
    response = oecf_rgb["response"]
    response = response.assign_attrs({**oecf_rgb.attrs, **response.attrs})
    if not black_level and black_level != 0:
        black_level = int(oecf_rgb.attrs.get("black_level", 0))
    out = merge_hdr(raw_rgb, response, black_level=black_level, saturation=saturation)
    out["radiance"] = out["radiance"].astype(np.float32).assign_attrs(
        units="1", long_name="relative RGB radiance")
    return out


# -- 5. band radiance ---------------------------------------------------------------------
class BandsParameters(Parameters):
    """Parameters of :func:`calibrate_bands`."""

    filter_size: float | None = Field(None, gt=0, description="filter size [px] for shots "
                                      "when raw/spectral has no filter_size coord")
    order: int = Field(1, ge=0, le=5, description="spline order of the registration resampling")


def calibrate_bands(
    raw_spectral: xr.Dataset,
    dark: xr.Dataset,
    oecf_spectral: xr.Dataset,
    spectral: xr.Dataset,
    registration: xr.Dataset,
    *,
    filter_size: float | None = None,
    order: int = 1,
) -> xr.Dataset:
    """Band radiance of every shot: ``band_signal / Q(lambda_shot)``, registered to RGB.

    Dark subtracted (negative values kept, never clipped), linearised with the spectral
    response, per second, divided by the quantum efficiency at the shot's wavelength (so in
    units of the measured illuminant, matching ``C``) and resampled onto the RGB pixel grid
    with :func:`~spectralize.nodes.calibration.registration.register_frames`. Lazy (dask).

    Returns
    -------
    xarray.Dataset
        Group ``bands``: ``radiance`` (shot, y, x) float32 [1]; per-shot coords of
        raw/spectral plus ``filter_size`` [px].

    Raises
    ------
    CalibrationError
        A dark frame missing for a shot's exposure time, a shot wavelength without QE.
    SchemaError
        No filter size (neither the coord nor the parameter), no registration shift.
    """
    _require(raw_spectral, "raw/spectral", ("counts",), ("wavelength", "exposure_time"))
    _require(spectral, "calibration/spectral", ("quantum_efficiency",))
    _require(registration, "registration", ("shift",))
    if "filter_size" in raw_spectral.coords:
        sizes = raw_spectral["filter_size"]
    elif filter_size is not None:
        sizes = xr.full_like(raw_spectral["exposure_time"], float(filter_size))
    else:
        raise SchemaError("cannot calibrate bands:", [Problem(
            "raw/spectral:filter_size", "a per-shot coord [px] or the filter_size parameter",
            "nothing")])
    wavelengths = np.asarray(raw_spectral["wavelength"].values, dtype=float)
    q = spectral["quantum_efficiency"].load()
    grid = np.asarray(q["wavelength"].values, dtype=float)
    idx = np.array([int(np.argmin(np.abs(grid - w))) for w in wavelengths], dtype=int)
    missing = np.flatnonzero(np.abs(grid[idx] - wavelengths) > 1e-6) if grid.size else \
        np.arange(wavelengths.size)
    if missing.size:
        raise CalibrationError(
            f"calibration/spectral:quantum_efficiency has no band at {wavelengths[missing]} nm "
            f"(shots of raw/spectral); it covers {grid.tolist()} nm")
    q_shot = xr.DataArray(np.asarray(q.values, dtype=float)[idx], dims="shot")
    if not np.all(q_shot.values > 0):
        raise CalibrationError(
            "calibration/spectral:quantum_efficiency is not positive at "
            f"{wavelengths[~(q_shot.values > 0)].tolist()} nm")
    counts = raw_spectral["counts"]
    if counts.chunks is None:
        counts = counts.chunk({"shot": 8})
    counts = counts.chunk({"y": -1, "x": -1})
    signal = band_signal(raw_spectral.assign(counts=counts), dark, response=oecf_spectral)
    radiance = (signal / q_shot).astype(np.float32)
    if radiance.chunks is not None:
        radiance = radiance.chunk({"y": -1, "x": -1})
    radiance = register_frames(radiance, registration["shift"], order=order)
    keep = [c for c in raw_spectral.coords if raw_spectral[c].dims == ("shot",)]
    radiance = radiance.drop_vars([c for c in radiance.coords if c not in keep])
    radiance = radiance.assign_attrs(units="1", long_name="relative band radiance (units of "
                                     "the measured illuminant), registered to the RGB camera")
    coords = {c: raw_spectral[c] for c in keep}
    coords["filter_size"] = ("shot", np.asarray(sizes.values, dtype=float),
                             {"units": "px", "long_name": "Gaussian filter size s_i (eq. 3)"})
    return xr.Dataset({"radiance": radiance}, coords=coords,
                      attrs={"registration_shift_px": [float(v) for v in
                                                       registration["shift"].values],
                             "negative_values": "kept (noise below the dark level)"})


RECOVER_RGB_OECF = Node(
    name="recover_rgb_oecf", version="1", function=recover_rgb_oecf,
    inputs={"raw_rgb": "raw/rgb"}, outputs=("calibration/oecf_rgb",),
    parameters=RgbOecfParameters,
    description="RGB camera response per channel by Robertson 2003 from raw/rgb (sec. 4).",
)

RECOVER_SPECTRAL_OECF = Node(
    name="recover_spectral_oecf", version="1", function=recover_spectral_oecf,
    inputs={"white_reference": "raw/white_reference", "dark": "dark"},
    outputs=("calibration/oecf_spectral",), parameters=SpectralOecfParameters,
    description="Spectral camera response: low-SNR extension joined to Robertson (sec. 4).",
)

CALIBRATE_SPECTRAL = Node(
    name="calibrate_spectral", version="1", function=calibrate_spectral,
    inputs={"white_reference": "raw/white_reference", "colour_checker": "raw/colour_checker",
            "dark": "dark", "oecf_rgb": "calibration/oecf_rgb",
            "oecf_spectral": "calibration/oecf_spectral"},
    outputs=("calibration/spectral",), parameters=SpectralCalibrationParameters,
    description="Quantum efficiency, camera matrix C and cross-validation (sec. 4, Fig. 4).",
)

HDR_MERGE = Node(
    name="hdr_merge", version="1", function=merge_hdr_node,
    inputs={"raw_rgb": "raw/rgb", "oecf_rgb": "calibration/oecf_rgb"}, outputs=("hdr",),
    parameters=HdrMergeParameters,
    description="HDR RGB radiance from the exposure series (Robertson), lazy per chunk.",
)

CALIBRATE_BANDS = Node(
    name="calibrate_bands", version="1", function=calibrate_bands,
    inputs={"raw_spectral": "raw/spectral", "dark": "dark",
            "oecf_spectral": "calibration/oecf_spectral", "spectral": "calibration/spectral",
            "registration": "registration"},
    outputs=("bands",), parameters=BandsParameters,
    description="Band radiance (signal / Q), registered onto the RGB grid, filter size per shot.",
)

