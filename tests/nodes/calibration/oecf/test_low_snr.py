"""Tests of spectralize.nodes.calibration.oecf.low_snr: the paper's low-SNR extension."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration import oecf
from spectralize.nodes.calibration.oecf import low_snr, reverse_regression
from spectralize.schemas import CalibrationError


def _scaled_errors(code: np.ndarray, values: np.ndarray, truth, at: np.ndarray) -> np.ndarray:
    """|f/f_true - 1| at dark-subtracted values ``at`` after one scale fitted on 10..40 DN."""
    f_true = truth.response(code / 1023)
    fit = (code > 10) & (code < 40)
    scale = np.median(values[fit] / f_true[fit])
    return np.abs(np.interp(at, code, values) / (scale * truth.response(at / 1023)) - 1)


def test_low_snr_extension_succeeds_where_plain_robertson_fails(low_snr_series) -> None:
    series, dark, truth = low_snr_series()
    extension = oecf.recover_oecf_low_snr(series, dark, filter_size=20)["response"]
    plain = oecf.recover_oecf(series)["response"]
    assert extension.attrs["converged"] is True
    assert extension.attrs["dark_subtracted"] is True
    assert extension.attrs["stretch_low"] < 0 < 2 < extension.attrs["stretch_high"]
    # pixel values from 1.5 DN (SNR 0.5 at sigma 3 DN) to 40 DN above dark
    at = np.array([1.5, 2.0, 3.0, 5.0, 8.0, 12.0, 20.0, 30.0, 40.0])
    ext_err = _scaled_errors(extension["code"].values, extension.values, truth, at)
    plain_code = plain["code"].values - extension.attrs["dark_level"]
    plain_err = _scaled_errors(plain_code, plain.values, truth, at)
    snr_le_1 = at <= 3.0
    assert ext_err.max() < 0.04, ext_err
    assert ext_err[snr_le_1].max() < 0.04
    assert np.median(ext_err) < 0.01
    assert np.median(plain_err) > 0.2, plain_err
    assert plain_err[snr_le_1].min() > 0.2
    assert np.median(plain_err) > 20 * np.median(ext_err)


def test_low_snr_debiasing_removes_regression_to_the_mean(low_snr_series) -> None:
    # Robertson's E[x t | v] regresses to the mean where the density of filtered values falls
    # steeply (the bottom of the series); the reverse regression E[v | x t] and the fit
    # through 0 remove that bias (recover_oecf_low_snr, steps 6 and 7)
    series, dark, truth = low_snr_series()
    plain = oecf.recover_oecf_low_snr(series, dark, filter_size=20, debias=False)["response"]
    fixed = oecf.recover_oecf_low_snr(series, dark, filter_size=20)["response"]
    assert plain.attrs["debiased"] is False and np.isnan(plain.attrs["fit_below"])
    assert fixed.attrs["debiased"] is True
    assert fixed.attrs["fit_below"] == pytest.approx(0.1 * fixed.attrs["stretch_high"])
    np.testing.assert_array_equal(fixed["samples"].values, plain["samples"].values)
    assert np.all(np.diff(fixed.values) >= 0)
    assert np.interp(
        0.5 * (fixed.attrs["stretch_low"] + fixed.attrs["stretch_high"]),
        fixed["code"].values,
        fixed.values,
    ) == pytest.approx(1.0)
    at = np.array([1.0, 1.5, 2.0, 3.0])  # SNR 0.33 .. 1 per pixel
    before = _scaled_errors(plain["code"].values, plain.values, truth, at)
    after = _scaled_errors(fixed["code"].values, fixed.values, truth, at)
    assert after.max() < 0.015, after
    assert after.max() < 0.5 * before.max(), (before, after)
    # negative (noise) values stay negative and increasing through the fit's branch
    low = oecf.apply_response(xr.DataArray([-0.5, 0.0, 0.5], dims="v"), fixed).values
    assert low[0] < 0 and abs(low[1]) < 1e-3 * low[2] and low[1] < low[2]


def test_reverse_regression_is_unbiased_where_the_forward_mean_is_not() -> None:
    # v = f^-1(X) + noise with f^-1(X) = 100 X, X log-uniform: E[X | v] (Robertson's update)
    # is pulled towards the bulk of the data at small v, E[v | X] is not
    rng = np.random.default_rng(3)
    exposure = np.exp(rng.uniform(np.log(0.01), np.log(1.0), 400_000))
    values = 100.0 * exposure + rng.normal(0.0, 2.0, exposure.size)
    grid = np.linspace(-5.0, 105.0, 221)
    k = np.clip(np.rint((values - grid[0]) / (grid[1] - grid[0])).astype(int), 0, grid.size - 1)
    forward = np.bincount(k, exposure, grid.size) / np.maximum(np.bincount(k, None, grid.size), 1)
    levels = grid / 100.0 * (1.0 + 0.02 * np.sin(grid / 7.0))  # any monotone start
    levels = np.maximum.accumulate(levels)
    reverse = reverse_regression.reverse_regression(exposure, values, levels, grid)
    check = (grid >= 4.0) & (grid <= 95.0)
    truth = grid[check] / 100.0
    assert np.max(np.abs(reverse[check] / truth - 1)) < 0.01
    assert np.abs(forward[check][:4] / truth[:4] - 1).min() > 0.03  # biased at 4-5.5 DN
    coefficients = low_snr._quadratic_through_zero(exposure, values, 0.2)
    assert coefficients is not None
    c1, c2 = coefficients
    assert c1 == pytest.approx(100.0, rel=0.01) and abs(c2) < 5.0
    x = np.array([-0.01, 0.0, 0.05, 0.2])
    np.testing.assert_allclose(low_snr._invert_quadratic(c1 * x + c2 * x * x, c1, c2), x, atol=1e-12)


def test_low_snr_keeps_negative_values_and_maps_back_to_pixel_values(low_snr_series) -> None:
    series, dark, _ = low_snr_series(side=96)
    response = oecf.recover_oecf_low_snr(series, dark, filter_size=10)["response"]
    code = response["code"].values
    assert code[0] == pytest.approx(response.attrs["stretch_low"])
    assert code[-1] == pytest.approx(response.attrs["stretch_high"])
    assert code.size == 1024 and np.all(np.diff(code) > 0)
    assert code[0] < 0  # noise below the dark level survives the filtering
    assert response.attrs["dark_level"] == pytest.approx(15.5, abs=0.1)
    assert response["code"].attrs["long_name"] == "dark-subtracted pixel value"
    linear = oecf.apply_response(xr.DataArray([-1.0, 0.0, 5.0], dims="v"), response)
    assert linear.values[0] < linear.values[1] < linear.values[2]


# -- bad input ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("times", "word"),
    [
        (np.array([1.0, 3.0, 2.0, 25.0, 60.0]) / 60, "unsorted"),
        (np.array([1.0, 3.0, 3.0, 25.0, 60.0]) / 60, "duplicate"),
    ],
)
def test_unsorted_or_duplicate_exposure_times(times: np.ndarray, word: str, small_series) -> None:
    series = small_series().assign_coords(exposure_time=("exposure", times))
    with pytest.raises(CalibrationError, match=word):
        oecf.recover_oecf_low_snr(
            series,
            xr.DataArray(
                np.zeros((5, 20, 20)), dims=("exposure_time", "y", "x"), coords={"exposure_time": times}
            ),
            filter_size=5,
        )


def test_dark_frames_of_another_size(low_snr_series) -> None:
    series, dark, _ = low_snr_series(side=48)
    with pytest.raises(CalibrationError, match="dark:mean frames are 40x48 px but"):
        oecf.recover_oecf_low_snr(series, dark.isel(y=slice(0, 40)), filter_size=5)


def test_dark_frame_missing_for_an_exposure_time(low_snr_series) -> None:
    series, dark, _ = low_snr_series(side=48)
    missing = float(series["exposure_time"][3])
    with pytest.raises(
        CalibrationError, match=rf"dark:mean has no frame for exposure_time {missing} s \(exposure 3\)"
    ):
        oecf.recover_oecf_low_snr(series, dark.drop_sel(exposure_time=missing), filter_size=5)


def test_other_bad_input(TIMES, small_series) -> None:
    series = small_series()
    with pytest.raises(CalibrationError, match="saturated pixels"):
        sat = series.copy(data=series.values.copy())
        sat.values[1, 0, 0] = 255
        oecf.recover_oecf_low_snr(
            sat,
            xr.DataArray(
                np.zeros((5, 20, 20)), dims=("exposure_time", "y", "x"), coords={"exposure_time": TIMES}
            ),
            filter_size=5,
        )
    with pytest.raises(CalibrationError, match="too small for filter_size"):
        oecf.recover_oecf_low_snr(
            series.clip(max=200),
            xr.DataArray(
                np.zeros((5, 20, 20)), dims=("exposure_time", "y", "x"), coords={"exposure_time": TIMES}
            ),
            filter_size=40,
        )
