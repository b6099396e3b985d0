"""Dark frames (paper section 4, "Calibration"): averaging them, and finding them again.

The spectral camera works close to its noise floor, so its dark current must be known
exactly for every pixel: many closed-shutter frames are taken per exposure time and averaged
with floating-point accuracy (the paper uses 200 per exposure time). Every later step
subtracts the mean dark frame of the *same* exposure time; :func:`dark_frames_at` is the one
place that looks it up.

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

__all__ = ["average_dark_frames", "dark_frames_at", "EXPOSURE_TIME_RTOL"]

EXPOSURE_TIME_RTOL: float = 1e-6
"""Relative tolerance within which a dark frame's exposure time matches a shot's."""


def average_dark_frames(
    raw_dark: xr.Dataset,
    *,
    frames_per_chunk: Annotated[int, Field(ge=1, description="dark frames read per dask chunk")] = 16,
    ddof: Annotated[
        int, Field(ge=0, le=1, description="delta degrees of freedom of the std (1: sample)")
    ] = 1,
) -> xr.Dataset:
    """Per-pixel mean and standard deviation of raw dark frames, per exposure time.

    ``mean[t, y, x] = (1/N) sum_k frames[t, k, y, x]`` and the sample standard deviation
    over the ``N`` frames ``k`` of exposure time ``t``. The mean is the dark frame
    subtracted from every shot of the same exposure time before the low-SNR OECF recovery
    (paper section 4) and before band radiance is computed.
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

    Returns
    -------
    xarray.Dataset
        Group ``dark``: ``mean`` and ``std`` (exposure_time, y, x) float32 [DN], lazy.

    Raises
    ------
    SchemaError
        If ``raw_dark`` has fewer than ``ddof + 1`` frames per exposure time.

    Warns
    -----
    RuntimeWarning
        When frames at the ADC's maximum code are found (a light leak or a wrong bit depth):
        the mean is then biased, and is reported rather than silently clipped.

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
    # One pass over the stack: mean, std and the saturation count share the same reads.
    mean, std, saturated = dask.compute(
        as_float.mean(axis=1), as_float.std(axis=1, ddof=ddof), (frames >= max_code).sum()
    )
    if saturated:
        warnings.warn(
            f"raw/dark:frames has {int(saturated)} pixel value(s) at the maximum code "
            f"{max_code}: the dark mean is biased low there (light leak or wrong "
            "bit_depth?)",
            RuntimeWarning,
            stacklevel=2,
        )
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
