"""Tests of spectralize.nodes.calibration.matched_level_qe: Q at the band shot's own level."""

from __future__ import annotations

import numpy as np

from spectralize.nodes.calibration.matched_level_qe import level_table, matched_quantum_efficiency

FULL = 4000.0


def compressed(level: np.ndarray) -> np.ndarray:
    """A linearisation that missed 8 % of compression at full scale (level-dependent error)."""
    return level * (1.0 - 0.08 * level / FULL)


def test_band_radiance_is_unbiased_when_q_comes_from_the_shot_s_own_level():
    rng = np.random.default_rng(4)
    wavelength = np.arange(410.0, 720.0, 10.0)
    n = wavelength.size
    q_true = 0.2 + rng.uniform(0.0, 1.0, n)
    light = 0.97 * (0.05 + rng.uniform(0.0, 1.0, n))
    times = np.cumprod([1.0] + [2.0 if k % 2 == 0 else 3.0 for k in range(10)]) * 0.5
    white_level = (light * q_true)[:, None] * times[None, :]  # true f(I - dark) per exposure
    usable = (white_level < FULL) & (white_level > 20.0)
    table = level_table(compressed(white_level) / times, times, usable, light, wavelength)
    assert table["qe_by_level"].dims == ("wavelength", "spectral_exposure")
    assert np.isnan(table["qe_by_level"].values[~usable]).all()

    # band shots of a radiance x at their own exposure, landing anywhere in the white's range
    x = 0.03 + rng.uniform(0.0, 1.0, n)
    lowest = np.where(usable, white_level, np.inf).min(1)
    highest = np.where(usable, white_level, 0.0).max(1)
    shot_level = np.exp(rng.uniform(np.log(lowest), np.log(highest)))
    t_shot = shot_level / (x * q_true)
    measured = compressed(shot_level)  # the shot's linearised level
    longest = np.array([table["qe_by_level"].values[b, np.flatnonzero(usable[b])[-1]] for b in range(n)])
    matched = matched_quantum_efficiency(table, wavelength, measured, longest)

    def bias(q):
        return measured / t_shot / q / x - 1.0

    assert np.abs(bias(longest)).max() > 0.03  # the ripple of the longest exposure's Q
    assert np.abs(bias(matched)).max() < 0.01
    # outside the white's levels: the nearest exposure's Q; no usable exposure: the fallback
    high = matched_quantum_efficiency(table, wavelength[:1], [10 * FULL], [-1.0])
    assert high[0] == table["qe_by_level"].values[0, np.flatnonzero(usable[0])[-1]]
    nothing = level_table(compressed(white_level) / times, times, usable & False, light, wavelength)
    assert matched_quantum_efficiency(nothing, wavelength[:2], [100.0, 100.0], [7.0, 8.0]).tolist() == [
        7.0,
        8.0,
    ]
    assert matched_quantum_efficiency(table, [415.0], [100.0], [5.0]).tolist() == [5.0]  # no such band
