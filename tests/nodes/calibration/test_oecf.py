"""Tests of spectralize.nodes.calibration.oecf: Robertson OECF recovery and the low-SNR extension."""

from __future__ import annotations

import warnings

import dask.array as da
import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spectralize.nodes.calibration import oecf
from spectralize.nodes.simulation.camera_model import capture, response_model
from spectralize.schemas import CalibrationError, SchemaError

# Exposure times with unequal ratios: equal ratios leave the response ambiguous up to a
# factor periodic in log exposure (see robertson_response Notes).
TIMES = np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0


def noise_for(bit_depth: int) -> tuple[float, float]:
    """(ADC offset, read noise sigma) [DN]: 16 DN and 3 DN at 10 bit, scaled with the depth."""
    scale = 2.0 ** (bit_depth - 10)
    return 16.0 * scale, 3.0 * scale


def exposure_series(model: str, *, bit_depth: int, pixels: int, times: np.ndarray = TIMES,
                    seed: int = 0, radiance: np.ndarray | None = None,
                    **params: float) -> tuple[np.ndarray, object]:
    """Eq. 5 exposure series (exposure, pixel) of log-uniformly distributed radiances."""
    rng = np.random.default_rng(seed)
    if radiance is None:
        radiance = np.exp(rng.uniform(np.log(3e-3), np.log(2.0), pixels))
    offset, sigma = noise_for(bit_depth)
    truth = response_model(model, **params)
    counts = capture(radiance[None, :], times[:, None], response=truth, adc_offset=offset,
                     noise_sigma=sigma, bit_depth=bit_depth, seed=rng)
    return counts, truth


def true_response(truth, bit_depth: int, codes: np.ndarray) -> np.ndarray:
    """True f at raw codes: code m is produced on average by signal m + 1/2 - offset."""
    offset, _ = noise_for(bit_depth)
    full = 2**bit_depth - 1
    f = truth.response((np.asarray(codes, dtype=float) + 0.5 - offset) / full)
    return f / np.interp((full) / 2, codes, f)


def relative_errors(response: np.ndarray, truth, bit_depth: int) -> np.ndarray:
    """|f/f_true - 1| over codes from 5% to 99% of the signal range."""
    codes = np.arange(2**bit_depth)
    offset, _ = noise_for(bit_depth)
    full = 2**bit_depth - 1
    signal = codes + 0.5 - offset
    keep = (signal >= 0.05 * full) & (codes <= 0.99 * full)
    f_true = true_response(truth, bit_depth, codes)
    return np.abs(response[keep] / f_true[keep] - 1)


def as_dataarray(counts: np.ndarray, bit_depth: int, times: np.ndarray = TIMES,
                 side: int | None = None) -> xr.DataArray:
    side = side or int(np.sqrt(counts.shape[1]))
    return xr.DataArray(counts[:, : side * side].reshape(len(times), side, side),
                        dims=("exposure", "y", "x"),
                        coords={"exposure_time": ("exposure", times)},
                        attrs={"bit_depth": bit_depth})


# -- recovery of known responses ----------------------------------------------------------------
@pytest.mark.parametrize("model", ["gamma", "log", "s_curve"])
@pytest.mark.parametrize(("bit_depth", "pixels"), [(8, 20_000), (10, 60_000), (12, 60_000),
                                                   (16, 40_000)])
def test_recovers_known_responses(model: str, bit_depth: int, pixels: int) -> None:
    counts, truth = exposure_series(model, bit_depth=bit_depth, pixels=pixels)
    offset, sigma = noise_for(bit_depth)
    result = oecf.recover_oecf(as_dataarray(counts, bit_depth),
                               black_level=int(offset + 3 * sigma))
    response = result["response"]
    assert response.dims == ("code",)
    assert response.sizes["code"] == 2**bit_depth
    assert response.attrs["converged"] is True
    assert np.all(np.isfinite(response.values))
    assert np.all(np.diff(response.values) >= 0)
    errors = relative_errors(response.values, truth, bit_depth)
    assert np.median(errors) < 0.005, np.median(errors)
    assert errors.max() < 0.025, errors.max()


