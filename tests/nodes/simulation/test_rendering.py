"""Tests of the renderer: one block renderer for every raw capture (eq. 5), noise streams."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.nodes.simulation.rendering import PATTERN_STREAM, STREAMS, Capture, Renderer


def test_every_capture_has_its_own_noise_stream():
    ids = list(STREAMS.values()) + [PATTERN_STREAM]
    assert len(set(ids)) == len(ids)
    assert Capture("rgb", "white", np.ones(3)).stream != Capture("spectral", "white", np.ones(3)).stream


def test_noise_free_white_target_counts_are_eq5():
    """RGB counts of the white target: floor(f^-1(x t) (2^b - 1) + offset), x = 0.98 C L."""
    renderer = Renderer(get_recipe("tiny", rgb_noise_sigma=0.0))
    times = np.array([0.002, 0.01])
    counts = renderer.counts(
        Capture("rgb", "white", times), slice(0, 2), slice(0, 32), slice(0, 32), slice(0, 3)
    )
    assert counts.shape == (2, 32, 32, 3) and counts.dtype == np.uint16
    c = renderer.rgb_camera.camera_matrix.values  # (3, wavelength)
    x = 0.98 * c @ renderer.illuminant.values
    for k, t in enumerate(times):
        for ch, name in enumerate("RGB"):
            oecf = renderer.rgb_camera.responses[name].oecf(np.asarray(x[ch] * t))
            want = np.clip(np.floor(oecf * 1023 + renderer.recipe.rgb_adc_offset), 0, 1023)
            assert np.abs(counts[k, ..., ch].astype(float) - want).max() <= 1.0


def test_dark_frames_are_the_fixed_pattern_plus_dark_current():
    renderer = Renderer(get_recipe("tiny", spectral_noise_sigma=0.0))
    t = np.array([[0.5, 0.5]])  # one exposure time, two frames
    frames = renderer.counts(
        Capture("spectral", "dark", t), slice(0, 1), slice(0, 2), slice(0, 32), slice(0, 32)
    )
    offset, dark_current = renderer.dark_pattern(slice(0, 32), slice(0, 32))
    np.testing.assert_array_equal(frames[0, 0], frames[0, 1])  # no noise: equal frames
    np.testing.assert_array_equal(frames[0, 0], np.floor(offset + dark_current * 0.5))


def test_chunks_must_align_to_the_noise_tile():
    renderer = Renderer(get_recipe("tiny", noise_tile=16))
    capture = Capture("rgb", "white", np.ones(1))
    with pytest.raises(SimulationParameterError, match="noise_tile"):
        renderer.counts(capture, slice(0, 1), slice(8, 24), slice(0, 32), slice(0, 3))
    # an aligned chunk equals the same pixels of a whole-image render
    whole = renderer.counts(capture, slice(0, 1), slice(0, 32), slice(0, 32), slice(0, 3))
    part = renderer.counts(capture, slice(0, 1), slice(16, 32), slice(0, 16), slice(1, 3))
    np.testing.assert_array_equal(part, whole[:, 16:32, 0:16, 1:3])
