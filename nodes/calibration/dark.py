"""Dark frames (paper section 4, "Calibration"): averaging them, and finding them again.

The spectral camera works close to its noise floor, so its dark current must be known
exactly for every pixel: many closed-shutter frames are taken per exposure time and averaged
with floating-point accuracy (the paper uses 200 per exposure time). Every later step
subtracts the mean dark frame of the *same* exposure time; :func:`dark_frames_at` is the one
place that looks it up.

A lab that takes a handful of frames per exposure time leaves about ``sigma_read / sqrt(N)``
of noise in each mean, as much as the signal of a weak band (a band a few DN above the dark
level is then dominated by its dark frame's noise, and its radiance ripples from band to band).
A pixel's dark level is, to well within that noise, an offset plus a dark current times the
exposure time, ``d(t) = a + b t``; fitted per pixel over the frames of *all* exposure times
(:func:`linear_dark`, ``model="linear"``, the default), it averages every frame of the
series. Pixels where the line does not hold within the frames' own noise (a hot pixel that
saturates, a response that bends), and pixels with a frame at the ADC's maximum, keep their
mean per exposure time.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 (dark frames, 200 per exposure time).
"""

from __future__ import annotations

import warnings
from typing import Annotated

import dask
import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "average_dark_frames",
    "dark_frames_at",
    "linear_dark",
    "DARK_MODELS",
    "EXPOSURE_TIME_RTOL",
    "LINEAR_DARK_TOLERANCE",
]

EXPOSURE_TIME_RTOL: float = 1e-6
"""Relative tolerance within which a dark frame's exposure time matches a shot's."""

DARK_MODELS = ("linear", "per-time")
"""How :func:`average_dark_frames` gives the mean dark frame: a line in exposure time per pixel
over all frames (:func:`linear_dark`) or the mean of each exposure time's frames alone."""

LINEAR_DARK_BLOCK = 2**22
"""Values (exposure time x pixel) :func:`average_dark_frames` fits a line through at a time."""

LINEAR_DARK_TOLERANCE: float = 3.0
"""A pixel keeps its per-exposure-time means where the line's squared residuals exceed this
many times the noise of those means (chi-square per degree of freedom)."""


