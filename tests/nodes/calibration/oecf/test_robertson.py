"""Tests of spectralize.nodes.calibration.oecf.robertson: Robertson 2003 OECF recovery."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import isotonic_regression

from spectralize.nodes.calibration import oecf
from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf
from spectralize.nodes.simulation.camera_model import capture, response_model
from spectralize.schemas import CalibrationError, SchemaError


# -- recovery of known responses ----------------------------------------------------------------
@pytest.mark.parametrize("model", ["gamma", "log", "s_curve"])
@pytest.mark.parametrize(
    ("bit_depth", "pixels"), [(8, 20_000), (10, 60_000), (12, 60_000), (16, 40_000)]
)
def test_recovers_known_responses(
    model: str, bit_depth: int, pixels: int, noise_for, exposure_series, relative_errors, as_dataarray
) -> None:
    counts, truth = exposure_series(model, bit_depth=bit_depth, pixels=pixels)
    offset, sigma = noise_for(bit_depth)
    result = oecf.recover_oecf(as_dataarray(counts, bit_depth), black_level=int(offset + 3 * sigma))
    response = result["response"]
    assert response.dims == ("code",)
    assert response.sizes["code"] == 2**bit_depth
    assert response.attrs["converged"] is True
    assert np.all(np.isfinite(response.values))
    assert np.all(np.diff(response.values) >= 0)
    errors = relative_errors(response.values, truth, bit_depth)
    assert np.median(errors) < 0.005, np.median(errors)
    assert errors.max() < 0.025, errors.max()


def test_response_contract_and_normalisation(exposure_series, as_dataarray) -> None:
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


def test_convergence_is_checked_not_a_fixed_count(TIMES, exposure_series) -> None:
    counts, _ = exposure_series("log", bit_depth=8, pixels=4_000)
    weights = oecf.weighting_function(np.arange(256), black_level=4, saturation=255)
    loose = oecf.robertson_response(
        counts, TIMES, n_codes=256, weights=weights, tolerance=1e-3, solver="power"
    )
    tight = oecf.robertson_response(
        counts, TIMES, n_codes=256, weights=weights, tolerance=1e-9, solver="power"
    )
    capped = oecf.robertson_response(
        counts, TIMES, n_codes=256, weights=weights, tolerance=1e-12, max_iterations=3, solver="power"
    )
    assert loose.converged and tight.converged and not capped.converged
    assert loose.iterations < tight.iterations
    assert tight.change < 1e-9 <= loose.change or loose.change < 1e-3
    assert capped.iterations == 3 and capped.change > 1e-12


def test_solvers_and_operators_reach_the_same_fixed_point(TIMES, exposure_series) -> None:
    counts, _ = exposure_series("s_curve", bit_depth=10, pixels=8_000)
    weights = oecf.weighting_function(np.arange(1024), black_level=25, saturation=1023)
    reference = oecf.robertson_response(
        counts,
        TIMES,
        n_codes=1024,
        weights=weights,
        tolerance=1e-10,
        solver="power",
        operator="samples",
        max_iterations=50_000,
    )
    for solver, operator in [
        ("lanczos", "dense"),
        ("lanczos", "sparse"),
        ("power", "dense"),
        ("lanczos", "samples"),
    ]:
        other = oecf.robertson_response(
            counts,
            TIMES,
            n_codes=1024,
            weights=weights,
            tolerance=1e-10,
            solver=solver,
            operator=operator,
            max_iterations=50_000,
        )
        assert other.converged
        np.testing.assert_allclose(other.response, reference.response, rtol=1e-5, atol=1e-9)
    fast = oecf.robertson_response(
        counts, TIMES, n_codes=1024, weights=weights, tolerance=1e-10, max_iterations=50_000
    )
    assert fast.iterations < reference.iterations


def test_pixels_without_a_weighted_sample_are_left_out(TIMES, exposure_series) -> None:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=3_000)
    weights = oecf.weighting_function(np.arange(256), black_level=4, saturation=255)
    base = oecf.robertson_response(counts, TIMES, n_codes=256, weights=weights, tolerance=1e-10)
    useless = np.concatenate(
        [np.full((5, 40), 255), np.full((5, 30), 2), np.tile([[1], [3], [255], [255], [255]], 20)],
        axis=1,
    )
    padded = np.concatenate([counts, useless.astype(counts.dtype)], axis=1)
    for operator in ("dense", "samples"):
        other = oecf.robertson_response(
            padded, TIMES, n_codes=256, weights=weights, tolerance=1e-10, operator=operator
        )
        np.testing.assert_array_equal(other.samples, base.samples)
        np.testing.assert_allclose(other.response, base.response, rtol=1e-9)


def test_frame_checks_with_channels_last(TIMES, exposure_series) -> None:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=2_500)
    rgb = np.stack([counts, counts, counts], axis=-1).reshape(5, 50, 50, 3).copy()
    rgb[2, ..., 1] = 1  # one channel of one exposure all dark
    data = xr.DataArray(
        rgb,
        dims=("exposure", "y", "x", "channel"),
        coords={"exposure_time": ("exposure", TIMES)},
        attrs={"bit_depth": 8},
    )
    with pytest.raises(CalibrationError, match=r"frame exposure=2, channel=1 .*entirely dark"):
        oecf.recover_oecf(data, black_level=4)
    rgb[2, ..., 1] = 255
    with pytest.raises(CalibrationError, match=r"channel=1 .*entirely saturated"):
        oecf.recover_oecf(data.copy(data=rgb), black_level=4)


def test_unobserved_codes_are_interpolated_never_nan(TIMES, exposure_series) -> None:
    counts, _ = exposure_series("gamma", bit_depth=8, pixels=5_000)
    sparse_codes = (counts.astype(np.int64) // 4) * 4 + 8  # only every 4th code
    sparse_codes = np.clip(sparse_codes, 0, 255).astype(np.uint16)
    weights = oecf.weighting_function(np.arange(256), black_level=10, saturation=255)
    result = oecf.robertson_response(sparse_codes, TIMES, n_codes=256, weights=weights)
    unseen = np.flatnonzero(result.samples == 0)
    assert unseen.size > 150
    assert np.all(np.isfinite(result.response))
    assert np.all(np.diff(result.response) >= 0)
    seen = np.flatnonzero((result.samples > 0) & (np.arange(256) < 255))  # not saturated
    inner = unseen[(unseen > seen[0]) & (unseen < seen[-1])]
    np.testing.assert_allclose(result.response[inner], np.interp(inner, seen, result.response[seen]))
    assert result.response[0] <= result.response[seen[0]]


def test_per_camera_and_channel_responses(TIMES, relative_errors) -> None:
    rng = np.random.default_rng(4)
    side = 64
    models = [response_model("gamma", gamma=2.2), response_model("log", a=30.0)]
    images = []
    for camera in range(2):
        radiance = np.exp(rng.uniform(np.log(3e-3), np.log(2.0), (side, side, 3)))
        channel_scale = np.array([1.0, 0.8, 0.6])
        images.append(
            capture(
                radiance[None] * channel_scale,
                TIMES[:, None, None, None],
                response=models[camera],
                adc_offset=16,
                noise_sigma=3,
                bit_depth=10,
                seed=rng,
            )
        )
    raw = xr.Dataset(
        {"counts": (("image", "exposure", "y", "x", "channel"), np.stack(images))},
        coords={
            "exposure_time": (("image", "exposure"), np.stack([TIMES, TIMES * 1.3])),
            "channel": ["R", "G", "B"],
            "camera": ("image", [3, 7]),
        },
        attrs={"bit_depth": 10},
    )
    response = oecf.recover_oecf(raw, black_level=25)["response"]
    assert response.dims == ("camera", "channel", "code")
    assert response["camera"].values.tolist() == [3, 7]
    assert response["channel"].values.tolist() == ["R", "G", "B"]
    for index, camera in enumerate([3, 7]):
        for channel in "RGB":
            errors = relative_errors(
                response.sel(camera=camera, channel=channel).values, models[index], 10
            )
            assert np.median(errors) < 0.01


def test_max_pixels_subsample_is_reproducible(
    TIMES, exposure_series, relative_errors, as_dataarray
) -> None:
    counts, truth = exposure_series("gamma", bit_depth=10, pixels=40_000)
    series = as_dataarray(counts, 10)
    a = oecf.recover_oecf(series, black_level=25, max_pixels=10_000, seed=1)["response"]
    b = oecf.recover_oecf(series, black_level=25, max_pixels=10_000, seed=1)["response"]
    xr.testing.assert_identical(a, b)
    assert int(a["samples"].sum()) == 10_000 * len(TIMES)
    assert np.median(relative_errors(a.values, truth, 10)) < 0.01


def test_lazy_input_and_a_shot_dim(TIMES, exposure_series, as_dataarray) -> None:
    counts, _ = exposure_series("log", bit_depth=10, pixels=10_000)
    series = as_dataarray(counts, 10)
    eager = oecf.recover_oecf(series, black_level=25)["response"]
    lazy = oecf.recover_oecf(series.chunk({"y": 50}), black_level=25)["response"]
    xr.testing.assert_allclose(lazy, eager)
    raw_spectral = xr.Dataset(
        {"counts": series.clip(max=1000).rename(exposure="shot")}, attrs={"bit_depth": 10}
    )
    dark = xr.DataArray(
        np.full((5, 100, 100), 15.5), dims=("exposure_time", "y", "x"), coords={"exposure_time": TIMES}
    )
    low = oecf.recover_oecf_low_snr(raw_spectral, dark, filter_size=5)["response"]
    assert low.dims == ("code",) and low.attrs["converged"] is True


def test_geometric_exposure_series_warns(exposure_series, as_dataarray) -> None:
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
@given(
    increments=st.lists(st.floats(0.3, 3.0), min_size=4, max_size=8),
    seed=st.integers(0, 1000),
    time_scale=st.floats(1e-3, 1e3),
)
def test_monotone_responses_are_recovered_monotone(
    increments: list[float], seed: int, time_scale: float, TIMES
) -> None:
    truth = _TabulatedResponse(increments)
    rng = np.random.default_rng(seed)
    radiance = np.exp(rng.uniform(np.log(2e-3), np.log(2.0), 6_000))
    counts = capture(
        radiance[None, :],
        TIMES[:, None],
        response=truth,
        adc_offset=4,
        noise_sigma=0.75,
        bit_depth=8,
        seed=rng,
    )
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


def _pool_adjacent_violators(values: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The hand-written weighted PAVA the project used before scipy 1.12's (reference)."""
    y = np.asarray(values, dtype=np.float64)
    w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=np.float64)
    if y.size == 0 or np.all(np.diff(y) >= 0):
        return y.copy()
    means: list[float] = []
    sums: list[float] = []
    lengths: list[int] = []
    for value, weight in zip(y.tolist(), w.tolist(), strict=True):
        means.append(value)
        sums.append(weight)
        lengths.append(1)
        while len(means) > 1 and means[-2] > means[-1]:
            total = sums[-2] + sums[-1]
            merged = (means[-2] * sums[-2] + means[-1] * sums[-1]) / total
            length = lengths[-2] + lengths[-1]
            del means[-1], sums[-1], lengths[-1]
            means[-1], sums[-1], lengths[-1] = merged, total, length
    return np.repeat(np.asarray(means), lengths)


