"""The recovered response smoothed to a spline in the log code (oecf/log_spline.py)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.calibration.oecf.log_spline import codes_reached, log_spline_response
from spectralize.schemas import CalibrationError

BLACK = 60.0
CODES = np.arange(4096, dtype=np.float64)


def smooth_response() -> np.ndarray:
    """(3, code) a gamma-like response per channel, 0 at and below the black level."""
    level = np.clip(CODES - BLACK, 0, None) / (4095 - BLACK)
    return np.stack([level**g for g in (2.2, 2.0, 1.8)])


def test_the_ripple_goes_the_curve_stays_and_unreached_codes_keep_the_recovered_response():
    """A recovered response that ripples by 3 % from code to code (period 300 DN): over the
    codes the target reaches the spline follows the smooth curve within 0.5 % (one scale); codes it does
    not reach keep the recovered table as it was."""
    truth = smooth_response()
    ripple = 1 + 0.03 * np.sin(2 * np.pi * CODES / 300.0)
    recovered = truth * ripple
    reached = (100.0, 3900.0)
    table = log_spline_response(recovered, BLACK, reached)
    mid = (CODES >= 500) & (CODES <= 3800)
    assert np.abs(recovered[:, mid] / truth[:, mid] - 1).max() > 0.029
    ratio = table[:, mid] / truth[:, mid]  # a response is relative: one scale per channel
    assert np.abs(ratio / np.median(ratio, axis=1, keepdims=True) - 1).max() < 0.005
    outside = (CODES < reached[0]) | (CODES > reached[1])
    np.testing.assert_array_equal(table[:, outside], recovered[:, outside])
    with pytest.raises(CalibrationError, match="knots must be >= 4"):
        log_spline_response(recovered, BLACK, reached, knots=3)
    with pytest.raises(CalibrationError, match="channel 0 has 5 codes"):
        log_spline_response(recovered, BLACK, (100.0, 104.0))


def test_codes_reached_between_the_levels():
    counts = np.array([[0, 60, 61, 2000], [4095, 4094, 3000, 59]])
    assert codes_reached(counts, BLACK, 4095) == (61.0, 4094.0)
    assert codes_reached(np.array([10, 60, 4095]), BLACK, 4095) is None
