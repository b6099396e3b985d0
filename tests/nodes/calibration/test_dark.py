import numpy as np
import pytest

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.nodes.calibration.dark import DARK_AVERAGE, average_dark_frames
from spectralize.schemas import SchemaError, validate_dataset
from spectralize.schemas.run import DARK


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
    assert float(out["mean"].sel(exposure_time=0.5).mean()) > float(
        out["mean"].sel(exposure_time=0.01).mean()) + 5
    # read noise of 3 DN (plus quantisation) is what the std sees
    assert 2.8 < float(out["std"].median()) < 3.3


def test_population_std_is_selectable(raw):
    out = average_dark_frames(raw, ddof=0)
    np.testing.assert_allclose(out["std"].values, raw.frames.values.astype(float).std(axis=1),
                               rtol=1e-5)


def test_saturated_dark_frames_warn_and_are_not_clipped(raw):
    hot = raw.copy()
    frames = hot.frames.values.copy()
    frames[0, :, 0, 0] = 1023
    hot["frames"] = (hot.frames.dims, frames, hot.frames.attrs)
    with pytest.warns(RuntimeWarning, match="37 pixel value"):
        out = average_dark_frames(hot)
    assert float(out["mean"][0, 0, 0]) == 1023.0


def test_bad_input_names_the_array(raw):
    with pytest.raises(SchemaError, match="raw/dark:frames: expected dtype uint16, found dtype float64"):
        average_dark_frames(raw.assign(frames=raw.frames.astype(float)))
    with pytest.raises(SchemaError, match="at least 2 frames"):
        average_dark_frames(raw.isel(frame=slice(0, 1)))


def test_node_declaration_runs_the_function(raw):
    out = DARK_AVERAGE({"raw_dark": raw}, {"frames_per_chunk": 4})
    assert list(out) == ["dark"]
    np.testing.assert_allclose(out["dark"]["mean"].values,
                               raw.frames.values.astype(float).mean(axis=1), rtol=1e-6)