@settings(max_examples=25, deadline=None)
@given(values=st.lists(st.floats(-10, 10), min_size=1, max_size=40))
def test_isotonic_regression_is_monotone_and_mean_preserving(values: list[float]) -> None:
    fitted = isotonic_regression(np.array(values)).x
    assert np.all(np.diff(fitted) >= -1e-12)
    assert fitted.sum() == pytest.approx(sum(values), abs=1e-9)


@settings(max_examples=50, deadline=None)
@given(values=st.lists(st.floats(-10, 10), min_size=1, max_size=60), seed=st.integers(0, 2**31 - 1))
def test_scipy_isotonic_regression_equals_the_former_pava(values: list[float], seed: int) -> None:
    # scipy's `weights` are the same case weights (samples per code) the hand-written
    # pool-adjacent-violators took: a weighted mean per pooled block
    y = np.array(values)
    weights = np.random.default_rng(seed).integers(1, 500, y.size).astype(float)
    np.testing.assert_allclose(isotonic_regression(y).x, _pool_adjacent_violators(y), rtol=0, atol=1e-12)
    np.testing.assert_allclose(
        isotonic_regression(y, weights=weights).x,
        _pool_adjacent_violators(y, weights),
        rtol=1e-12,
        atol=1e-12,
    )


def test_scipy_isotonic_regression_on_a_recovered_response(exposure_series) -> None:
    # the projection robertson_response makes: a noisy response, weighted by samples per code
    counts, _ = exposure_series("s_curve", bit_depth=10, pixels=8_000)
    weights = oecf.weighting_function(np.arange(1024), black_level=25, saturation=1023)
    raw = oecf.robertson_response(
        counts,
        np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0,
        n_codes=1024,
        weights=weights,
        monotone=False,
    )
    seen = raw.samples > 0
    f, n = raw.response[seen], raw.samples[seen].astype(float)
    assert np.any(np.diff(f) < 0)  # something to project
    np.testing.assert_allclose(
        isotonic_regression(f, weights=n).x, _pool_adjacent_violators(f, n), rtol=1e-12, atol=1e-12
    )


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
    with pytest.raises(CalibrationError, match=f"exposure_time.*{word}"):
        oecf.recover_oecf(series)


