"""The low end of the RGB response: a strong toe followed by the reverse regression."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration.oecf.low_end import low_end_anchor
from spectralize.nodes.calibration.oecf.robertson import recover_oecf
from spectralize.nodes.calibration.oecf.weighting import weighting_function

BLACK, TOP, TOE = 64.0, 4095, 0.03
TIMES = np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0


def toe(y: np.ndarray) -> np.ndarray:
    """A consumer camera's response: ``sqrt(y^2 + toe^2) - toe``, 1 at full scale."""
    return (np.sqrt(y * y + TOE * TOE) - TOE) / (np.sqrt(1.0 + TOE * TOE) - TOE)


def true_exposure(codes: np.ndarray) -> np.ndarray:
    """The exposure a code stands for (the inverse of :func:`toe` above the black offset)."""
    fine = np.linspace(0.0, 1.2, 200_001)
    return np.interp((codes - BLACK) / (TOP - BLACK), toe(fine), fine)


@pytest.fixture(scope="module")
def series() -> xr.Dataset:
    """Exposure series of a textured scene through the toe camera (12 bit, black offset 64)."""
    rng = np.random.default_rng(3)
    radiance = np.exp(rng.uniform(np.log(2e-3), np.log(1.5), size=(6, 48, 48)))
    y = radiance[:, None] * TIMES[None, :, None, None]
    codes = BLACK + (TOP - BLACK) * toe(y) + rng.normal(0.0, 1.2, y.shape)
    counts = np.clip(np.round(codes), 0, TOP).astype(np.uint16)
    return xr.Dataset(
        {"counts": (("image", "exposure", "y", "x"), counts)},
        coords={"exposure_time": ("exposure", TIMES)},
        attrs={"bit_depth": 12},
    )


def low_end_error(response: np.ndarray, lo: int, hi: int) -> float:
    """Median ``|f / f_true - 1|`` over codes ``lo .. hi`` (one scale, fitted mid-range)."""
    codes = np.arange(response.size, dtype=float)
    true = true_exposure(codes)
    mid = (codes >= 1000) & (codes <= 3500)
    scale = (response[mid] @ true[mid]) / (response[mid] @ response[mid])
    sel = (codes >= lo) & (codes <= hi)
    return float(np.median(np.abs(scale * response[sel] / true[sel] - 1)))


def test_the_low_end_follows_a_strong_toe_the_smooth_response_cannot(series):
    black_level = int(BLACK) + 3
    smooth = recover_oecf(series, black_level=black_level, smooth=16)["response"].values
    toed = recover_oecf(series, black_level=black_level, smooth=16, low_end=True)["response"].values
    lowest = (black_level + 1, black_level + 20)
    assert low_end_error(smooth, *lowest) > 0.1  # the spline misses the toe by tens of percent
    assert low_end_error(toed, *lowest) < 0.03
    above = (black_level + 20, black_level + 100)
    assert low_end_error(toed, *above) < low_end_error(smooth, *above)


def test_the_response_from_the_anchor_up_is_the_fitted_one(series):
    black_level = int(BLACK) + 3
    smooth = recover_oecf(series, black_level=black_level, smooth=16)["response"].values
    toed = recover_oecf(series, black_level=black_level, smooth=16, low_end=True)["response"].values
    weights = weighting_function(np.arange(TOP + 1), black_level=black_level, saturation=TOP)
    first, anchor = low_end_anchor(weights)
    assert first == black_level + 1 and first < anchor < 300
    np.testing.assert_allclose(toed[anchor:], smooth[anchor:], rtol=1e-12)
    assert np.all(np.diff(toed) >= 0)


def test_no_low_end_without_codes_under_the_anchor():
    weights = np.ones(4096)
    assert low_end_anchor(weights) is None
    assert low_end_anchor(np.zeros(4096)) is None
