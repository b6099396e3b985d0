"""One writer per store, nothing damaged or stale trusted, clear errors: real CLI processes,
real Prefect runs, real zarr stores, real file systems."""

import functools
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import psutil
import pytest
import xarray as xr
from zarr.errors import UnstableSpecificationWarning

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Node, RegisteredNode, Step
from spectralize.engine import discovery as engine
from spectralize.flows import cli
from spectralize.flows.runtime import run_steps
from spectralize.nodes.calibration.dark import average_dark_frames
from spectralize.schemas import SchemaError
from spectralize.store import RunStore, work_dir

EXE = [sys.executable, "-m", "spectralize.flows.cli"]


def spawn(*args):
    env = {**os.environ, "PREFECT_LOGGING_LEVEL": "WARNING"}
    return subprocess.Popen(
        [*EXE, *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def raw_store(path: Path, **kwargs) -> RunStore:
    store = RunStore.create(path)
    sizes = {"frames": 48, "shape": (96, 96), "exposure_times": (0.1, 0.2, 0.4)} | kwargs
    store.write("raw/dark", make_raw_dark(**sizes), fingerprint="raw-v1")
    return store


def lock_note(store: Path) -> dict:
    try:
        return json.loads((work_dir(store) / "lock.json").read_text())
    except (OSError, ValueError):
        return {}


def wait_for(condition, process, what, timeout=120):
    deadline = time.time() + timeout
    while not condition():
        assert process.poll() is None, f"the run ended before {what}: {process.communicate()}"
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


@pytest.mark.slow
def test_second_concurrent_run_fails_clearly_and_the_first_result_is_complete(tmp_path):
    store = raw_store(tmp_path / "run.zarr")
    first = spawn("run", "dark", str(store.path))
    try:
        wait_for(lambda: lock_note(store.path).get("pid") == first.pid, first, "the first run locked")
        second = subprocess.run([*EXE, "run", "dark", str(store.path)], capture_output=True, text=True)
        assert second.returncode == 2
        assert f"store busy: run by pid {first.pid} on host " in second.stderr
        assert "Traceback" not in second.stderr
        out, err = first.communicate(timeout=300)
    finally:
        first.kill()
    assert first.returncode == 0, err
    assert "dark_average             ran" in out
    # the committed result is complete and equal to a single run's
    dark = store.read("dark")
    alone = average_dark_frames(store.read("raw/dark").load())
    np.testing.assert_allclose(dark["mean"].values, alone["mean"].values, rtol=1e-6)
    np.testing.assert_allclose(dark["std"].values, alone["std"].values, rtol=1e-5)
    assert store.validate(deep=True) == [] and store.staging_leftovers() == []


@pytest.mark.slow
def test_sigkill_leaves_no_process_and_the_next_run_marks_the_flow_run_crashed(tmp_path):
    store = raw_store(tmp_path / "run.zarr", frames=96, shape=(160, 160))
    run = spawn("run", "dark", str(store.path), "--set", "frames_per_chunk=2")
    started: list[psutil.Process] = []
    try:
        wait_for(lambda: "flow_run_id" in lock_note(store.path), run, "the flow started")
        started = psutil.Process(run.pid).children(recursive=True)
        assert started, "the embedded Prefect server should be a child of the flow process"
        os.kill(run.pid, signal.SIGKILL)  # the flow process only, not its process group
        run.wait()
        gone, alive = psutil.wait_procs(started, timeout=30)
        assert alive == [], [p.cmdline() for p in alive]
    finally:
        for process in started:
            if process.is_running():
                process.kill()
    flow_run_id = lock_note(store.path)["flow_run_id"]
    assert not store.has("dark")
    rerun = subprocess.run([*EXE, "run", "dark", str(store.path)], capture_output=True, text=True)
    assert rerun.returncode == 0, rerun.stderr
    assert f"taking over the lock of a run that is gone (pid {run.pid}" in rerun.stderr
    assert (
        f"flow run {flow_run_id} of pid {run.pid}" in rerun.stderr
        and "marked it crashed" in rerun.stderr
    )
    assert store.has("dark") and store.validate() == [] and lock_note(store.path) == {}


def hdr_with_nan():
    """A lazy ``hdr`` group following its contract but for two NaN pixels of image 1."""
    import dask.array as da

    radiance = np.ones((2, 3, 3, 3), np.float32)
    radiance[1, 0, :2, 0] = np.nan
    per_image = {name: ("image", [0, 1]) for name in ("camera", "rotation", "led")}
    angles = {
        n: ("image", [10.0, 20.0], {"units": "degree"}) for n in ("theta_i", "phi_i", "theta_o", "phi_o")
    }
    return xr.Dataset(
        {"radiance": (("image", "y", "x", "channel"), da.from_array(radiance), {"units": "1"})},
        coords={"channel": ["R", "G", "B"], **per_image, **angles},
    )


# -- in-process flows against the session's Prefect API ------------------------------------
CALLS = {"hdr_mean": 0}


def hdr_mean(hdr: xr.Dataset) -> xr.Dataset:
    CALLS["hdr_mean"] += 1
    return xr.Dataset(
        {"level": hdr.radiance.mean(("y", "x")).astype(np.float32).assign_attrs(units="1")}
    )


def dark_level(dark: xr.Dataset) -> xr.Dataset:
    CALLS.setdefault("dark_level", 0)
    CALLS["dark_level"] += 1
    return xr.Dataset(
        {"level": dark["mean"].mean(("y", "x")).astype(np.float32).assign_attrs(units="DN")}
    )


@pytest.fixture
def test_nodes(monkeypatch):
    installed = dict(engine.registry(refresh=True))
    for node in (
        Node(name="hdr_mean", function=hdr_mean, inputs={"hdr": "hdr"}, outputs=("hdr_mean",)),
        Node(name="dark_level", function=dark_level, inputs={"dark": "dark"}, outputs=("dark_level",)),
    ):
        installed[node.name] = RegisteredNode(node, "test")
    monkeypatch.setattr(engine, "_installed", lambda: installed)
    CALLS.clear()
    CALLS["hdr_mean"] = 0
    return installed


def test_nan_in_hdr_is_caught_before_any_numerics(prefect_api, test_nodes, tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("hdr", hdr_with_nan(), fingerprint="h")
    with pytest.raises(SchemaError) as info:
        run_steps(store.path, [Step("hdr_mean")])
    assert "hdr:radiance: expected finite values, found 2 NaN/inf value(s) (first at image=1" in str(
        info.value
    )
    assert "node 'hdr_mean' cannot run" in str(info.value)
    assert CALLS["hdr_mean"] == 0 and not store.has("hdr_mean")


def truncate(store, group, variable):
    manifest = store.manifest(group)["files"]
    chunk = store.path / group / sorted(k for k in manifest if k.startswith(f"{variable}/c/"))[0]
    chunk.write_bytes(chunk.read_bytes()[:-5])
    return chunk


def test_damaged_output_is_recomputed_and_its_dependants_run_again(prefect_api, test_nodes, tmp_path):
    store = raw_store(tmp_path / "run.zarr", frames=6, shape=(5, 6), exposure_times=(0.1, 0.3))
    steps = [Step("dark_average"), Step("dark_level")]
    first = run_steps(store.path, steps)
    assert [s.status for s in first.steps] == ["ran", "ran"]
    want = store.read("dark")["mean"].values
    assert [s.status for s in run_steps(store.path, steps).steps] == ["skipped", "skipped"]
    truncate(store, "dark", "mean")
    again = run_steps(store.path, steps)
    assert [s.status for s in again.steps] == ["ran", "ran"]
    assert again.steps[0].reason.startswith("damaged output dark (dark/mean/c/")
    assert again.steps[1].reason == "input dark was recomputed"
    np.testing.assert_array_equal(store.read("dark")["mean"].values, want)
    assert store.validate(deep=True) == []


# -- the corpus of bad inputs ----------------------------------------------------------------
@pytest.fixture
def small_filesystem(tmp_path):
    mount = tmp_path / "small"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=True)


def imported_dark(path, exposure_times):
    store = RunStore.create(path)
    raw = make_raw_dark(frames=4, shape=(4, 5), exposure_times=(0.1, 0.2, 0.3))
    raw = raw.assign_coords(exposure_time=("exposure_time", exposure_times, {"units": "s"}))
    raw.to_zarr(store.path, group="raw/dark", zarr_format=3, consolidated=False)  # a lab's importer
    return store


def small(path):
    return raw_store(path, frames=6, shape=(5, 6), exposure_times=(0.1, 0.3))


def flipped(path, keep_time=False):
    store = small(path)
    manifest = store.manifest("raw/dark")["files"]
    chunk = store.path / "raw/dark" / sorted(k for k in manifest if k.startswith("frames/c/"))[0]
    stat = chunk.stat()
    data = bytearray(chunk.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 64] = bytes(b ^ 0xFF for b in data[middle : middle + 64])
    chunk.write_bytes(bytes(data))
    if keep_time:
        os.utime(chunk, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    return store


def added_file(path):
    store = small(path)
    extra = store.path / "raw/dark/frames/c/7/0/0/0"
    extra.parent.mkdir(parents=True)
    extra.write_bytes(b"\1" * 32)
    return store


def truncated_raw(path):
    store = small(path)
    truncate(store, "raw/dark", "frames")
    return store


def with_dark(path):
    store = small(path)
    run_steps(store.path, [Step("dark_average")])
    return store


def truncated_dark(path):
    store = with_dark(path)
    truncate(store, "dark", "std")
    return store


def abandoned_staging(path):
    store = small(path)
    (store.staging_dir / "dark.0123456789abcdef.99999-cafebabe").mkdir(parents=True)
    return store


def nan_hdr(path):
    store = RunStore.create(path)
    store.write("hdr", hdr_with_nan(), fingerprint="h")
    return store


@functools.cache
def simulated_groups() -> dict[str, xr.Dataset]:
    """raw/rgb of the tiny simulated run (image, exposure, y, x, channel), 10 bit, and the RGB
    cameras' calibration targets the OECF recovery reads beside it, in memory."""
    from spectralize.nodes.simulation.assembly import simulate_run
    from spectralize.nodes.simulation.recipes import get_recipe

    run = simulate_run(get_recipe("tiny"))
    return {g: run[g].load() for g in ("raw/rgb", "raw/colour_checker", "raw/white_reference")}


def imported_rgb(path, *, counts=None, exposure_time=None):
    """A store whose raw/rgb a lab's importer wrote, with edited counts or exposure times."""
    store = RunStore.create(path)
    rgb = simulated_groups()["raw/rgb"].copy(deep=True)
    if counts is not None:
        rgb["counts"].values[...] = counts
    if exposure_time is not None:
        times = rgb["exposure_time"].values.copy()
        times[1, 2] = exposure_time  # image 1, exposure 2 (0.01 s)
        rgb = rgb.assign_coords(exposure_time=(rgb["exposure_time"].dims, times, {"units": "s"}))
    with warnings.catch_warnings():  # the channel names: str arrays are not in zarr v3's spec
        warnings.simplefilter("ignore", UnstableSpecificationWarning)
        rgb.to_zarr(store.path, group="raw/rgb", zarr_format=3, consolidated=False)
    for group in ("raw/colour_checker", "raw/white_reference"):
        store.write(group, simulated_groups()[group], fingerprint="lab import")
    return store


HOLDER = "import sys, time\nfrom spectralize.store import RunStore\nwith RunStore.open(sys.argv[1]).lock():\n    print('locked', flush=True)\n    time.sleep(300)\n"

# (case, setup, command, exit status, fragments of stderr/stdout)
CORPUS = [
    (
        "store missing",
        None,
        ["run", "dark", "{store}"],
        2,
        ["run.zarr' does not exist", "reads raw/dark", "spectralize ingest"],
    ),
    ("not a store", "plain", ["run", "dark", "{store}"], 2, ["not a zarr v3 store"]),
    (
        "raw/rgb missing for btf",
        small,
        ["validate", "{store}", "--flow", "btf"],
        1,
        ["raw/rgb: expected a finished group"],
    ),
    (
        "raw groups missing for btf",
        small,
        ["run", "btf", "{store}"],
        2,
        ["the node graph cannot run", "raw/rgb"],
    ),
    (
        "negative exposure time",
        lambda p: imported_dark(p, [0.1, -0.2, 0.3]),
        ["run", "dark", "{store}"],
        2,
        [
            "raw/dark:exposure_time: expected values in [0, 10000], found range [-0.2, 0.3] (1 value(s) outside, first at exposure_time=1: -0.2)"
        ],
    ),
    (
        "negative exposure time (validate)",
        lambda p: imported_dark(p, [0.1, -0.2, 0.3]),
        ["validate", "{store}"],
        1,
        ["raw/dark:exposure_time: expected values in [0, 10000]"],
    ),
    (
        "NaN exposure time",
        lambda p: imported_dark(p, [0.1, 0.2, np.nan]),
        ["run", "dark", "{store}"],
        2,
        [
            "raw/dark:exposure_time: expected finite values, found 1 NaN/inf value(s) (first at exposure_time=2"
        ],
    ),
    (
        "all-saturated RGB frames",
        lambda p: imported_rgb(p, counts=1023),
        ["run", "recover_rgb_oecf", "{store}"],
        2,
        [
            "recover_rgb_oecf: raw/rgb:counts: frame image=0, exposure=0, channel=0 (exposure_time "
            "0.001 s) is entirely saturated (>= saturation = 1023): it carries no information; "
            "240 such frame(s) in all. Use shorter exposures",
            "raw/rgb:counts[image=0, exposure=1, channel=1]: expected a frame with some values "
            "below saturation = 1023, found every value >= 1023 (exposure_time 0.003 s)",
            "... and 235 more",
            "in node 'recover_rgb_oecf' (computing)",
        ],
    ),
    (
        "negative RGB exposure time",
        lambda p: imported_rgb(p, exposure_time=-0.01),
        ["run", "recover_rgb_oecf", "{store}"],
        2,
        [
            "raw/rgb:exposure_time: expected values in [0, 10000], found range [-0.01, 0.04] "
            "(1 value(s) outside, first at image=1, exposure=2: -0.01)"
        ],
    ),
    (
        "zero RGB exposure time",
        lambda p: imported_rgb(p, exposure_time=0.0),
        ["run", "recover_rgb_oecf", "{store}"],
        2,
        [
            "recover_rgb_oecf: raw/rgb: exposure_time must be positive and finite; 1 value(s) are "
            "not, the first at image=1, exposure=2: 0 s",
            "raw/rgb:exposure_time[image=1, exposure=2]: expected a positive, finite time [s], found 0",
        ],
    ),
    (
        "NaN in hdr (validate)",
        nan_hdr,
        ["validate", "{store}"],
        1,
        ["hdr:radiance: expected finite values, found 2 NaN/inf"],
    ),
    (
        "truncated raw chunk",
        truncated_raw,
        ["run", "dark", "{store}"],
        2,
        [
            "input group(s) raw/dark are damaged",
            "raw/dark/frames/c/",
            "(truncated or overwritten)",
            "raw data: restore",
        ],
    ),
    (
        "64 flipped bytes in a raw chunk",
        flipped,
        ["run", "dark", "{store}"],
        2,
        ["raw/dark/frames/c/", "(edited after commit)"],
    ),
    (
        "bit rot in a raw chunk (run)",
        lambda p: flipped(p, keep_time=True),
        ["run", "dark", "{store}"],
        2,
        [
            "group 'raw/dark'",
            "is damaged and no step of this flow can recompute it: chunk raw/dark/frames/c/",
            "do not match the checksum",
            "in node 'dark_average'",
        ],
    ),
    (
        "bit rot in a raw chunk (validate --deep)",
        lambda p: flipped(p, keep_time=True),
        ["validate", "{store}", "--deep"],
        1,
        ["raw/dark/frames/c/", "(changed on disk)"],
    ),
    (
        "file added to a raw group",
        added_file,
        ["run", "dark", "{store}"],
        2,
        ["raw/dark/frames/c/7/0/0/0", "a file added later"],
    ),
    ("unknown flow", small, ["run", "nope", "{store}"], 2, ["unknown flow or node 'nope'"]),
    (
        "unknown and invalid --set",
        small,
        ["run", "dark", "{store}", "--set", "bogus=1", "--set", "frames_per_chunk=0"],
        2,
        ["--set bogus", "dark_average.frames_per_chunk"],
    ),
    ("busy store", "busy", ["run", "dark", "{store}"], 2, ["store busy: run by pid"]),
    (
        "read-only store",
        "read-only",
        ["run", "dark", "{store}"],
        2,
        ["cannot write to run store", "Read-only file system"],
    ),
    (
        "full disk",
        "full",
        ["run", "dark", "{store}"],
        2,
        ["not enough free space", "group 'dark'", "in node 'dark_average'"],
    ),
    # reported, and repaired or left for `clean`: not errors
    (
        "truncated derived chunk",
        truncated_dark,
        ["run", "dark", "{store}"],
        0,
        ["ran again: damaged output dark (dark/std/c/"],
    ),
    (
        "abandoned staging",
        abandoned_staging,
        ["validate", "{store}"],
        0,
        ["warning: ", "an unfinished or interrupted write"],
    ),
]


def finished_results(path: Path) -> dict:
    try:
        store = RunStore.open(path)
    except Exception:
        return {}
    return {g: (store.fingerprint(g), store.manifest(g)) for g in store.groups()}


def test_bad_input_corpus(prefect_api, tmp_path, small_filesystem, capsys):
    tally = {"tried": 0, "clear": 0, "changed": 0}
    for case, setup, argv, status, fragments in CORPUS:
        path = tmp_path / case.replace(" ", "_").replace("/", "_") / "run.zarr"
        path.parent.mkdir()
        holder = None
        if setup == "plain":
            path.mkdir()
        elif setup == "busy":
            small(path)
            holder = subprocess.Popen(
                [sys.executable, "-c", HOLDER, str(path)], stdout=subprocess.PIPE, text=True
            )
            assert holder.stdout.readline().strip() == "locked"
        elif setup in ("read-only", "full"):
            path = small_filesystem / setup / "run.zarr"
            path.parent.mkdir()
            small(path)
            if setup == "full":  # leave a few kB: less than the result needs
                filler = small_filesystem / "filler"
                with open(filler, "wb") as f:
                    while shutil.disk_usage(small_filesystem).free > 8192:
                        f.write(b"\0" * min(65536, shutil.disk_usage(small_filesystem).free - 4096))
            else:
                subprocess.run(["mount", "-o", "remount,ro", str(small_filesystem)], check=True)
        elif setup is not None:
            setup(path)
        before = finished_results(path)
        capsys.readouterr()
        try:
            code = cli.main([a.replace("{store}", str(path)) for a in argv])
        finally:
            if holder is not None:
                holder.kill()
                holder.wait()
            if setup == "read-only":
                subprocess.run(["mount", "-o", "remount,rw", str(small_filesystem)], check=True)
            if setup == "full":
                (small_filesystem / "filler").unlink()
        out = capsys.readouterr()
        text = out.out + out.err
        tally["tried"] += 1
        assert code == status, (case, text)
        for fragment in fragments:
            assert fragment in text, (case, fragment, text)
        assert "Traceback" not in text, (case, text)
        tally["clear"] += 1
        after = finished_results(path)
        if case == "truncated derived chunk":  # repaired: the same result, intact again
            assert after.keys() == before.keys() and after["dark"][0] == before["dark"][0]
            assert RunStore.open(path).validate(deep=True) == []
        elif after != before:
            tally["changed"] += 1
    print(
        f"\n{tally['tried']} bad inputs tried, {tally['clear']} clear errors, {tally['changed']} finished results changed"
    )
    assert tally == {"tried": len(CORPUS), "clear": len(CORPUS), "changed": 0}


def test_serve_skips_a_busy_store_and_says_so(prefect_api, tmp_path):
    from spectralize.flows.schedule import process_new_runs

    small(tmp_path / "a.zarr")
    small(tmp_path / "b.zarr")
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(tmp_path / "b.zarr")], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        outcome = process_new_runs(str(tmp_path), flow_name="dark")
    finally:
        holder.kill()
        holder.wait()
    assert outcome[str(tmp_path / "a.zarr")] == "1 node(s) ran, 0 up to date"
    assert outcome[str(tmp_path / "b.zarr")].startswith(f"skipped: store busy: run by pid {holder.pid}")
