"""Dark-frame averaging (paper section 4, "Calibration").

The spectral camera works close to its noise floor, so its dark current must be known
exactly for every pixel: many closed-shutter frames are taken per exposure time and averaged
with floating-point accuracy (the paper uses 200 per exposure time).
"""

from __future__ import annotations

import warnings

import dask
import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.engine import Node, Parameters
from spectralize.schemas import SchemaError
from spectralize.schemas.run import RAW_DARK
from spectralize.schemas.spec import validate_dataset

__all__ = ["average_dark_frames", "DarkAverageParameters", "DARK_AVERAGE"]


class DarkAverageParameters(Parameters):
    """Parameters of :func:`average_dark_frames`."""

    frames_per_chunk: int = Field(16, ge=1, description="dark frames read per dask chunk")
    ddof: int = Field(1, ge=0, le=1, description="delta degrees of freedom of the std (1: sample)")


def average_dark_frames(
    raw_dark: xr.Dataset, *, frames_per_chunk: int = 16, ddof: int = 1
) -> xr.Dataset:
    """Per-pixel mean and standard deviation of raw dark frames, per exposure time.

    The mean is the dark frame subtracted from every shot of the same exposure time before
    the low-SNR OECF recovery (paper section 4) and before band radiance is computed.
    The frames are streamed with dask ``frames_per_chunk`` at a time and reduced in float64,
    so the whole stack is never in memory.

    Parameters
    ----------
    raw_dark
        Group ``raw/dark``: ``frames`` (exposure_time, frame, y, x) uint16 [DN].
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
        If ``raw_dark`` breaks the ``raw/dark`` contract, or has fewer than ``ddof + 1``
        frames.

    Warns
    -----
    RuntimeWarning
        When frames at the ADC's maximum code are found (a light leak or a wrong bit depth):
        the mean is then biased, and is reported rather than silently clipped.

    References
    ----------
    Fast Capture of Spectral Image Series, section 4 (dark frames, 200 per exposure time).
    """
    problems = validate_dataset(raw_dark, RAW_DARK, group="raw/dark")
    if not problems and raw_dark.sizes["frame"] < ddof + 1:
        problems.append(f"raw/dark:frames: expected at least {ddof + 1} frames per exposure "
                        f"time, found {raw_dark.sizes['frame']}")
    if problems:
        raise SchemaError("cannot average dark frames:", problems)

    max_code = 2 ** int(raw_dark.attrs["bit_depth"]) - 1
    frames = raw_dark["frames"].chunk({"frame": frames_per_chunk}).data
    as_float = frames.astype(np.float64)
    # One pass over the stack: mean, std and the saturation count share the same reads.
    mean, std, saturated = dask.compute(
        as_float.mean(axis=1), as_float.std(axis=1, ddof=ddof), (frames >= max_code).sum()
    )
    if saturated:
        warnings.warn(f"raw/dark:frames has {int(saturated)} pixel value(s) at the maximum code "
                      f"{max_code}: the dark mean is biased low there (light leak or wrong "
                      "bit_depth?)", RuntimeWarning, stacklevel=2)
    dims = ("exposure_time", "y", "x")

    out = xr.Dataset(
        {
            "mean": (dims, mean.astype(np.float32),
                     {"units": "DN", "long_name": "mean dark frame"}),
            "std": (dims, std.astype(np.float32),
                    {"units": "DN", "long_name": "per-pixel standard deviation of the dark frames"}),
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


DARK_AVERAGE = Node(
    name="dark_average",
    version="1",
    function=average_dark_frames,
    inputs={"raw_dark": "raw/dark"},
    outputs=("dark",),
    parameters=DarkAverageParameters,
    description="Average raw dark frames per exposure time into float32 mean and std (sec. 4).",
)
