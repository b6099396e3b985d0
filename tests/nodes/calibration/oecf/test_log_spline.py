"""The recovered response smoothed to a spline in the log code (oecf/log_spline.py)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.calibration.oecf.log_spline import (
    chosen_log_spline_response,
    code_residual,
    codes_reached,
    log_spline_response,
)
from spectralize.nodes.calibration.oecf.weighting import weighting_function
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


def _series(shapes, pixels: int = 8000):
    """(truth (channel, code), codes (1, exposure, pixel, channel), times (1, exposure)): an
    exposure series of unequal ratios through each response ``shapes[ch]`` (level -> exposure
    inverse), shot noise and 1.2 DN read noise, as a camera writes it."""
    rng = np.random.default_rng(3)
    times = np.array([[1, 3, 8, 25, 60]], float) / 60
    exposure = times[0][:, None] * np.exp(rng.uniform(np.log(2e-3), np.log(1.2), pixels))[None, :]
    fine = np.linspace(0.0, 1.3, 100_001)
    level = (CODES - BLACK) / (4095 - BLACK)
    tables, counts = [], []
    for h in shapes:
        table = np.interp(level, h(fine), fine)
        tables.append(np.where(CODES <= BLACK, 0.0, table))
        noisy = exposure + rng.normal(0, 1, exposure.shape) * np.sqrt(exposure / 5000)
        dn = BLACK + (4095 - BLACK) * h(np.clip(noisy, 0, None)) + rng.normal(0, 1.2, exposure.shape)
        counts.append(np.clip(np.round(dn), 0, 4095).astype(np.intp))
    return np.stack(tables), np.stack(counts, -1)[None], times


def test_each_channel_chooses_its_flexibility_a_shoulder_keeps_more():
    """Two channels recovered with the same 2 % ripple (period 300 DN): one with a linear
    response, one with an early shoulder the fixed 8-coefficient log spline cannot follow
    (over 5 % off). Scored on their own exposure series, the linear channel is smoothed with
    few coefficients to within 0.5 % of its truth, the shoulder keeps more than 8 and gets
    within 2.5 %, under half of the fixed spline's error."""
    shoulder = 0.15**1.15
    shapes = [lambda y: y, lambda y: y**1.15 / (y**1.15 + shoulder) * (1 + shoulder)]
    truth, codes, times = _series(shapes)
    recovered = truth * (1 + 0.02 * np.sin(2 * np.pi * CODES / 300.0))
    weights = weighting_function(CODES.astype(int), black_level=BLACK, saturation=4095)
    reached = (BLACK + 2, 4094.0)
    table, chosen = chosen_log_spline_response(recovered, BLACK, reached, codes, times, weights)
    fixed = log_spline_response(recovered, BLACK, reached, 8)

    def error(t: np.ndarray) -> np.ndarray:
        mid = (CODES >= 200) & (CODES <= 3900)
        ratio = t[:, mid] / truth[:, mid]
        return np.abs(ratio / np.median(ratio, axis=1, keepdims=True) - 1).max(axis=1)

    assert chosen[0] <= 8 < chosen[1]
    assert error(table)[0] < 0.005 and error(recovered)[0] > 0.019
    assert error(fixed)[1] > 0.05
    assert error(table)[1] < min(0.025, error(fixed)[1] / 2)
    # the residual the choice rests on: the truth predicts the codes better than the ripple
    assert code_residual(truth[1], codes[..., 1], times, weights, reached) < code_residual(
        recovered[1], codes[..., 1], times, weights, reached
    )


def test_the_chosen_response_never_falls_above_the_black_level():
    """A recovered response whose first codes above the black level are flat (a toe the
    recovery could not resolve): a spline in the log code dips there, a response does not, so
    the chosen one rises (or stays) from the black level to the highest code reached."""
    truth, codes, times = _series([lambda y: y, lambda y: y])
    recovered = truth * (1 + 0.02 * np.sin(2 * np.pi * CODES / 300.0))
    recovered[:, 61:64] = recovered[:, 64:65]
    recovered = np.maximum.accumulate(recovered, axis=1)
    reached = (BLACK + 1, 4094.0)
    weights = weighting_function(CODES.astype(int), black_level=BLACK, saturation=4095)
    table, chosen = chosen_log_spline_response(recovered, BLACK, reached, codes, times, weights)
    dips = [
        (np.diff(log_spline_response(recovered[ch : ch + 1], BLACK, reached, k)[0, 61:4095]) < 0).any()
        for ch, k in enumerate(chosen)
        if k
    ]
    assert any(dips)  # the spline alone would fall here
    assert (np.diff(table[:, 61:4095], axis=1) >= 0).all()
