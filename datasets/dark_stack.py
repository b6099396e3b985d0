"""A small raw dark stack, generated deterministically (the first demo's input).

Model of a cooled CCD behind a closed shutter, per pixel p and exposure time t::

    I = clip(floor(offset(p) + rate(p) * t + N(0, read_noise)), 0, 2**bit_depth - 1)

with a fixed-pattern ADC offset, a dark-current rate with a few hot pixels, and Gaussian read
noise (the paper's camera: dark noise Gaussian with standard deviation 3 DN).
"""

from __future__ import annotations

import dask.array as da
import numpy as np
import xarray as xr

from spectralize.schemas import SimulationError

__all__ = ["make_raw_dark"]


def make_raw_dark(
    *,
    exposure_times: tuple[float, ...] = (0.01, 0.05, 0.2),
    frames: int = 64,
    shape: tuple[int, int] = (48, 64),
    bit_depth: int = 10,
    adc_offset: float = 32.0,
    dark_current: float = 20.0,
    read_noise: float = 3.0,
    frames_per_chunk: int = 16,
    seed: int = 0,
) -> xr.Dataset:
    """Raw dark frames per the ``raw/dark`` contract, lazily, chunk by chunk.

    Parameters
    ----------
    exposure_times
        Exposure times [s], increasing.
    frames
        Frames per exposure time.
    shape
        (y, x) frame size [px].
    bit_depth
        ADC bit depth.
    adc_offset
        Mean ADC offset [DN]; each pixel deviates by a fixed pattern of 1 DN.
    dark_current
        Mean dark-current rate [DN/s]; 1 % of the pixels are hot (twenty times the rate).
    read_noise
        Standard deviation of the Gaussian read noise [DN].
    frames_per_chunk
        Frames per dask chunk (each chunk has its own seed, so values do not depend on
        scheduling).
    seed
        Seed of the fixed pattern and the noise.

    Raises
    ------
    SimulationError
        When ``exposure_times`` are not positive and increasing.
    """
    times = np.asarray(exposure_times, dtype=float)
    if times.ndim != 1 or times.size == 0 or np.any(times <= 0) or np.any(np.diff(times) <= 0):
        raise SimulationError.single(
            "exposure_times",
            "a non-empty 1-D sequence of positive, increasing exposure times [s]",
            np.ravel(times).tolist(),
        )
    pattern = np.random.default_rng([seed, 0])
    offset = adc_offset + pattern.normal(0.0, 1.0, shape)
    rate = dark_current * np.where(pattern.random(shape) < 0.01, 20.0, 1.0)
    max_code = 2**bit_depth - 1

    def block(e: int, f0: int, n: int) -> np.ndarray:
        rng = np.random.default_rng([seed, 1, e, f0])
        mean = offset + rate * times[e]
        values = np.floor(mean + rng.normal(0.0, read_noise, (n, *shape)))
        return np.clip(values, 0, max_code).astype(np.uint16)[None]

    rows = []
    for e in range(times.size):
        pieces = [
            da.from_delayed(
                _delayed(block, e, f0, min(frames_per_chunk, frames - f0)),
                shape=(1, min(frames_per_chunk, frames - f0), *shape),
                dtype=np.uint16,
            )
            for f0 in range(0, frames, frames_per_chunk)
        ]
        rows.append(da.concatenate(pieces, axis=1))
    data = da.concatenate(rows, axis=0)
    return xr.Dataset(
        {
            "frames": (
                ("exposure_time", "frame", "y", "x"),
                data,
                {"units": "DN", "long_name": "raw dark frame"},
            )
        },
        coords={"exposure_time": ("exposure_time", times, {"units": "s", "long_name": "exposure time"})},
        attrs={
            "camera": "spectral",
            "bit_depth": bit_depth,
            "description": "simulated closed-shutter frames (spectralize.datasets.dark_stack)",
        },
    )


def _delayed(function, *args):
    import dask

    return dask.delayed(function, pure=True)(*args)
