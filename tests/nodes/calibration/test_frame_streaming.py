"""The calibration nodes compute frame by frame, never a whole stack of frames (issue 27).

At 2048^2 a float64 frame is 34 MB: a white reference's band series (32 bands x 13
exposures) is 3.5 GB of uint16 and a float64 stack of 32 band shots 1.1 GB, with several
copies in the response's lookup. The nodes reduce their series chunk by chunk instead (per
frame means, patch means, maxima), so that their memory is a few frames per thread.

What is checked: with the calibration targets and dark frames in chunks of one frame and the
band shots in one chunk (as a run store can hold them), and the nodes' frame chunks
(:func:`~spectralize.nodes.calibration.exposure_series.frame_chunks`) bounded to one of these
small frames, as they are to one frame at 2048^2, no dask task of a node returns more than
:data:`MAX_FRAMES` float64 frames' worth of bytes. A node that loads a target series, a stack of shots or their float64 copy in one
piece (``.load()``, ``.values``, ``.compute()`` of the whole stack) makes a task that returns
the whole stack (32 to 416 frames here) and fails. No timing and no resident-memory figure
is involved.
"""

from __future__ import annotations

import dask.array as da
import numpy as np
import pytest
import xarray as xr
from dask.callbacks import Callback

from spectralize.nodes.calibration import exposure_series
from spectralize.nodes.calibration.band_radiance import WRITE_SHOTS, calibrate_bands
from spectralize.nodes.calibration.dark import average_dark_frames
from spectralize.nodes.calibration.exposure_series import FRAME_CHUNK_BYTES, frame_chunks
from spectralize.nodes.calibration.oecf.low_snr import recover_spectral_oecf
from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf
from spectralize.nodes.calibration.registration import estimate_registration
from spectralize.nodes.calibration.spectral import calibrate_spectral
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe

pytestmark = pytest.mark.slow  # a simulated run and three nodes on 416 one-frame chunks: ~15 s

MAX_FRAMES = 8
"""The most float64 frames (8 bytes per pixel each) one task may return: a band's low-SNR
series of uint16 frames, an RGB exposure series, the shots joined for writing fit; the
32-band stacks do not."""


class _LargestResult(Callback):
    """The largest array any dask task returned while it was active [bytes]."""

    def __init__(self) -> None:
        super().__init__()
        self.largest = 0
        self.key = None

    def _posttask(self, key, result, dsk, state, worker_id) -> None:
        size = int(getattr(result, "nbytes", 0) or 0)
        if isinstance(result, tuple | list):
            size = sum(int(getattr(r, "nbytes", 0) or 0) for r in result)
        if size > self.largest:
            self.largest, self.key = size, key


def _per_frame(ds: xr.Dataset, frame_dims: dict[str, list[str]]) -> xr.Dataset:
    """``ds`` with each listed variable in chunks of one frame (1 along its frame dims)."""
    out = ds.copy()
    for name, dims in frame_dims.items():
        out[name] = ds[name].chunk({d: 1 for d in dims} | {"y": -1, "x": -1})
    return out


@pytest.fixture(scope="module")
def run():
    """The tiny simulated run, its inputs in chunks of one frame."""
    raw = {k: v.load() for k, v in simulate_run(get_recipe("tiny")).items() if k != "truth/spectra"}
    dark = average_dark_frames(raw["raw/dark"]).load()
    targets = {
        "spectral_counts": ["wavelength", "spectral_exposure"],
        "rgb_counts": ["camera", "rgb_exposure"],
    }
    return {
        "white": _per_frame(raw["raw/white_reference"], targets),
        "checker": _per_frame(raw["raw/colour_checker"], targets),
        # the band shots in one chunk, as the run store holds them: the node splits them
        "spectral": raw["raw/spectral"].chunk({"shot": -1, "y": -1, "x": -1}),
        "dark": _per_frame(dark, {"mean": ["exposure_time"], "std": ["exposure_time"]}),
        "oecf_rgb": recover_rgb_oecf(raw["raw/rgb"]),
        "registration": estimate_registration(raw["raw/registration"]),
        "frame_bytes": 8 * raw["raw/spectral"].sizes["y"] * raw["raw/spectral"].sizes["x"],
        "stack": raw["raw/white_reference"]["spectral_counts"].sizes["wavelength"],
    }


def _largest_frames(function, run) -> tuple[object, float, object]:
    """``function()``'s result and the largest task result while it ran and while every chunk
    of its lazy outputs was computed (as a writer reads them), in frames."""
    with _LargestResult() as seen:
        result = function()
        for ds in result.values() if isinstance(result, dict) else [result]:
            for variable in ds.data_vars.values():
                if variable.chunks is not None:  # a sum of the chunks returns no stack
                    variable.sum().compute()
    return result, seen.largest / run["frame_bytes"], seen.key


@pytest.fixture(scope="module")
def measured(run):
    """Each node run once on the per-frame inputs: (its result, largest task, its key), with
    frame chunks of one frame (as a 2048^2 frame's float64 bytes fill FRAME_CHUNK_BYTES)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(exposure_series, "FRAME_CHUNK_BYTES", run["frame_bytes"])
        return _measure(run)


def _measure(run):
    oecf = _largest_frames(lambda: recover_spectral_oecf(run["white"], run["dark"]), run)
    spectral = _largest_frames(
        lambda: calibrate_spectral(
            run["white"], run["checker"], run["dark"], run["oecf_rgb"], oecf[0], ridge=1e-3
        ),
        run,
    )
    bands = _largest_frames(
        lambda: calibrate_bands(
            run["spectral"], run["dark"], oecf[0], spectral[0], run["registration"], filter_size=8.0
        ),
        run,
    )
    return {"recover_spectral_oecf": oecf, "calibrate_spectral": spectral, "calibrate_bands": bands}


def test_the_stacks_are_larger_than_the_bound(run):
    assert run["stack"] >= 4 * MAX_FRAMES  # 32 bands: a whole stack would not pass


@pytest.mark.parametrize("node", ["recover_spectral_oecf", "calibrate_spectral", "calibrate_bands"])
def test_no_task_returns_a_stack_of_frames(measured, node):
    _, frames, key = measured[node]
    assert frames <= MAX_FRAMES, f"{node}: a task returned {frames:.1f} frames ({key})"


def test_bands_are_written_a_few_shots_a_chunk(run, measured):
    bands = measured["calibrate_bands"][0]
    assert max(bands["radiance"].chunks[0]) == WRITE_SHOTS < run["spectral"].sizes["shot"]
    assert np.isfinite(bands["radiance"].values).all()


@pytest.mark.parametrize("size", [32, 2048])
def test_frame_chunks_hold_as_many_frames_as_fit_their_bytes(size):
    # lazy, never allocated; one chunk, as a stack read from the store (a fancy-indexed
    # broadcast of one pixel made a graph of size^2 chunks, minutes to build at 2048)
    frames = xr.DataArray(da.zeros((4096, size, size), np.uint16, chunks=-1), dims=("shot", "y", "x"))
    chunks = frame_chunks(frames, ("shot",)).chunks
    assert chunks[1:] == ((size,), (size,))
    per_chunk = max(chunks[0])
    assert per_chunk * 8 * size * size <= max(FRAME_CHUNK_BYTES, 8 * size * size)
    assert per_chunk == (1 if size == 2048 else 4096)  # one 2048^2 frame; all small ones
