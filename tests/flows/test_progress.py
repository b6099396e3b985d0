"""Progress display: the store's region messages drive it, plain lines carry an ETA, the rich
bar renders, and Prefect's console is quiet unless verbose."""

import io
import logging
import sys

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.flows import progress
from spectralize.flows.progress import (
    PlainProgress,
    RichProgress,
    format_seconds,
    listening,
    quiet_prefect,
    store_message,
)
from spectralize.schemas import RunStore


class Recorder:
    def __init__(self):
        self.calls = []

    def step_started(self, *args):
        self.calls.append(("step_started", *args))

    def stage(self, *args):
        self.calls.append(("stage", *args))

    def regions(self, *args):
        self.calls.append(("regions", *args))

    def step_finished(self, *args):
        self.calls.append(("step_finished", *args))


def lazy_cube(fail_at=None):
    def block(i):
        if i == fail_at:
            raise RuntimeError(f"crash in region {i}")
        return np.full((1, 4, 4), i, np.float32)

    pieces = [da.from_delayed(dask.delayed(block)(i), (1, 4, 4), np.float32) for i in range(4)]
    return xr.Dataset({"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})})


def test_the_store_region_messages_drive_the_display_also_when_resuming(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    recorder = Recorder()

    def write(ds):
        resumed = {}
        store.write(
            "cube",
            ds,
            fingerprint="fp",
            resumable_along="image",
            progress=lambda message: store_message("node", "cube", message, resumed),
        )

    with listening(recorder):
        with pytest.raises(RuntimeError, match="region 2"):
            write(lazy_cube(fail_at=2))
        assert recorder.calls == [
            ("regions", "node", "cube", 1, 4, 0),
            ("regions", "node", "cube", 2, 4, 0),
        ]
        recorder.calls.clear()
        write(lazy_cube())
    assert recorder.calls == [
        ("regions", "node", "cube", 2, 4, 2),  # written by the failed run
        ("regions", "node", "cube", 3, 4, 2),
        ("regions", "node", "cube", 4, 4, 2),
    ]
    progress.notify("regions", "node", "cube", 4, 4, 0)  # no listener left: nothing happens
    assert len(recorder.calls) == 3


def test_plain_lines_say_the_node_the_image_sets_and_the_time_left():
    now = [100.0]
    out = io.StringIO()
    display = PlainProgress(out, clock=lambda: now[0])
    display.step_started(10, 12, "reconstruct_image_sets")
    display.stage("reconstruct_image_sets", "computing and writing spectra")
    display.regions("reconstruct_image_sets", "spectra", 3, 10, 3)  # resumed
    now[0] = 130.0
    display.regions("reconstruct_image_sets", "spectra", 4, 10, 3)
    now[0] = 160.0
    display.regions("reconstruct_image_sets", "spectra", 5, 10, 3)  # 30 s per set, 5 left
    display.step_finished("reconstruct_image_sets", "ran", 75.0)
    assert out.getvalue().splitlines() == [
        "[10/12] reconstruct_image_sets",
        "    reconstruct_image_sets: computing and writing spectra",
        "    reconstruct_image_sets: spectra: 3/10 image set(s) written by an earlier run, resuming",
        "    reconstruct_image_sets: spectra: 4/10 image set(s) written, about 3 min 00 s left",
        "    reconstruct_image_sets: spectra: 5/10 image set(s) written, about 2 min 30 s left",
        "    reconstruct_image_sets: done in 1 min 15 s",
    ]


def test_format_seconds():
    assert [format_seconds(s) for s in (4.4, 65, 7300)] == ["4 s", "1 min 05 s", "2 h 01 min"]


def test_the_rich_bar_renders_on_a_terminal():
    from rich.console import Console

    out = io.StringIO()
    with RichProgress(Console(file=out, force_terminal=True, width=100)) as display:
        with listening(display):
            progress.notify("step_started", 1, 2, "reconstruct_image_sets")
            progress.notify("stage", "reconstruct_image_sets", "computing and writing spectra")
            for done in range(1, 5):
                progress.notify("regions", "reconstruct_image_sets", "spectra", done, 4, 0)
                display.progress.refresh()
            text = out.getvalue()
            progress.notify("step_finished", "reconstruct_image_sets", "ran", 3.0)
    assert "spectra: image sets" in text and "4/4" in text
    assert "[1/2] reconstruct_image_sets: done in 3 s" in out.getvalue()


def test_a_failing_display_is_dropped_not_the_run(capsys):
    class Broken(Recorder):
        def stage(self, *args):
            raise ValueError("boom")

    broken = Broken()
    with listening(broken):
        progress.notify("stage", "node", "computing")
        progress.notify("stage", "node", "computing")  # dropped after the first error
        progress.notify("step_finished", "node", "ran", 1.0)
    assert capsys.readouterr().err.count("progress display stopped: ValueError: boom") == 1
    assert broken.calls == []


def test_prefect_console_is_quiet_unless_verbose(monkeypatch):
    monkeypatch.delenv(progress._CONSOLE_LEVEL, raising=False)
    quiet_prefect(verbose=False)
    assert progress.os.environ[progress._CONSOLE_LEVEL] == "WARNING"
    if "prefect" in sys.modules:  # already configured in this process: its handlers follow
        handlers = [
            h for h in logging.getLogger().handlers if type(h).__name__ == "PrefectConsoleHandler"
        ]
        assert all(h.level == logging.WARNING for h in handlers)
    quiet_prefect(verbose=True)
    assert progress.os.environ[progress._CONSOLE_LEVEL] == "INFO"
