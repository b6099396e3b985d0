import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.nodes.calibration.dark import average_dark_frames, dark_frames_at
from spectralize.nodes.calibration.declarations import DARK_AVERAGE
from spectralize.schemas import CalibrationError, SchemaError, validate_dataset
from spectralize.schemas.run import DARK, RAW_DARK


@pytest.fixture(scope="module")
def raw():
    return make_raw_dark(frames=37, shape=(9, 11), exposure_times=(0.01, 0.5), frames_per_chunk=8)


@pytest.mark.parametrize("frames_per_chunk", [1, 5, 64])
def test_mean_and_std_match_numpy_whatever_the_chunking(raw, frames_per_chunk):
    out = average_dark_frames(raw, frames_per_chunk=frames_per_chunk)
    stack = raw.frames.values.astype(np.float64)
    np.testing.assert_allclose(out["mean"].values, stack.mean(axis=1), rtol=1e-6)
    np.testing.assert_allclose(out["std"].values, stack.std(axis=1, ddof=1), rtol=1e-5)
    assert out["mean"].dtype == np.float32 and out["std"].dtype == np.float32
    assert validate_dataset(out, DARK) == []
    assert out.attrs["frame_count"] == 37


def test_dark_mean_recovers_the_simulated_dark_level(raw):
    out = average_dark_frames(raw)
    # long exposures accumulate dark current: the mean rises with exposure time
    assert (
        float(out["mean"].sel(exposure_time=0.5).mean())
        > float(out["mean"].sel(exposure_time=0.01).mean()) + 5
    )
    # read noise of 3 DN (plus quantisation) is what the std sees
    assert 2.8 < float(out["std"].median()) < 3.3


def test_population_std_is_selectable(raw):
    out = average_dark_frames(raw, ddof=0)
    np.testing.assert_allclose(out["std"].values, raw.frames.values.astype(float).std(axis=1), rtol=1e-5)


def test_saturated_dark_frames_warn_and_are_not_clipped(raw):
    hot = raw.copy()
    frames = hot.frames.values.copy()
    frames[0, :, 0, 0] = 1023
    hot["frames"] = (hot.frames.dims, frames, hot.frames.attrs)
    with pytest.warns(RuntimeWarning, match="37 pixel value"):
        out = average_dark_frames(hot)
    assert float(out["mean"][0, 0, 0]) == 1023.0


def test_bad_input_names_the_array(raw):
    # the contract is the schema's (the engine validates every input group against it)
    problems = validate_dataset(raw.assign(frames=raw.frames.astype(float)), RAW_DARK)
    assert "raw/dark:frames: expected dtype uint16, found dtype float64" in map(str, problems)
    with pytest.raises(SchemaError, match="at least 2 frames"):
        average_dark_frames(raw.isel(frame=slice(0, 1)))


def test_node_declaration_runs_the_function(raw):
    out = DARK_AVERAGE({"raw_dark": raw}, {"frames_per_chunk": 4})
    assert list(out) == ["dark"]
    np.testing.assert_allclose(
        out["dark"]["mean"].values, raw.frames.values.astype(float).mean(axis=1), rtol=1e-6
    )


# -- the one dark-frame lookup ---------------------------------------------------------------
@pytest.fixture(scope="module")
def dark(raw):
    return average_dark_frames(raw).load()


def test_dark_frames_at_selects_per_exposure_time(dark):
    times = np.array([0.5, 0.01, 0.5 * (1 + 1e-8)])  # any order, within rtol
    out = dark_frames_at(dark, times, used_by="test", dim="shot", frame_shape=(9, 11))
    assert out["mean"].dims == ("shot", "y", "x") and set(out.data_vars) == {"mean", "std"}
    np.testing.assert_array_equal(out["exposure_time"].values, [0.5, 0.01, 0.5])
    np.testing.assert_array_equal(out["mean"].values[1], dark["mean"].sel(exposure_time=0.01))
    only_mean = dark_frames_at(dark["mean"], times[:1], used_by="test")
    assert set(only_mean.data_vars) == {"mean"}
    unsorted = dark.isel(exposure_time=[1, 0])
    xr.testing.assert_identical(
        dark_frames_at(unsorted, times, used_by="test"), dark_frames_at(dark, times, used_by="test")
    )