def test_response_contract_and_normalisation() -> None:
    counts, _ = exposure_series("gamma", bit_depth=10, pixels=10_000)
    response = oecf.recover_oecf(as_dataarray(counts, 10), tolerance=1e-7)["response"]
    attrs = response.attrs
    assert attrs["units"] == "1"
    assert attrs["bit_depth"] == 10
    assert attrs["method"] == "robertson2003"
    assert attrs["converged"] is True and 1 <= attrs["iterations"] < 5000
    assert attrs["tolerance"] == 1e-7
    assert response["code"].attrs["units"] == "DN"
    np.testing.assert_array_equal(response["code"].values, np.arange(1024))
    assert np.interp(511.5, response["code"].values, response.values) == pytest.approx(1.0)
    assert response["samples"].sum() == counts.size


def test_convergence_is_checked_not_a_fixed_count() -> None:
    counts, _ = exposure_series("log", bit_depth=8, pixels=4_000)
    weights = oecf.weighting_function(np.arange(256), black_level=4, saturation=255)
    loose = oecf.robertson_response(counts, TIMES, n_codes=256, weights=weights,
                                    tolerance=1e-3, solver="power")
    tight = oecf.robertson_response(counts, TIMES, n_codes=256, weights=weights,
                                    tolerance=1e-9, solver="power")
    capped = oecf.robertson_response(counts, TIMES, n_codes=256, weights=weights,
                                     tolerance=1e-12, max_iterations=3, solver="power")
    assert loose.converged and tight.converged and not capped.converged
    assert loose.iterations < tight.iterations
    assert tight.change < 1e-9 <= loose.change or loose.change < 1e-3
    assert capped.iterations == 3 and capped.change > 1e-12


def test_solvers_and_operators_reach_the_same_fixed_point() -> None:
    counts, _ = exposure_series("s_curve", bit_depth=10, pixels=8_000)
    weights = oecf.weighting_function(np.arange(1024), black_level=25, saturation=1023)
    reference = oecf.robertson_response(counts, TIMES, n_codes=1024, weights=weights,
                                        tolerance=1e-10, solver="power", operator="samples",
                                        max_iterations=50_000)
    for solver, operator in [("lanczos", "dense"), ("lanczos", "sparse"),
                             ("power", "dense"), ("lanczos", "samples")]:
        other = oecf.robertson_response(counts, TIMES, n_codes=1024, weights=weights,
                                        tolerance=1e-10, solver=solver, operator=operator,
                                        max_iterations=50_000)
        assert other.converged
        np.testing.assert_allclose(other.response, reference.response, rtol=1e-5, atol=1e-9)
    fast = oecf.robertson_response(counts, TIMES, n_codes=1024, weights=weights,
                                   tolerance=1e-10, max_iterations=50_000)
    assert fast.iterations < reference.iterations


def test_pixels_without_a_weighted_sample_are_left_out() -> None:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=3_000)
    weights = oecf.weighting_function(np.arange(256), black_level=4, saturation=255)
    base = oecf.robertson_response(counts, TIMES, n_codes=256, weights=weights,
                                   tolerance=1e-10)
    useless = np.concatenate([np.full((5, 40), 255), np.full((5, 30), 2),
                              np.tile([[1], [3], [255], [255], [255]], 20)], axis=1)
    padded = np.concatenate([counts, useless.astype(counts.dtype)], axis=1)
    for operator in ("dense", "samples"):
        other = oecf.robertson_response(padded, TIMES, n_codes=256, weights=weights,
                                        tolerance=1e-10, operator=operator)
        np.testing.assert_array_equal(other.samples, base.samples)
        np.testing.assert_allclose(other.response, base.response, rtol=1e-9)