def linear_dark(
    mean: np.ndarray,
    variance: np.ndarray,
    exposure_time: np.ndarray,
    frames: int,
    usable: np.ndarray,
    *,
    tolerance: float = LINEAR_DARK_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel, the line ``a + b t`` through the dark means of all exposure times.

    Least squares over the exposure times ``t_k`` a pixel has ``usable`` (no frame at the
    ADC's maximum), every mean of ``frames`` frames; where fewer than three are usable, or
    where ``chi2 = sum_k r_k^2 / sum_k (s_k^2 / N) * K / (K - 2)`` exceeds ``tolerance`` (the
    line's residuals ``r_k`` against the means' own noise, ``s_k^2`` the frames' sample
    variance), the pixel keeps its means per exposure time.

    Parameters
    ----------
    mean, variance
        (exposure_time, y, x) per-time mean [DN] and sample variance [DN^2] of the frames.
    exposure_time
        (exposure_time,) [s].
    frames
        ``N``, frames per exposure time.
    usable
        (exposure_time, y, x) bool.
    tolerance
        Largest accepted ``chi2`` per degree of freedom.

    Returns
    -------
    tuple of numpy.ndarray
        The mean dark frames (exposure_time, y, x) [DN] and the (y, x) bool map of pixels
        on the line.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (dark frames).
    .. [2] European Machine Vision Association, Standard 1288 (release 4.0, 2021), section 6
       (dark signal linear in exposure time: offset plus dark current).
    """
    t = np.asarray(exposure_time, dtype=np.float64)[:, None, None]
    w = np.asarray(usable, dtype=np.float64)
    m = np.asarray(mean, dtype=np.float64)
    s0, s1, s2 = w.sum(0), (w * t).sum(0), (w * t * t).sum(0)
    y0, y1 = (w * m).sum(0), (w * t * m).sum(0)
    det = s0 * s2 - s1 * s1
    ok = (s0 >= 3) & (det > 1e-12 * np.maximum(s2 * s0, 1e-300))
    safe = np.where(ok, det, 1.0)
    slope = np.where(ok, (s0 * y1 - s1 * y0) / safe, 0.0)
    offset = np.where(ok, (y0 - slope * s1) / np.maximum(s0, 1.0), 0.0)
    line = offset[None] + slope[None] * t
    residual = (w * (m - line) ** 2).sum(0)
    expected = (w * np.asarray(variance, dtype=np.float64) / frames).sum(0)
    dof = np.maximum(s0 - 2.0, 1.0) / np.maximum(s0, 1.0)
    ok &= residual <= tolerance * dof * np.maximum(expected, 1e-300)
    return np.where(ok[None], line, m), ok


def average_dark_frames(
    raw_dark: xr.Dataset,
    *,
    frames_per_chunk: Annotated[int, Field(ge=1, description="dark frames read per dask chunk")] = 16,
    ddof: Annotated[
        int, Field(ge=0, le=1, description="delta degrees of freedom of the std (1: sample)")
    ] = 1,
    model: Annotated[
        str,
        Field(
            pattern="^(linear|per-time)$",
            description="'linear': per pixel a line in exposure time through the frames of all "
            "exposure times (where it holds within their noise); 'per-time': the mean of each "
            "exposure time's frames alone",
        ),
    ] = "linear",
) -> xr.Dataset:
    """Per-pixel mean and standard deviation of raw dark frames, per exposure time.

    ``model="per-time"``: ``mean[t, y, x] = (1/N) sum_k frames[t, k, y, x]``; ``"linear"``
    (default): per pixel the line ``a + b t`` through those means (:func:`linear_dark`),
    which averages the frames of every exposure time, where it holds within their noise
    (three or more exposure times). ``std`` is the sample standard deviation over the ``N``
    frames ``k`` of exposure time ``t`` in both. The mean is the dark frame subtracted from
    every shot of the same exposure time before the low-SNR OECF recovery (paper section 4)
    and before band radiance is computed.
    The frames are streamed with dask ``frames_per_chunk`` at a time and reduced in float64,
    so the whole stack is never in memory.

    Parameters
    ----------
    raw_dark
        Group ``raw/dark``: ``frames`` (exposure_time, frame, y, x) uint16 [DN], attrs
        ``bit_depth`` and ``camera`` (the engine checks the group against its schema).
    frames_per_chunk
        Frames per dask chunk while streaming.
    ddof
        Delta degrees of freedom of the standard deviation (1: unbiased sample variance).
    model
        ``"linear"`` or ``"per-time"`` (:data:`DARK_MODELS`).

    Returns
    -------
    xarray.Dataset
        Group ``dark``: ``mean`` and ``std`` (exposure_time, y, x) float32 [DN]. Attrs
        ``dark_model`` and, for ``"linear"``, ``pixels_on_line`` (the share of pixels whose
        mean is the line).

    Raises
    ------
    SchemaError
        If ``raw_dark`` has fewer than ``ddof + 1`` frames per exposure time.

    Warns
    -----
    RuntimeWarning
        When frames at the ADC's maximum code are found (hot pixels in long darks, a light
        leak or a wrong bit depth): the mean per exposure time is then biased there, and is
        reported rather than silently clipped (``"linear"`` leaves those frames out of the
        pixel's line).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (dark frames, 200 per exposure
       time).
    """
    if raw_dark.sizes["frame"] < ddof + 1:
        raise SchemaError(
            "cannot average dark frames:",
            [
                Problem(
                    "raw/dark:frames",
                    f"at least {ddof + 1} frames per exposure time",
                    f"{raw_dark.sizes['frame']}",
                )
            ],
        )

    max_code = 2 ** int(raw_dark.attrs["bit_depth"]) - 1
    frames = raw_dark["frames"].chunk({"frame": frames_per_chunk}).data
    as_float = frames.astype(np.float64)
    if model not in DARK_MODELS:
        raise CalibrationError(f"average_dark_frames: model must be one of {DARK_MODELS}, got {model!r}")
    # One pass over the stack: mean, std and the saturation counts share the same reads.
    mean, std, at_max = dask.compute(
        as_float.mean(axis=1), as_float.std(axis=1, ddof=ddof), (frames >= max_code).sum(axis=1)
    )
    saturated = int(at_max.sum())
    if saturated:
        pixels = int((at_max > 0).any(axis=0).sum())
        warnings.warn(
            f"raw/dark:frames has {saturated} pixel value(s) at the maximum code {max_code} "
            f"in {pixels} pixel(s): hot pixels in long darks, a light leak or a wrong "
            "bit_depth; the mean of those frames is biased low there",
            RuntimeWarning,
            stacklevel=2,
        )
    attrs: dict = {"dark_model": "mean of each exposure time's frames"}
    times = np.asarray(raw_dark["exposure_time"].values, dtype=np.float64)
    if model == "linear" and np.unique(times).size >= 3:
        n = int(raw_dark.sizes["frame"])
        mean = np.array(mean, dtype=np.float64)
        on_line = np.zeros(mean.shape[1:], dtype=bool)
        rows = max(1, LINEAR_DARK_BLOCK // max(mean.shape[0] * mean.shape[2], 1))
        for y in range(0, mean.shape[1], rows):  # a block of rows at a time: bounded memory
            block = slice(y, y + rows)
            variance = std[:, block] ** 2 * (n - ddof) / max(n - 1, 1)  # the sample variance
            mean[:, block], on_line[block] = linear_dark(
                mean[:, block], variance, times, n, at_max[:, block] == 0
            )
        attrs = {
            "dark_model": "per pixel a line in exposure time through all frames "
            "(linear_dark), the per-time mean where it does not hold",
            "pixels_on_line": float(on_line.mean()),
        }
    dims = ("exposure_time", "y", "x")

    out = xr.Dataset(
        {
            "mean": (dims, mean.astype(np.float32), {"units": "DN", "long_name": "mean dark frame"}),
            "std": (
                dims,
                std.astype(np.float32),
                {"units": "DN", "long_name": "per-pixel standard deviation of the dark frames"},
            ),
        },
        coords={"exposure_time": raw_dark["exposure_time"]},
        attrs={
            "frame_count": int(raw_dark.sizes["frame"]),
            "camera": str(raw_dark.attrs["camera"]),
            "bit_depth": int(raw_dark.attrs["bit_depth"]),
            "std_ddof": ddof,
            **attrs,
        },
    )
    return out


def dark_frames_at(
    dark: xr.Dataset | xr.DataArray,
    exposure_time: np.ndarray | xr.DataArray,
    *,
    used_by: str,
    dim: str = "shot",
    frame_shape: tuple[int, int] | None = None,
    rtol: float = EXPOSURE_TIME_RTOL,
) -> xr.Dataset:
    """The dark frames recorded at each of the given exposure times.

    ``dark(t_j) = dark.sel(exposure_time=t_j, method="nearest")`` for every ``t_j``, accepted
    only within ``rtol * t_j``: a shot of exposure time ``t`` must be dark-subtracted with
    the mean dark frame of that same ``t`` (eq. 5: the dark current grows with ``t``).

    Parameters
    ----------
    dark
        Group ``dark`` (``mean``, optionally ``std``, (exposure_time, y, x) [DN]) or its
        ``mean`` as a DataArray.
    exposure_time
        Exposure times [s] of the frames to be dark-subtracted, 1-D.
    used_by
        Who needs them, for the error message (``"band_signal"``,
        ``"raw/white_reference:spectral_counts"``).
    dim
        Name of the dim along ``exposure_time`` in the result.
    frame_shape
        ``(ny, nx)`` of the frames to be dark-subtracted; checked when given.
    rtol
        Relative tolerance of the exposure-time match.

    Returns
    -------
    xarray.Dataset
        ``mean`` (and ``std`` where ``dark`` has it) with dims ``(dim, y, x)``; coord
        ``exposure_time`` (dim,) holds the dark frames' own exposure times.

    Raises
    ------
    CalibrationError
        Listing every exposure time without a dark frame (with its position along ``dim``)
        and the exposure times that have one; or dark frames of another size.
    SchemaError
        ``dark``'s mean is not (exposure_time, y, x).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    ds = dark if isinstance(dark, xr.Dataset) else xr.Dataset({"mean": dark})
    mean = ds["mean"]
    if set(mean.dims) != {"exposure_time", "y", "x"}:
        raise SchemaError(
            "cannot look up dark frames:",
            [Problem("dark:mean", "dims (exposure_time, y, x)", f"dims {mean.dims}")],
        )
    if frame_shape is not None and (mean.sizes["y"], mean.sizes["x"]) != tuple(frame_shape):
        raise CalibrationError(
            f"dark:mean frames are {mean.sizes['y']}x{mean.sizes['x']} px but the frames of "
            f"{used_by} are {frame_shape[0]}x{frame_shape[1]} px; use dark frames of the same "
            "camera and region"
        )
    ds = ds[[v for v in ("mean", "std") if v in ds.data_vars]]
    if not ds.indexes["exposure_time"].is_monotonic_increasing:
        ds = ds.sortby("exposure_time")
    wanted = np.atleast_1d(np.asarray(exposure_time, dtype=np.float64))
    try:
        return ds.sel(
            exposure_time=xr.DataArray(wanted, dims=dim),
            method="nearest",
            tolerance=rtol * np.abs(wanted),
        )
    except KeyError:
        pass
    available = np.asarray(ds["exposure_time"].values, dtype=np.float64)
    found = np.isclose(available[None, :], wanted[:, None], rtol=rtol, atol=0.0).any(axis=1)
    missing = np.flatnonzero(~found)
    if missing.size == 1:
        what = f"exposure_time {float(wanted[missing[0]])} s ({dim} {int(missing[0])})"
    else:
        what = f"exposure_times {wanted[missing].tolist()} s ({dim}s {missing.tolist()})"
    raise CalibrationError(
        f"dark:mean has no frame for {what} used by {used_by}; dark frames exist for "
        f"{available.tolist()} s. Record dark frames at every exposure time used"
    )