def test_all_saturated_or_all_dark_frame(TIMES, small_series) -> None:
    series = small_series()
    saturated = series.copy(data=series.values.copy())
    saturated.values[4] = 255
    with pytest.raises(CalibrationError, match=r"frame exposure=4 .*saturated.*255"):
        oecf.recover_oecf(saturated)
    dark = series.copy(data=series.values.copy())
    dark.values[0] = 3
    with pytest.raises(CalibrationError, match=r"exposure_time 0.0166.*dark \(<= black_level"):
        oecf.recover_oecf(dark, black_level=3)
    everything = series.copy(data=np.full(series.shape, 255, dtype=np.uint16))
    weights = oecf.weighting_function(np.arange(256), black_level=0, saturation=255)
    with pytest.raises(CalibrationError, match="every sample is saturated or under-exposed"):
        oecf.robertson_response(everything.values.reshape(5, -1), TIMES, n_codes=256, weights=weights)


def test_mismatched_shapes(TIMES, low_snr_series) -> None:
    weights = oecf.weighting_function(np.arange(256), black_level=0, saturation=255)
    with pytest.raises(CalibrationError, match=r"got codes \(5, 10\), exposure_times \(4,\)"):
        oecf.robertson_response(np.zeros((5, 10), np.uint8), TIMES[:4], n_codes=256, weights=weights)
    series, dark, _ = low_snr_series(side=48)
    with pytest.raises(SchemaError, match="wrong dims"):
        oecf.recover_oecf(series.expand_dims(band=2))