def test_frame_checks_with_channels_last() -> None:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=2_500)
    rgb = np.stack([counts, counts, counts], axis=-1).reshape(5, 50, 50, 3).copy()
    rgb[2, ..., 1] = 1                              # one channel of one exposure all dark
    data = xr.DataArray(rgb, dims=("exposure", "y", "x", "channel"),
                        coords={"exposure_time": ("exposure", TIMES)},
                        attrs={"bit_depth": 8})
    with pytest.raises(CalibrationError,
                       match=r"frame \{'exposure': 2, 'channel': 1\}.*entirely dark"):
        oecf.recover_oecf(data, black_level=4)
    rgb[2, ..., 1] = 255
    with pytest.raises(CalibrationError, match=r"'channel': 1\}.*entirely saturated"):
        oecf.recover_oecf(data.copy(data=rgb), black_level=4)


def test_unobserved_codes_are_interpolated_never_nan() -> None:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=5_000)
    sparse_codes = (counts.astype(np.int64) // 4) * 4 + 8          # only every 4th code
    sparse_codes = np.clip(sparse_codes, 0, 255).astype(np.uint16)
    weights = oecf.weighting_function(np.arange(256), black_level=10, saturation=255)
    result = oecf.robertson_response(sparse_codes, TIMES, n_codes=256, weights=weights)
    unseen = np.flatnonzero(result.samples == 0)
    assert unseen.size > 150
    assert np.all(np.isfinite(result.response))
    assert np.all(np.diff(result.response) >= 0)
    seen = np.flatnonzero((result.samples > 0) & (np.arange(256) < 255))  # not saturated
    inner = unseen[(unseen > seen[0]) & (unseen < seen[-1])]
    np.testing.assert_allclose(result.response[inner],
                               np.interp(inner, seen, result.response[seen]))
    assert result.response[0] <= result.response[seen[0]]


def test_per_camera_and_channel_responses() -> None:
    rng = np.random.default_rng(4)
    side = 64
    models = [response_model("gamma", gamma=2.2), response_model("log", a=30.0)]
    images = []
    for camera in range(2):
        radiance = np.exp(rng.uniform(np.log(3e-3), np.log(2.0), (side, side, 3)))
        channel_scale = np.array([1.0, 0.8, 0.6])
        images.append(capture(radiance[None] * channel_scale, TIMES[:, None, None, None],
                              response=models[camera], adc_offset=16, noise_sigma=3,
                              bit_depth=10, seed=rng))
    raw = xr.Dataset(
        {"counts": (("image", "exposure", "y", "x", "channel"), np.stack(images))},
        coords={"exposure_time": (("image", "exposure"), np.stack([TIMES, TIMES * 1.3])),
                "channel": ["R", "G", "B"], "camera": ("image", [3, 7])},
        attrs={"bit_depth": 10})
    response = oecf.recover_oecf(raw, black_level=25)["response"]
    assert response.dims == ("camera", "channel", "code")
    assert response["camera"].values.tolist() == [3, 7]
    assert response["channel"].values.tolist() == ["R", "G", "B"]
    for index, camera in enumerate([3, 7]):
        for channel in "RGB":
            errors = relative_errors(response.sel(camera=camera, channel=channel).values,
                                     models[index], 10)
            assert np.median(errors) < 0.01


def test_max_pixels_subsample_is_reproducible() -> None:
    counts, truth = exposure_series("gamma", bit_depth=10, pixels=40_000)
    series = as_dataarray(counts, 10)
    a = oecf.recover_oecf(series, black_level=25, max_pixels=10_000, seed=1)["response"]
    b = oecf.recover_oecf(series, black_level=25, max_pixels=10_000, seed=1)["response"]
    xr.testing.assert_identical(a, b)
    assert int(a["samples"].sum()) == 10_000 * len(TIMES)
    assert np.median(relative_errors(a.values, truth, 10)) < 0.01


def test_lazy_input_and_a_shot_dim() -> None:
    counts, _ = exposure_series("log", bit_depth=10, pixels=10_000)
    series = as_dataarray(counts, 10)
    eager = oecf.recover_oecf(series, black_level=25)["response"]
    lazy = oecf.recover_oecf(series.chunk({"y": 50}), black_level=25)["response"]
    xr.testing.assert_allclose(lazy, eager)
    raw_spectral = xr.Dataset({"counts": series.clip(max=1000).rename(exposure="shot")},
                              attrs={"bit_depth": 10})
    dark = xr.DataArray(np.full((5, 100, 100), 15.5), dims=("exposure_time", "y", "x"),
                        coords={"exposure_time": TIMES})
    low = oecf.recover_oecf_low_snr(raw_spectral, dark, filter_size=5)["response"]
    assert low.dims == ("code",) and low.attrs["converged"] is True


def test_geometric_exposure_series_warns() -> None:
    times = np.array([1.0, 4.0, 16.0, 64.0]) / 64
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=2_500, times=times)
    with pytest.warns(RuntimeWarning, match="periodic in log exposure"):
        oecf.recover_oecf(as_dataarray(counts, 8, times))