def test_missing_dark_exposure_time_is_named_with_the_available_ones(dark):
    with pytest.raises(
        CalibrationError,
        match=r"dark:mean has no frame for exposure_time 0.2 s \(shot 1\) used "
        r"by band_signal; dark frames exist for \[0.01, 0.5\] s",
    ):
        dark_frames_at(dark, [0.5, 0.2], used_by="band_signal")
    with pytest.raises(CalibrationError, match=r"exposure_times \[0.2, 0.3\] s \(exposures \[0, 2\]\)"):
        dark_frames_at(dark, [0.2, 0.01, 0.3], used_by="x", dim="exposure")
    with pytest.raises(CalibrationError, match="no frame for exposure_time 0.5001 s"):
        dark_frames_at(dark, [0.5001], used_by="x")  # beyond the relative tolerance


def test_dark_frames_of_another_size_or_shape(dark):
    with pytest.raises(
        CalibrationError, match="dark:mean frames are 9x11 px but the frames of x are 8x11 px"
    ):
        dark_frames_at(dark, [0.5], used_by="x", frame_shape=(8, 11))
    with pytest.raises(SchemaError, match=r"dark:mean: expected dims \(exposure_time, y, x\)"):
        dark_frames_at(dark["mean"].rename(y="row"), [0.5], used_by="x")


# -- the dark level as a line in exposure time ------------------------------------------------
def _few_frames(frames: int = 6, hot_saturates: bool = False) -> tuple[xr.Dataset, np.ndarray]:
    """Dark frames of 12 exposure times, ``frames`` each: offset + current * t + read noise
    (3 DN); pixel (0, 0) hot, at the maximum code in the longest darks when ``hot_saturates``."""
    rng = np.random.default_rng(3)
    times = np.geomspace(0.01, 5.0, 12)
    offset = 60 + rng.normal(0, 2, (8, 10))
    current = rng.gamma(4.0, 0.5, (8, 10))
    current[0, 0] = 400.0 if hot_saturates else current[0, 0]
    level = offset[None] + current[None] * times[:, None, None]
    stack = level[:, None] + rng.normal(0, 3.0, (times.size, frames, 8, 10))
    counts = np.clip(np.round(stack), 0, 1023).astype(np.uint16)
    raw = xr.Dataset(
        {"frames": (("exposure_time", "frame", "y", "x"), counts, {"units": "DN"})},
        coords={"exposure_time": ("exposure_time", times, {"units": "s"})},
        attrs={"bit_depth": 10, "camera": "mono"},
    )
    return raw, np.minimum(level, 1023.0)


def test_a_line_in_exposure_time_averages_every_frame_of_the_series():
    """Six frames per exposure time: the per-time mean is off by about 3 / sqrt(6) DN; the
    line through all 72 frames per pixel is several times closer to the true dark level."""
    raw, truth = _few_frames()
    line = average_dark_frames(raw)
    alone = average_dark_frames(raw, model="per-time")
    assert line.attrs["dark_model"].startswith("per pixel a line")
    assert line.attrs["pixels_on_line"] > 0.95
    assert validate_dataset(line, DARK) == []
    err_line = np.sqrt(np.mean((line["mean"].values - truth) ** 2))
    err_alone = np.sqrt(np.mean((alone["mean"].values - truth) ** 2))
    assert err_line < 0.5 * err_alone, (err_line, err_alone)
    np.testing.assert_allclose(line["std"].values, alone["std"].values)


def test_a_hot_pixel_at_the_maximum_code_keeps_its_own_means():
    raw, _ = _few_frames(hot_saturates=True)
    with pytest.warns(RuntimeWarning, match=r"in 1 pixel\(s\): hot pixels in long darks"):
        line = average_dark_frames(raw)
    alone = average_dark_frames(raw, model="per-time")
    # the line holds for the frames below the maximum; where it does not, its own means
    hot = line["mean"].values[:, 0, 0]
    assert np.all(np.isfinite(hot)) and hot.max() <= 1023.0
    on = line["mean"].values[:, 1:, 1:] != alone["mean"].values[:, 1:, 1:]
    assert on.any()
    with pytest.raises(CalibrationError, match="model must be one of"):
        average_dark_frames(raw, model="spline")


def test_the_line_is_fitted_a_block_of_rows_at_a_time_with_the_same_result(monkeypatch):
    from spectralize.nodes.calibration import dark as module

    raw, _ = _few_frames()
    whole = average_dark_frames(raw)
    monkeypatch.setattr(module, "LINEAR_DARK_BLOCK", 12 * 10 * 3)  # three rows per block
    xr.testing.assert_identical(average_dark_frames(raw), whole)
