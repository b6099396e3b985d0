"""Exposure series simulated by eq. 5 for the OECF tests (factories served as fixtures)."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.simulation.camera_model import capture, response_model

# Exposure times with unequal ratios: equal ratios leave the response ambiguous up to a
# factor periodic in log exposure (see robertson_response Notes).
_TIMES = np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0


def _noise_for(bit_depth: int) -> tuple[float, float]:
    """(ADC offset, read noise sigma) [DN]: 16 DN and 3 DN at 10 bit, scaled with the depth."""
    scale = 2.0 ** (bit_depth - 10)
    return 16.0 * scale, 3.0 * scale


def _exposure_series(
    model: str,
    *,
    bit_depth: int,
    pixels: int,
    times: np.ndarray = _TIMES,
    seed: int = 0,
    radiance: np.ndarray | None = None,
    **params: float,
) -> tuple[np.ndarray, object]:
    """Eq. 5 exposure series (exposure, pixel) of log-uniformly distributed radiances."""
    rng = np.random.default_rng(seed)
    if radiance is None:
        radiance = np.exp(rng.uniform(np.log(3e-3), np.log(2.0), pixels))
    offset, sigma = _noise_for(bit_depth)
    truth = response_model(model, **params)
    counts = capture(
        radiance[None, :],
        times[:, None],
        response=truth,
        adc_offset=offset,
        noise_sigma=sigma,
        bit_depth=bit_depth,
        seed=rng,
    )
    return counts, truth


def _true_response(truth, bit_depth: int, codes: np.ndarray) -> np.ndarray:
    """True f at raw codes: code m is produced on average by signal m + 1/2 - offset."""
    offset, _ = _noise_for(bit_depth)
    full = 2**bit_depth - 1
    f = truth.response((np.asarray(codes, dtype=float) + 0.5 - offset) / full)
    return f / np.interp((full) / 2, codes, f)


def _relative_errors(response: np.ndarray, truth, bit_depth: int) -> np.ndarray:
    """|f/f_true - 1| over codes from 5% to 99% of the signal range."""
    codes = np.arange(2**bit_depth)
    offset, _ = _noise_for(bit_depth)
    full = 2**bit_depth - 1
    signal = codes + 0.5 - offset
    keep = (signal >= 0.05 * full) & (codes <= 0.99 * full)
    f_true = _true_response(truth, bit_depth, codes)
    return np.abs(response[keep] / f_true[keep] - 1)


def _as_dataarray(
    counts: np.ndarray, bit_depth: int, times: np.ndarray = _TIMES, side: int | None = None
) -> xr.DataArray:
    side = side or int(np.sqrt(counts.shape[1]))
    return xr.DataArray(
        counts[:, : side * side].reshape(len(times), side, side),
        dims=("exposure", "y", "x"),
        coords={"exposure_time": ("exposure", times)},
        attrs={"bit_depth": bit_depth},
    )


def _low_snr_series(side: int = 192, model: str = "s_curve", seed: int = 5):
    """A smooth target, 15 short exposures reaching ~50 DN, sigma 3 DN, 10 bit; dark frames."""
    rng = np.random.default_rng(seed)
    truth = response_model(model)
    yy, xx = np.mgrid[0:side, 0:side]
    radiance = np.exp(np.log(30.0) * xx / (side - 1)) * (1 + 0.1 * np.sin(yy / 15.0))
    grid = np.linspace(0.0, 1.0, 200_001)
    top = np.interp(50.0, truth.oecf(grid) * 1023, grid)
    ratios = np.array([1, 1.4, 2, 2.7, 3.8, 5.3, 7.2, 10, 14, 19, 27, 37, 52, 72, 100.0])
    times = top / radiance.max() * ratios / ratios.max()
    counts = capture(
        radiance[None] * np.ones((times.size, 1, 1)),
        times[:, None, None],
        response=truth,
        adc_offset=16,
        noise_sigma=3,
        bit_depth=10,
        seed=rng,
    )
    dark_frames = capture(
        np.zeros((64, side, side)), 1.0, adc_offset=16, noise_sigma=3, bit_depth=10, seed=rng
    )
    dark_mean = dark_frames.mean(axis=0, dtype=np.float64)  # no dark current: same per time
    series = xr.DataArray(
        counts,
        dims=("exposure", "y", "x"),
        coords={"exposure_time": ("exposure", times)},
        attrs={"bit_depth": 10},
    )
    dark = xr.Dataset(
        {
            "mean": (
                ("exposure_time", "y", "x"),
                np.repeat(dark_mean[None], times.size, 0).astype(np.float32),
            )
        },
        coords={"exposure_time": times},
    )
    return series, dark, truth


def _small_series(times: np.ndarray = _TIMES) -> xr.DataArray:
    counts, _ = _exposure_series("gamma", bit_depth=8, pixels=400, times=times)
    return _as_dataarray(counts, 8, times)


@pytest.fixture(scope="session")
def TIMES():
    return _TIMES


@pytest.fixture(scope="session")
def noise_for():
    return _noise_for


@pytest.fixture(scope="session")
def exposure_series():
    return _exposure_series


@pytest.fixture(scope="session")
def true_response():
    return _true_response


@pytest.fixture(scope="session")
def relative_errors():
    return _relative_errors


@pytest.fixture(scope="session")
def as_dataarray():
    return _as_dataarray


@pytest.fixture(scope="session")
def low_snr_series():
    return _low_snr_series


@pytest.fixture(scope="session")
def small_series():
    return _small_series