# -- property tests -------------------------------------------------------------------------------
class _TabulatedResponse:
    """A monotone OECF given by increments (for hypothesis)."""

    name = "tabulated"

    def __init__(self, increments: list[float]) -> None:
        knots = np.concatenate([[0.0], np.cumsum(increments)])
        self.signal = knots / knots[-1]
        self.exposure = np.linspace(0.0, 1.0, self.signal.size)

    def oecf(self, exposure):
        return np.interp(np.clip(exposure, 0, 1), self.exposure, self.signal)

    def response(self, signal):
        return np.interp(np.clip(signal, 0, 1), self.signal, self.exposure)

    def parameters(self) -> dict[str, float]:
        return {}


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(increments=st.lists(st.floats(0.3, 3.0), min_size=4, max_size=8),
       seed=st.integers(0, 1000), time_scale=st.floats(1e-3, 1e3))
def test_monotone_responses_are_recovered_monotone(increments: list[float], seed: int,
                                                   time_scale: float) -> None:
    truth = _TabulatedResponse(increments)
    rng = np.random.default_rng(seed)
    radiance = np.exp(rng.uniform(np.log(2e-3), np.log(2.0), 6_000))
    counts = capture(radiance[None, :], TIMES[:, None], response=truth, adc_offset=4,
                     noise_sigma=0.75, bit_depth=8, seed=rng)
    weights = oecf.weighting_function(np.arange(256), black_level=6, saturation=255)
    result = oecf.robertson_response(counts, TIMES, n_codes=256, weights=weights)
    assert result.converged
    assert np.all(np.isfinite(result.response))
    assert np.all(np.diff(result.response) >= 0)
    assert result.response[int(127.5)] <= 1.0 <= result.response[128]
    codes = np.arange(256)
    f_true = truth.response((codes + 0.5 - 4) / 255)
    f_true = f_true / np.interp(127.5, codes, f_true)
    keep = (codes >= 30) & (codes <= 250)
    assert np.median(np.abs(result.response[keep] / f_true[keep] - 1)) < 0.05
    # the response does not depend on the unit of time (only on exposure-time ratios)
    scaled = oecf.robertson_response(counts, TIMES * time_scale, n_codes=256, weights=weights)
    np.testing.assert_allclose(scaled.response, result.response, rtol=1e-5, atol=1e-8)


@settings(max_examples=25, deadline=None)
@given(values=st.lists(st.floats(-10, 10), min_size=1, max_size=40))
def test_isotonic_regression_is_monotone_and_mean_preserving(values: list[float]) -> None:
    fitted = oecf.isotonic_regression(np.array(values))
    assert np.all(np.diff(fitted) >= -1e-12)
    assert fitted.sum() == pytest.approx(sum(values), abs=1e-9)