def test_other_bad_input(TIMES, small_series) -> None:
    series = small_series()
    with pytest.raises(CalibrationError, match=r"must lie in \[0, 255\].*found \[.*, 300\]"):
        bad = series.copy(data=series.values.copy())
        bad.values[2, 0, 0] = 300
        oecf.recover_oecf(bad)
    with pytest.raises(SchemaError, match="bit depth is unknown"):
        oecf.recover_oecf(series.drop_attrs())
    with pytest.raises(SchemaError, match="an integer in 8..16, found 20"):
        oecf.recover_oecf(series, bit_depth=20)
    with pytest.raises(SchemaError, match="integers"):
        oecf.recover_oecf(series.astype(float))
    with pytest.raises(CalibrationError, match="at least 2 exposures"):
        oecf.recover_oecf(series.isel(exposure=[0]))
    with pytest.raises(CalibrationError, match="positive"):
        oecf.recover_oecf(series.assign_coords(exposure_time=("exposure", -TIMES)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        oecf.recover_oecf(series)  # unequal ratios: no warning


def test_rgb_oecf_per_camera_by_default_each_with_its_black_level_and_pooling_warns(TIMES) -> None:
    """Issue 25, item 1: cameras of two models get their own responses and black levels;
    pooling them is allowed but warned about with the measured difference."""
    rng = np.random.default_rng(5)
    side = 48
    models = [response_model("gamma", gamma=2.2), response_model("log", a=30.0)]
    offsets = [40, 16]
    images = []
    for camera in range(2):
        radiance = np.exp(rng.uniform(np.log(3e-3), np.log(2.0), (side, side, 3)))
        images.append(
            capture(
                radiance[None],
                TIMES[:, None, None, None],
                response=models[camera],
                adc_offset=offsets[camera],
                noise_sigma=2,
                bit_depth=10,
                seed=rng,
            )
        )
    raw = xr.Dataset(
        {"counts": (("image", "exposure", "y", "x", "channel"), np.stack(images))},
        coords={
            "exposure_time": (("image", "exposure"), np.stack([TIMES, TIMES])),
            "channel": ["R", "G", "B"],
            "camera": ("image", [0, 1]),
        },
        attrs={"bit_depth": 10},
    )
    own = recover_rgb_oecf(raw)
    assert own.attrs["per_camera"] and own["response"]["camera"].values.tolist() == [0, 1]
    low, high = own.attrs["black_levels"]
    assert low > high and own.attrs["black_level"] == high  # each camera's own floor
    quarter = own["response"].sel(channel="G").isel(code=256).values  # the two models differ
    assert abs(quarter[0] / quarter[1] - 1) > 0.1
    declared = recover_rgb_oecf(raw.assign_attrs(black_level_dn=[40, -1]))
    assert declared.attrs["black_levels"][0] == 43  # capture.toml's black_level_dn + 3
    with pytest.warns(UserWarning, match=r"per_camera=False pools cameras whose own responses differ"):
        pooled = recover_rgb_oecf(raw, per_camera=False)
    assert not pooled.attrs["per_camera"]
    # by default each camera's response smoothed in the log code, its coefficients chosen per
    # channel on the camera's own series; a channel whose recovered response predicts its
    # codes best (knots 0: these responses have no ripple) keeps it exactly
    recovered = recover_rgb_oecf(raw, log_spline=False)
    knots = np.reshape(own["response"].attrs["log_spline_knots"], (2, 3))
    assert all(k == 0 or k >= 5 for k in knots.ravel())
    for camera, channel in np.argwhere(knots == 0):
        np.testing.assert_array_equal(
            own["response"].values[camera, channel], recovered["response"].values[camera, channel]
        )
    assert "log_spline_knots" not in recovered["response"].attrs


# -- the smooth (spline) solution -----------------------------------------------------------------
def _few_materials_series(seed: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 12-bit series of a scene of six materials (crowded exposures) with exposure noise.

    Returns ``(counts (exposure, pixel), times, f_true at every code)``; the response is a
    smooth S-curve over a black offset of 60 DN, as a foreign lab's camera.
    """
    rng = np.random.default_rng(seed)
    materials = np.array([0.8, 1.9, 3.5, 6.0, 11.0, 20.0])
    radiance = materials[rng.integers(0, 6, 60_000)] * np.exp(rng.normal(0.0, 0.15, 60_000))
    times = np.array([0.002, 0.004, 0.012, 0.024, 0.072])
    y = times[:, None] * radiance[None, :]
    y = y * (1 + rng.normal(0.0, 1.0, y.shape) * np.sqrt(1 / (5000.0 * np.maximum(y, 1e-6))))

    def s_curve(v: np.ndarray) -> np.ndarray:
        p = np.power(np.clip(v, 0.0, None), 1.3)
        return p / (p + 0.5**1.3) * (1 + 0.5**1.3)

    counts = np.clip(np.round(60 + 4035 * s_curve(y) + rng.normal(0.0, 1.2, y.shape)), 0, 4095)
    fine = np.linspace(0.0, 1.3, 400_001)
    codes = np.arange(4096.0)
    f_true = np.interp((codes - 60) / 4035, s_curve(fine), fine)
    return counts.astype(np.uint16), times, f_true


def test_smooth_response_removes_the_ripples_of_crowded_exposures() -> None:
    counts, times, f_true = _few_materials_series()
    weights = oecf.weighting_function(np.arange(4096), black_level=63, saturation=4095)
    codes = np.arange(4096)
    keep = (codes >= 150) & (codes <= 3900)

    def errors(smooth: int | None) -> np.ndarray:
        result = oecf.robertson_response(counts, times, n_codes=4096, weights=weights, smooth=smooth)
        assert result.converged
        assert np.all(np.isfinite(result.response)) and np.all(np.diff(result.response) >= 0)
        ratio = result.response[keep] / f_true[keep]
        return np.abs(ratio / np.median(ratio) - 1)

    per_code, spline = errors(None), errors(16)
    rms = [float(np.sqrt(np.mean(e**2))) for e in (per_code, spline)]
    # per code: ripples of ~4 % where the six materials crowd the codes; the spline: < 2.5 %
    assert rms[1] < 0.8 * rms[0], rms
    assert spline.max() < 0.65 * per_code.max(), (spline.max(), per_code.max())
    assert spline.max() < 0.025, spline.max()
