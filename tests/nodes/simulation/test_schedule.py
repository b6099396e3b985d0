"""Tests of the run schedule: images, band shots, pairing and exposure times (eq. 2)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.simulation.assembly import Gantry
from spectralize.nodes.simulation.recipes import get_recipe


@pytest.fixture(scope="module")
def tiny():
    return Gantry(get_recipe("tiny")).schedule


def test_dense_mode_has_all_bands_per_led():
    schedule = Gantry(get_recipe("tiny", spectral_mode="dense")).schedule
    per_rot = len(schedule.shots) // len(set(schedule.shots.rotation.tolist()))
    assert per_rot == 32 * schedule.recipe.spectral_set_size
    t = schedule.band_time[schedule.shots.band].sum()
    assert float(schedule.plan.spectral_capture_time) == pytest.approx(t, abs=len(schedule.shots) * 5e-5)


def test_image_index_finds_the_image(tiny):
    im = tiny.images
    for i in range(len(im)):
        assert tiny.image_index(int(im.camera[i]), int(im.rotation[i]), int(im.led[i])) == i


def test_each_shot_pairs_with_the_rgb_image_one_rotation_earlier(tiny):
    sh, im = tiny.shots, tiny.images
    assert np.all(im.camera[sh.image] == tiny.paired_camera)
    assert np.all(im.rotation[sh.image] == sh.rotation - 1)
    for k in range(len(sh)):
        assert tiny.partner_led(int(im.led[sh.image[k]])) == sh.led[k]
    for angle in ("theta_i", "phi_i", "theta_o", "phi_o"):
        np.testing.assert_allclose(getattr(sh, angle), getattr(im, angle)[sh.image], atol=1e-9)


def test_times_are_quantised_and_every_spectral_time_has_darks(tiny):
    step = tiny.recipe.exposure_resolution
    for times in (tiny.band_time, tiny.calib_spectral_times, tiny.calib_rgb_times, tiny.dark_times):
        assert np.all(times >= step)
        np.testing.assert_allclose(times / step, np.round(times / step), atol=1e-6)
    used = np.concatenate(
        [tiny.band_time[tiny.shots.band], tiny.calib_spectral_times, [tiny.registration_spectral_time]]
    )
    assert set(used.tolist()) <= set(tiny.dark_times.tolist())