# -- the low-SNR extension -----------------------------------------------------------------------
def low_snr_series(side: int = 192, model: str = "s_curve", seed: int = 5):
    """A smooth target, 15 short exposures reaching ~50 DN, sigma 3 DN, 10 bit; dark frames."""
    rng = np.random.default_rng(seed)
    truth = response_model(model)
    yy, xx = np.mgrid[0:side, 0:side]
    radiance = np.exp(np.log(30.0) * xx / (side - 1)) * (1 + 0.1 * np.sin(yy / 15.0))
    grid = np.linspace(0.0, 1.0, 200_001)
    top = np.interp(50.0, truth.oecf(grid) * 1023, grid)
    ratios = np.array([1, 1.4, 2, 2.7, 3.8, 5.3, 7.2, 10, 14, 19, 27, 37, 52, 72, 100.0])
    times = top / radiance.max() * ratios / ratios.max()
    counts = capture(radiance[None] * np.ones((times.size, 1, 1)), times[:, None, None],
                     response=truth, adc_offset=16, noise_sigma=3, bit_depth=10, seed=rng)
    dark_frames = capture(np.zeros((64, side, side)), 1.0, adc_offset=16, noise_sigma=3,
                          bit_depth=10, seed=rng)
    dark_mean = dark_frames.mean(axis=0, dtype=np.float64)  # no dark current: same per time
    series = xr.DataArray(counts, dims=("exposure", "y", "x"),
                          coords={"exposure_time": ("exposure", times)},
                          attrs={"bit_depth": 10})
    dark = xr.Dataset(
        {"mean": (("exposure_time", "y", "x"),
                  np.repeat(dark_mean[None], times.size, 0).astype(np.float32))},
        coords={"exposure_time": times})
    return series, dark, truth


def _scaled_errors(code: np.ndarray, values: np.ndarray, truth, at: np.ndarray) -> np.ndarray:
    """|f/f_true - 1| at dark-subtracted values ``at`` after one scale fitted on 10..40 DN."""
    f_true = truth.response(code / 1023)
    fit = (code > 10) & (code < 40)
    scale = np.median(values[fit] / f_true[fit])
    return np.abs(np.interp(at, code, values) / (scale * truth.response(at / 1023)) - 1)


def test_low_snr_extension_succeeds_where_plain_robertson_fails() -> None:
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


def test_low_snr_debiasing_removes_regression_to_the_mean() -> None:
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
    assert np.interp(0.5 * (fixed.attrs["stretch_low"] + fixed.attrs["stretch_high"]),
                     fixed["code"].values, fixed.values) == pytest.approx(1.0)
    at = np.array([1.0, 1.5, 2.0, 3.0])            # SNR 0.33 .. 1 per pixel
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
    forward = np.bincount(k, exposure, grid.size) / np.maximum(np.bincount(k, None, grid.size),
                                                               1)
    levels = grid / 100.0 * (1.0 + 0.02 * np.sin(grid / 7.0))     # any monotone start
    levels = np.maximum.accumulate(levels)
    reverse = oecf._reverse_regression(exposure, values, levels, grid)
    check = (grid >= 4.0) & (grid <= 95.0)
    truth = grid[check] / 100.0
    assert np.max(np.abs(reverse[check] / truth - 1)) < 0.01
    assert np.abs(forward[check][:4] / truth[:4] - 1).min() > 0.03     # biased at 4-5.5 DN
    coefficients = oecf._quadratic_through_zero(exposure, values, 0.2)
    assert coefficients is not None
    c1, c2 = coefficients
    assert c1 == pytest.approx(100.0, rel=0.01) and abs(c2) < 5.0
    x = np.array([-0.01, 0.0, 0.05, 0.2])
    np.testing.assert_allclose(oecf._invert_quadratic(c1 * x + c2 * x * x, c1, c2), x,
                               atol=1e-12)


def test_low_snr_keeps_negative_values_and_maps_back_to_pixel_values() -> None:
    series, dark, _ = low_snr_series(side=96)
    response = oecf.recover_oecf_low_snr(series, dark, filter_size=10)["response"]
    code = response["code"].values
    assert code[0] == pytest.approx(response.attrs["stretch_low"])
    assert code[-1] == pytest.approx(response.attrs["stretch_high"])
    assert code.size == 1024 and np.all(np.diff(code) > 0)
    assert code[0] < 0          # noise below the dark level survives the filtering
    assert response.attrs["dark_level"] == pytest.approx(15.5, abs=0.1)
    assert response["code"].attrs["long_name"] == "dark-subtracted pixel value"
    linear = oecf.apply_response(xr.DataArray([-1.0, 0.0, 5.0], dims="v"), response)
    assert linear.values[0] < linear.values[1] < linear.values[2]


