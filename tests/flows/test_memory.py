"""The peak resident memory of a block, and of each node of a flow run (flows/memory.py)."""

import json
import subprocess
import sys

import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Node, RegisteredNode, Step
from spectralize.engine import discovery as engine
from spectralize.flows.memory import (
    PeakMemory,
    release_free_memory,
    resident_bytes,
)
from spectralize.flows.runtime import run_steps
from spectralize.store import RunStore

BALLAST = 200_000_000  # bytes allocated (and touched) inside the measured block

measurable = resident_bytes() is not None and PeakMemory().__enter__()._measuring


def allocate(nbytes: int) -> float:
    """Allocate ``nbytes``, touch every page, free it; a checksum keeps it from being skipped."""
    ballast = np.ones(nbytes // 8)
    return float(ballast[:: 4096 // 8].sum())


_BLOCKS = """
import json
import numpy as np
from spectralize.flows.memory import PeakMemory, process_peak_bytes, resident_bytes

def allocate(nbytes):
    ballast = np.ones(nbytes // 8)
    return float(ballast[:: 4096 // 8].sum())

with PeakMemory() as first:
    allocate({ballast})
with PeakMemory() as second:
    allocate({ballast} // 100)
print(json.dumps({{
    "first": first.peak_bytes, "second": second.peak_bytes, "first_gb": first.peak_gb,
    "process": process_peak_bytes(), "hwm": resident_bytes("VmHWM"),
}}))
"""


def test_a_block_sees_its_own_allocation_and_the_next_one_does_not():
    if measurable:
        # in a fresh process: a test worker's heap, left resident by the tests before, can
        # serve the ballast without a new page, and its other threads allocate while the
        # blocks run
        found = subprocess.run(
            [sys.executable, "-c", _BLOCKS.format(ballast=BALLAST)],
            capture_output=True,
            text=True,
            check=True,
        )
        peaks = json.loads(found.stdout.strip().splitlines()[-1])
        assert peaks["first"] - peaks["second"] > 0.75 * BALLAST
        assert peaks["first_gb"] == pytest.approx(peaks["first"] / 1e9)
        # the whole process's peak keeps what the resets hid from VmHWM
        assert peaks["process"] >= peaks["first"] > peaks["hwm"]
    else:  # not Linux: nothing is measured, and nothing fails
        with PeakMemory() as measured:
            allocate(BALLAST)
        assert measured.peak_bytes is None and measured.peak_gb is None


def dark_level(dark: xr.Dataset) -> xr.Dataset:
    """A small downstream node: one dark level per exposure time."""
    level = dark["mean"].median(dim=("y", "x"))
    return xr.Dataset({"level": level.astype(np.float32).assign_attrs(units="DN")})


def test_memory_freed_inside_the_heap_goes_back_to_the_system():
    """Blocks of 64 kB (glibc's heap, below its mmap threshold) freed around survivors stay
    resident until released; released, the resident set drops by most of them."""
    blocks = [np.ones(8_000) for _ in range(BALLAST // 64_000)]  # 64 kB each, touched
    survivors = blocks[::16]  # every 16th stays: the free ones are inside the heap, not at its top
    del blocks
    import gc

    gc.collect()
    before = resident_bytes("VmRSS")
    released = release_free_memory()  # where nothing is measurable, it must not fail
    after = resident_bytes("VmRSS")
    assert len(survivors) == BALLAST // 64_000 // 16 + 1
    if released and before is not None and after is not None:  # glibc on Linux
        assert before - after > 0.5 * BALLAST


@pytest.fixture
def ballast_node(monkeypatch):
    """The installed nodes, ``dark_average`` allocating 200 MB while it runs."""
    installed = dict(engine.registry(refresh=True))
    dark = installed["dark_average"].node

    def heavy(raw_dark, **kwargs):
        allocate(BALLAST)
        return dark.function(raw_dark, **kwargs)

    heavy.__signature__ = __import__("inspect").signature(dark.function)
    installed["dark_average"] = RegisteredNode(Node(**{**dark.__dict__, "function": heavy}), "test")
    level = Node(
        name="dark_level", function=dark_level, inputs={"dark": "dark"}, outputs=("dark_level",)
    )
    installed["dark_level"] = RegisteredNode(level, "test")
    monkeypatch.setattr(engine, "_installed", lambda: installed)
    return installed


def test_each_node_reports_its_own_peak(prefect_api, ballast_node, tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    raw = make_raw_dark(frames=4, shape=(6, 8), exposure_times=(0.1, 0.3))
    store.write("raw/dark", raw, fingerprint="raw-v1")
    report = run_steps(store.path, [Step("dark_average"), Step("dark_level")])
    peaks = {step.node: step.peak_rss_gb for step in report.steps}
    assert [step.status for step in report.steps] == ["ran", "ran"]
    if measurable:
        # the 200 MB show in dark_average's peak, not in the next node's
        assert peaks["dark_average"] - peaks["dark_level"] > 0.75 * BALLAST / 1e9
        assert report.peak_rss_gb >= peaks["dark_average"]
    else:
        assert peaks == {"dark_average": None, "dark_level": None}


def test_the_summary_lines_carry_each_node_s_peak_for_the_benchmarks(capsys):
    """The CLI's summary and the full-run benchmark's parser agree (benchmarks/full_run.py)."""
    import importlib.util
    import io
    from pathlib import Path

    from spectralize.flows.cli import _print_report
    from spectralize.flows.progress import PlainProgress
    from spectralize.flows.steps import RunReport, StepReport

    steps = [
        StepReport("dark_average", "ran", 1.3, {"dark": "f1"}, peak_rss_gb=0.321),
        StepReport("hdr_merge", "skipped", 0.0, {"hdr": "f2"}),
        StepReport("reconstruct_image_sets", "ran", 239.4, {"spectra": "f3"}, peak_rss_gb=1.06),
    ]
    _print_report(RunReport("run.zarr", "btf", steps, peak_rss_gb=1.2))
    summary = capsys.readouterr().out
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "full_run.py"
    spec = importlib.util.spec_from_file_location("full_run_benchmark", path)
    full_run = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(full_run)
    assert full_run.node_seconds(summary) == {"dark_average": 1.3, "reconstruct_image_sets": 239.4}
    assert full_run.node_peak_rss_gb(summary) == {"dark_average": 0.32, "reconstruct_image_sets": 1.06}
    assert full_run.process_peak_rss_gb(summary) == 1.2

    out = io.StringIO()
    display = PlainProgress(out)
    display.step_peak("hdr_merge", 0.5)
    display.step_finished("hdr_merge", "ran", 3.0)
    display.step_finished("dark_average", "ran", 2.0)  # not measured: no peak
    assert out.getvalue().splitlines() == [
        "    hdr_merge: done in 3 s, peak 0.50 GB resident",
        "    dark_average: done in 2 s",
    ]
