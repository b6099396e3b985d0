"""Clear errors for unusable exposure series, on the tiny simulated run's raw/rgb (10 bit)."""

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration.hdr import merge_hdr
from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.schemas import CalibrationError


@pytest.fixture(scope="module")
def rgb() -> xr.Dataset:
    return simulate_run(get_recipe("tiny"))["raw/rgb"].load()


@pytest.fixture(scope="module")
def response(rgb) -> xr.Dataset:
    return recover_rgb_oecf(rgb)


def with_times(rgb: xr.Dataset, edit) -> xr.Dataset:
    times = rgb["exposure_time"].values.copy()
    edit(times)
    return rgb.assign_coords(exposure_time=(rgb["exposure_time"].dims, times))


def test_all_saturated_series_names_the_frames_not_the_black_level(rgb, response):
    saturated = rgb.copy(deep=True)
    saturated["counts"].values[...] = 1023
    for call, where in (
        (recover_rgb_oecf, "recover_rgb_oecf"),
        (lambda d: merge_hdr(d, response), "merge_hdr"),
    ):
        with pytest.raises(CalibrationError) as info:
            call(saturated)
        message = str(info.value)
        assert message.startswith(
            f"{where}: raw/rgb:counts: frame image=0, exposure=0, channel=0 (exposure_time 0.001 s) "
            "is entirely saturated (>= saturation = 1023): it carries no information; 240 such "
            "frame(s) in all. Use shorter exposures (or drop these frames)"
        ), message
        assert "black_level (1026)" not in message
        assert len(info.value.problems) == 6 and info.value.problems[-1] == "... and 235 more"
        assert str(info.value.problems[3]) == (
            f"{where}: raw/rgb:counts[image=0, exposure=1, channel=0]: expected a frame with some "
            "values below saturation = 1023, found every value >= 1023 (exposure_time 0.003 s)"
        )


def test_one_saturated_image_is_named(rgb):
    saturated = rgb.copy(deep=True)
    saturated["counts"].values[3, :2] = 1023
    with pytest.raises(CalibrationError, match=r"frame image=3, exposure=0, channel=0 .*6 such frame"):
        recover_rgb_oecf(saturated)


def test_almost_saturated_shortest_exposures_explain_the_default_black_level(rgb):
    bright = rgb.copy(deep=True)
    bright["counts"].values[:, 0] = 1023
    bright["counts"].values[:, 0, 0, 0] = 1000  # one pixel below saturation per frame
    with pytest.raises(CalibrationError) as info:
        recover_rgb_oecf(bright)
    assert str(info.value).startswith(
        "recover_rgb_oecf: raw/rgb:counts: the shortest exposures are (almost) entirely "
        "saturated: their 0.1 % quantile is 1023 DN, so the default black_level (1026) is not "
        "below saturation (1023). Use shorter exposures, or set black_level"
    ), str(info.value)


@pytest.mark.parametrize("value", [-0.01, 0.0, np.nan])
def test_a_bad_exposure_time_is_named_by_index_and_value(rgb, response, value):
    def edit(times):
        times[1, 2] = value

    bad = with_times(rgb, edit)
    for call, where in (
        (recover_rgb_oecf, "recover_rgb_oecf: raw/rgb"),
        (lambda d: merge_hdr(d, response), "merge_hdr: raw/rgb"),
    ):
        with pytest.raises(CalibrationError) as info:
            call(bad)
        assert str(info.value) == (
            f"{where}: exposure_time must be positive and finite; 1 value(s) are not, the first "
            f"at image=1, exposure=2: {value:g} s. Fix the capture's exposure times\n"
            f"  - {where}:exposure_time[image=1, exposure=2]: expected a positive, finite time "
            f"[s], found {value:g}"
        )


def test_many_negative_exposure_times_give_a_short_message(rgb):
    negative = with_times(rgb, lambda times: np.negative(times, out=times))
    with pytest.raises(CalibrationError) as info:
        recover_rgb_oecf(negative)
    message = str(info.value)
    assert "80 value(s) are not, the first at image=0, exposure=0: -0.001 s" in message
    assert message.endswith("  - ... and 75 more") and len(message) < 1000, message