def test_combined_response_covers_the_whole_range() -> None:
    series, dark, truth = low_snr_series(side=160)
    low = oecf.recover_oecf_low_snr(series, dark, filter_size=20)
    counts, _ = exposure_series("s_curve", bit_depth=10, pixels=20_000)
    full = oecf.recover_oecf(as_dataarray(counts, 10), black_level=25)
    combined = oecf.combine_responses(low, full)["response"]
    code = combined["code"].values
    assert combined.attrs["method"] == "combined" and combined.attrs["dark_subtracted"]
    assert code[0] < 1 and code[-1] > 1000
    assert np.all(np.isfinite(combined.values)) and np.all(np.diff(code) > 0)
    f_true = truth.response(np.clip(code, 0, None) / 1023)
    f_true = f_true / truth.response((511.5 + 0.5 - 16) / 1023)
    for lo, hi, tolerance in [(1.5, 50, 0.04), (50, 1000, 0.02)]:
        keep = (code >= lo) & (code <= hi)
        assert np.median(np.abs(combined.values[keep] / f_true[keep] - 1)) < tolerance / 2
        assert np.max(np.abs(combined.values[keep] / f_true[keep] - 1)) < tolerance


# -- apply_response ---------------------------------------------------------------------------------
def test_apply_response_interpolates_matches_channels_and_stays_lazy() -> None:
    table = xr.DataArray(np.stack([np.arange(4.0), 2 * np.arange(4.0)]),
                         dims=("channel", "code"),
                         coords={"channel": ["R", "G"], "code": np.arange(4)})
    values = xr.DataArray(np.array([[0.5, 3.5, -1.0], [1.0, 2.0, 5.0]]).T,
                          dims=("pixel", "channel"), coords={"channel": ["R", "G"]})
    out = oecf.apply_response(values, table)
    np.testing.assert_allclose(out.sel(channel="R").values, [0.5, 3.5, -1.0])
    np.testing.assert_allclose(out.sel(channel="G").values, [2.0, 4.0, 10.0])
    lazy = oecf.apply_response(values.chunk({"pixel": 1}), table)
    assert isinstance(lazy.data, da.Array)
    np.testing.assert_allclose(lazy.transpose(*out.dims).values, out.values)


def test_weighting_functions() -> None:
    codes = np.arange(0, 101)
    for kind in ("gaussian", "hat", "uniform"):
        w = oecf.weighting_function(codes, black_level=10, saturation=90, kind=kind)
        assert w[:11].max() == 0 and w[90:].max() == 0
        assert w[50] == pytest.approx(1.0)
        assert np.all((w >= 0) & (w <= 1))
    w = oecf.weighting_function(codes, black_level=0, saturation=100)
    np.testing.assert_allclose(w[:50], w[100:50:-1])


# -- bad input ------------------------------------------------------------------------------------
def _small_series(times: np.ndarray = TIMES) -> xr.DataArray:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=400, times=times)
    return as_dataarray(counts, 8, times)


@pytest.mark.parametrize(("times", "word"), [
    (np.array([1.0, 3.0, 2.0, 25.0, 60.0]) / 60, "unsorted"),
    (np.array([1.0, 3.0, 3.0, 25.0, 60.0]) / 60, "duplicate"),
])
def test_unsorted_or_duplicate_exposure_times(times: np.ndarray, word: str) -> None:
    series = _small_series().assign_coords(exposure_time=("exposure", times))
    with pytest.raises(CalibrationError, match=f"exposure_time.*{word}"):
        oecf.recover_oecf(series)
    with pytest.raises(CalibrationError, match=word):
        oecf.recover_oecf_low_snr(series, xr.DataArray(
            np.zeros((5, 20, 20)), dims=("exposure_time", "y", "x"),
            coords={"exposure_time": times}), filter_size=5)


def test_all_saturated_or_all_dark_frame() -> None:
    series = _small_series()
    saturated = series.copy(data=series.values.copy())
    saturated.values[4] = 255
    with pytest.raises(CalibrationError, match=r"frame \{'exposure': 4\}.*saturated.*255"):
        oecf.recover_oecf(saturated)
    dark = series.copy(data=series.values.copy())
    dark.values[0] = 3
    with pytest.raises(CalibrationError, match=r"exposure_time 0.0166.*dark \(<= black_level"):
        oecf.recover_oecf(dark, black_level=3)
    everything = series.copy(data=np.full(series.shape, 255, dtype=np.uint16))
    weights = oecf.weighting_function(np.arange(256), black_level=0, saturation=255)
    with pytest.raises(CalibrationError, match="every sample is saturated or under-exposed"):
        oecf.robertson_response(everything.values.reshape(5, -1), TIMES, n_codes=256,
                                weights=weights)


def test_mismatched_shapes() -> None:
    weights = oecf.weighting_function(np.arange(256), black_level=0, saturation=255)
    with pytest.raises(CalibrationError, match=r"got codes \(5, 10\), exposure_times \(4,\)"):
        oecf.robertson_response(np.zeros((5, 10), np.uint8), TIMES[:4], n_codes=256,
                                weights=weights)
    series, dark, _ = low_snr_series(side=48)
    with pytest.raises(CalibrationError, match="dark: mean frame is 40x48 px but"):
        oecf.recover_oecf_low_snr(series, dark.isel(y=slice(0, 40)), filter_size=5)
    with pytest.raises(SchemaError, match="wrong dims"):
        oecf.recover_oecf(series.expand_dims(band=2))


def test_dark_frame_missing_for_an_exposure_time() -> None:
    series, dark, _ = low_snr_series(side=48)
    missing = float(series["exposure_time"][3])
    with pytest.raises(CalibrationError, match=f"no dark frame for exposure_time {missing}"):
        oecf.recover_oecf_low_snr(series, dark.drop_sel(exposure_time=missing), filter_size=5)


def test_other_bad_input() -> None:
    series = _small_series()
    with pytest.raises(CalibrationError, match=r"must lie in \[0, 255\].*found \[.*, 300\]"):
        bad = series.copy(data=series.values.copy())
        bad.values[2, 0, 0] = 300
        oecf.recover_oecf(bad)
    with pytest.raises(SchemaError, match="bit depth is unknown"):
        oecf.recover_oecf(series.drop_attrs())
    with pytest.raises(CalibrationError, match="bit_depth must be an integer in 8..16"):
        oecf.recover_oecf(series, bit_depth=20)
    with pytest.raises(SchemaError, match="integers"):
        oecf.recover_oecf(series.astype(float))
    with pytest.raises(CalibrationError, match="at least 2 exposures"):
        oecf.recover_oecf(series.isel(exposure=[0]))
    with pytest.raises(CalibrationError, match="positive"):
        oecf.recover_oecf(series.assign_coords(exposure_time=("exposure", -TIMES)))
    with pytest.raises(CalibrationError, match="weighting 'box' is unknown"):
        oecf.weighting_function(np.arange(3), black_level=0, saturation=2, kind="box")
    with pytest.raises(CalibrationError, match="saturated pixels"):
        sat = series.copy(data=series.values.copy())
        sat.values[1, 0, 0] = 255
        oecf.recover_oecf_low_snr(sat, xr.DataArray(
            np.zeros((5, 20, 20)), dims=("exposure_time", "y", "x"),
            coords={"exposure_time": TIMES}), filter_size=5)
    with pytest.raises(CalibrationError, match="too small for filter_size"):
        oecf.recover_oecf_low_snr(series.clip(max=200), xr.DataArray(
            np.zeros((5, 20, 20)), dims=("exposure_time", "y", "x"),
            coords={"exposure_time": TIMES}), filter_size=40)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        oecf.recover_oecf(series)  # unequal ratios: no warning
