"""Safe on any folder (issue 26's corpus): ingest reads nothing outside its capture folder and
decodes nothing before it checks the header; damage is repaired, not repeated; stopped
commands leave nothing behind. Real files, real symbolic links, a real decompression bomb,
real processes and signals."""

import contextlib
import functools
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import psutil
import pytest
import tifffile
import xarray as xr
from support.capture_folders import rows, sample, write_rows  # noqa: F401  (sample: a fixture)

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Node, RegisteredNode, Step
from spectralize.engine import discovery as engine
from spectralize.flows import cli
from spectralize.flows.ingest import ingest
from spectralize.flows.ingest.raw_groups import capture_files_of_chunk
from spectralize.flows.runtime import run_steps
from spectralize.flows.schedule import failure_line
from spectralize.schemas import StoreError
from spectralize.store import RunStore, work_dir

EXE = [sys.executable, "-m", "spectralize.flows.cli"]


@pytest.fixture
def capture(sample, tmp_path):  # noqa: F811
    """A copy of the tiny sample capture folder, beside a folder ``outside`` it must not read."""
    (tmp_path / "outside").mkdir()
    return shutil.copytree(sample, tmp_path / "lab" / "capture", copy_function=shutil.copy2)


def first_dark(folder):
    """The index and row of the manifest's first dark frame (a monochrome TIFF)."""
    table = rows(folder)
    index = next(i for i, row in enumerate(table) if row["kind"] == "dark")
    return table, index


def ingest_cli(capsys, folder, store):
    code = cli.main(["ingest", str(folder), str(store)])
    out = capsys.readouterr()
    return code, out.out + out.err


# -- 1. containment ---------------------------------------------------------------------------
def escape_up(folder, outside):
    table, i = first_dark(folder)
    shutil.copy2(folder / table[i]["file"], outside / "secret.tif")
    table[i]["file"] = "../../outside/secret.tif"
    return table, i, "a path that leaves the capture folder"


def absolute(folder, outside):
    table, i = first_dark(folder)
    shutil.copy2(folder / table[i]["file"], outside / "secret.tif")
    table[i]["file"] = str(outside / "secret.tif")
    return table, i, "an absolute path"


def linked_file(folder, outside):
    table, i = first_dark(folder)
    frame = folder / table[i]["file"]
    shutil.copy2(frame, outside / "secret.tif")
    frame.unlink()
    frame.symlink_to(outside / "secret.tif")
    return table, i, "a symbolic link (not followed"


def linked_folder(folder, outside):
    table, i = first_dark(folder)
    shutil.move(folder / "dark", outside / "dark")
    (folder / "dark").symlink_to(outside / "dark", target_is_directory=True)
    return table, i, "in a symbolically linked folder 'dark'"


def linked_inside_without_permission(folder, outside):
    table, i = first_dark(folder)
    frame = folder / table[i]["file"]
    shutil.copy2(frame, folder / "copy.tif")
    frame.unlink()
    frame.symlink_to(folder / "copy.tif")
    return table, i, "a symbolic link (not followed: capture.toml has no follow_symlinks = true)"


def linked_outside_with_permission(folder, outside):
    table, i, _ = linked_file(folder, outside)
    text = (folder / "capture.toml").read_text()
    (folder / "capture.toml").write_text("follow_symlinks = true\n" + text)
    return (
        table,
        i,
        f"a symbolic link to {str((outside / 'secret.tif').resolve())!r}, outside the capture folder",
    )


@pytest.mark.parametrize(
    "make",
    [
        escape_up,
        absolute,
        linked_file,
        linked_folder,
        linked_inside_without_permission,
        linked_outside_with_permission,
    ],
)
def test_ingest_reads_no_file_outside_its_capture_folder(capture, capsys, make):
    outside = capture.parent.parent / "outside"
    table, index, why = make(capture, outside)
    write_rows(capture, table)
    store = capture.parent / "run.zarr"
    opened = []
    real_open = tifffile.TiffFile.__init__

    def watch(self, file, *args, **kwargs):  # which image files ingest opens
        opened.append(Path(file).resolve())
        real_open(self, file, *args, **kwargs)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tifffile.TiffFile, "__init__", watch)
        code, text = ingest_cli(capsys, capture, store)
    assert code == 2, text
    line = index + 2  # the header is line 1
    assert (
        f"manifest.csv line {line} ({table[index]['file']}): expected a file inside the capture folder"
        in text
    )
    assert why in text, text
    assert "Traceback" not in text
    assert not store.exists()  # nothing written
    assert not [f for f in opened if f.is_relative_to(outside.resolve())]


def test_a_symlink_inside_the_folder_is_followed_when_capture_toml_allows_it(capture, capsys):
    linked_inside_without_permission(capture, None)
    text = (capture / "capture.toml").read_text()
    (capture / "capture.toml").write_text("follow_symlinks = true\n" + text)
    code, out = ingest_cli(capsys, capture, capture.parent / "run.zarr")
    assert code == 0, out


def test_capture_toml_and_calibration_names_stay_inside_too(capture, capsys):
    outside = capture.parent.parent / "outside"
    shutil.copy2(capture / "calibration/colour_checker_patches.png", outside / "patches.png")
    text = (capture / "capture.toml").read_text()
    (capture / "capture.toml").write_text(
        text.replace('"calibration/colour_checker_patches.png"', '"../../outside/patches.png"')
    )
    shutil.move(capture / "calibration/illuminant.csv", outside / "illuminant.csv")
    (capture / "calibration/illuminant.csv").symlink_to(outside / "illuminant.csv")
    code, out = ingest_cli(capsys, capture, capture.parent / "run.zarr")
    assert code == 2
    assert (
        "../../outside/patches.png: expected a file inside the capture folder, found a path that leaves"
        in out
    )
    assert (
        "calibration/illuminant.csv: expected a file inside the capture folder, found a symbolic link"
        in out
    )


def test_readiness_counts_a_file_outside_the_folder_as_there_for_ingest_to_refuse(capture):
    from spectralize.flows.ingest import capture_state

    table, i, _ = escape_up(capture, capture.parent.parent / "outside")
    write_rows(capture, table)
    state = capture_state(capture, settle_seconds=0)
    assert state.ready, state.reason


# -- 2. header first: a decompression bomb -----------------------------------------------------
BOMB = (20000, 20000)


def write_bomb(path, shape=BOMB):
    """A small zlib-tiled TIFF declaring ``shape`` 16-bit pixels (written tile by tile)."""

    def tiles():
        tile = np.zeros((512, 512), np.uint16)
        for _ in range(-(-shape[0] // 512) * -(-shape[1] // 512)):
            yield tile

    tifffile.imwrite(path, tiles(), shape=shape, dtype=np.uint16, tile=(512, 512), compression="zlib")


PEAK = textwrap.dedent(
    """
    import resource, sys
    from spectralize.flows import cli
    code = cli.main(sys.argv[1:])
    print("peak_kib", resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "code", code)
    """
)


def peak_of(*argv):
    """``(peak RSS in MiB, exit status, output)`` of a CLI command in a process of its own."""
    done = subprocess.run([sys.executable, "-c", PEAK, *argv], capture_output=True, text=True)
    words = done.stdout.split()
    kib = int(words[words.index("peak_kib") + 1])
    return kib / 1024, int(words[words.index("code") + 1]), done.stdout + done.stderr


@pytest.mark.slow
def test_a_decompression_bomb_is_refused_from_its_header_in_bounded_memory(capture, tmp_path):
    control = shutil.copytree(capture, tmp_path / "control", copy_function=shutil.copy2)
    table, i = first_dark(capture)
    bomb = capture / table[i]["file"]
    write_bomb(bomb)
    assert bomb.stat().st_size < 2**20  # under 1 MiB on disk, 763 MiB declared
    larger = capture / table[i + 1]["file"]
    write_bomb(larger, (2048, 2048))  # 8 MiB: allowed in size, but not the run's frame size
    peak, code, out = peak_of("ingest", str(capture), str(tmp_path / "bomb.zarr"))
    control_peak, control_code, control_out = peak_of("ingest", str(control), str(tmp_path / "ok.zarr"))
    assert control_code == 0, control_out
    assert code == 2, out
    assert f"manifest.csv line {i + 2} ({table[i]['file']}): expected a frame of at most 256 MiB" in out
    assert "declaring 20000 x 20000 uint16 (763 MiB), not decoded" in out
    assert f"line {i + 3} ({table[i + 1]['file']}): expected frames of 32 x 32 px like the others" in out
    assert "2048 x 2048 px (declared in its header, not decoded)" in out
    assert not (tmp_path / "bomb.zarr").exists()
    # a decoded bomb alone would take 763 MiB; ingest stays near what a clean folder takes
    print(f"\npeak RSS: bomb folder {peak:.0f} MiB, clean folder {control_peak:.0f} MiB")
    assert peak < control_peak + 100, (peak, control_peak)


# -- 3. damage is repaired, not repeated ------------------------------------------------------
CALLS: dict[str, int] = {}


def dark_level(dark: xr.Dataset) -> xr.Dataset:
    CALLS["dark_level"] = CALLS.get("dark_level", 0) + 1
    return xr.Dataset(
        {"level": dark["mean"].mean(("y", "x")).astype(np.float32).assign_attrs(units="DN")}
    )


@pytest.fixture
def chain(monkeypatch):
    """Steps ``dark_average`` (raw/dark -> dark) and a test node ``dark_level`` (dark -> dark_level)."""
    installed = dict(engine.registry(refresh=True))
    node = Node(name="dark_level", function=dark_level, inputs={"dark": "dark"}, outputs=("dark_level",))
    installed[node.name] = RegisteredNode(node, "test")
    monkeypatch.setattr(engine, "_installed", lambda: installed)
    CALLS.clear()
    return [Step("dark_average"), Step("dark_level")]


def small_store(path):
    store = RunStore.create(path)
    raw = make_raw_dark(frames=6, shape=(5, 6), exposure_times=(0.1, 0.3))
    store.write("raw/dark", raw, fingerprint="raw-v1")
    return store


def rot(store, group, variable, index=0):
    """Flip bytes in the middle of a chunk and keep its modification time (real bit rot)."""
    manifest = store.manifest(group)["files"]
    rel = sorted(k for k in manifest if k.startswith(f"{variable}/c/"))[index]
    chunk = store.path / group / rel
    stat = chunk.stat()
    data = bytearray(chunk.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 16] = bytes(b ^ 0xFF for b in data[middle : middle + 16])
    chunk.write_bytes(bytes(data))
    os.utime(chunk, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    return f"{group}/{rel}"


def test_a_rotten_derived_chunk_read_by_a_step_is_recomputed_with_its_dependants(
    prefect_api, chain, tmp_path
):
    store = small_store(tmp_path / "run.zarr")
    run_steps(store.path, chain)
    want = store.read("dark")["mean"].values
    key = rot(store, "dark", "mean")
    assert store.validate() == []  # the cheap check cannot see it: sizes and times unchanged
    shutil.rmtree(store.path / "dark_level")  # so a step reads the rotten group
    report = run_steps(store.path, chain)
    assert [s.status for s in report.steps] == ["ran", "ran"]
    assert report.steps[0].reason.startswith(
        f"damaged output dark (dark: expected an undamaged group, found chunk {key}: its bytes do not match"
    )
    assert report.steps[1].reason == "input dark was recomputed"
    np.testing.assert_array_equal(store.read("dark")["mean"].values, want)
    assert store.validate(deep=True) == []


def test_verify_finds_rot_no_step_reads_and_repairs_it(prefect_api, chain, tmp_path, capsys):
    store = small_store(tmp_path / "run.zarr")
    run_steps(store.path, chain)
    key = rot(store, "dark", "std")
    # documented: without --verify, steps that are up to date read nothing, so trust the cheap check
    assert [s.status for s in run_steps(store.path, chain).steps] == ["skipped", "skipped"]
    report = run_steps(store.path, chain, verify=True)
    assert [s.status for s in report.steps] == ["ran", "ran"]
    err = capsys.readouterr().err
    assert (
        f"dark is damaged ({key}: CRC-32 " in err and "(changed on disk), expected content with" in err
    )
    assert store.validate(deep=True) == []
    assert [s.status for s in run_steps(store.path, chain, verify=True).steps] == ["skipped", "skipped"]


def test_a_rotten_raw_chunk_names_the_chunk_and_its_capture_files_and_ingest_repairs_it(
    prefect_api, capture, tmp_path
):
    store_path = tmp_path / "run.zarr"
    ingest(capture, store_path)
    store = RunStore.open(store_path)
    key = rot(store, "raw/dark", "frames")
    files = capture_files_of_chunk(store, key)
    assert files and all(f.startswith("dark/t") and f.endswith(".tif") for f in files)
    with pytest.raises(StoreError) as info:
        run_steps(store_path, [Step("dark_average")])
    text = str(info.value)
    assert (
        f"group 'raw/dark' of run store {str(store_path)!r} is damaged and no step of this flow can recompute it: chunk {key}: its bytes do not match the checksum"
        in text
    )
    assert f"its frames came from capture file(s) {files[0]}" in text
    assert f"spectralize ingest {capture.absolute()} {store_path}" in text
    assert not store.has("dark")
    # marked: even the cheap check sees it now, and ingest rewrites the group from its files
    assert any(p.where == "raw/dark" for p in store.validate())
    report = ingest(capture, store_path)
    assert report.groups["raw/dark"] == "written" and report.groups["raw/rgb"] == "up to date"
    assert store.validate(deep=True) == []
    assert [s.status for s in run_steps(store_path, [Step("dark_average")]).steps] == ["ran"]


def test_verify_names_a_rotten_raw_chunk_before_anything_runs(prefect_api, chain, tmp_path):
    store = small_store(tmp_path / "run.zarr")
    run_steps(store.path, chain)
    key = rot(store, "raw/dark", "frames")
    assert [s.status for s in run_steps(store.path, chain).steps] == ["skipped", "skipped"]
    with pytest.raises(StoreError, match=f"group 'raw/dark' .* is damaged .*: {key}: CRC-32"):
        run_steps(store.path, chain, verify=True)


# -- 3b. the report's groups: rot that kept its times is repaired by the same run ---------------
@pytest.fixture(scope="module")
def good_btf(prefect_api, tmp_path_factory):
    """The tiny simulated run as a store btf can run on: ``validate --flow btf``, then
    ``run btf`` (with its report) on it, once per module. The codes and stderr of both."""
    path = tmp_path_factory.mktemp("btf") / "run.zarr"
    btf_store(path, None)
    with contextlib.redirect_stderr(io.StringIO()) as checked:
        validated = cli.main(["validate", str(path), "--flow", "btf"])
    with contextlib.redirect_stderr(io.StringIO()) as ran:
        code = cli.main(["run", "btf", str(path)])
    return path, (validated, checked.getvalue()), (code, ran.getvalue())


@pytest.fixture(scope="module")
def reported_btf(good_btf):
    """A finished btf run of the tiny simulated run, with its report (made once per module)."""
    path, _, (code, err) = good_btf
    assert code == 0, err
    return path


def copy_run(source, target_dir):
    """A copy of a run store and its report folder (times kept: the report is up to date)."""
    target = target_dir / source.name
    shutil.copytree(source, target, copy_function=shutil.copy2, symlinks=True)
    report = source.parent / f"{source.stem}-report"
    shutil.copytree(report, target_dir / report.name, copy_function=shutil.copy2)
    return RunStore.open(target)


def run_btf(capsys, store):
    code = cli.main(["run", "btf", str(store.path)])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.slow
def test_rot_in_a_group_the_report_shows_is_repaired_by_an_up_to_date_run(
    reported_btf, tmp_path, capsys
):
    store = copy_run(reported_btf, tmp_path)
    want = store.read("spectra")["radiance"].values
    key = rot(store, "spectra", "radiance")
    # sizes and times unchanged, but the cheap check reads the first chunk of an array stored
    # to a stated precision (its value check), and a read checks the chunk's CRC-32
    assert [problem.where for problem in store.validate()] == [key]
    code, out, err = run_btf(capsys, store)
    assert code == 0, err
    assert f"spectra is damaged ({key}: CRC-32 " in err, err
    statuses = dict(line.split()[:2] for line in out.splitlines()[1:] if line.startswith("  "))
    assert statuses["reconstruct_image_sets"] == "ran" and statuses["dark_average"] == "skipped", out
    assert store.validate(deep=True) == []
    np.testing.assert_allclose(store.read("spectra")["radiance"].values, want, rtol=1e-5)
    code, out, err = run_btf(capsys, store)  # healthy now: everything up to date, no warning
    assert code == 0 and "damaged" not in err and " ran " not in out, (out, err)


@pytest.mark.slow
def test_rot_in_a_report_group_is_found_before_the_report_of_a_run_that_computed_something(
    reported_btf, tmp_path, capsys
):
    store = copy_run(reported_btf, tmp_path)
    shutil.rmtree(store.path / "spectra_seed")  # one step runs again; spectra stays up to date
    key = rot(store, "spectra", "radiance")
    code, out, err = run_btf(capsys, store)
    assert code == 0, err
    assert (
        f"ran again: damaged output spectra (spectra: expected an undamaged group, found {key}: CRC-32"
        in out
    ), out
    statuses = dict(line.split()[:2] for line in out.splitlines()[1:] if line.startswith("  "))
    assert statuses["reconstruct_seed_set"] == "ran" and statuses["reconstruct_image_sets"] == "ran", out
    assert statuses["calibrate_bands"] == "skipped", out
    assert store.validate(deep=True) == []


@pytest.mark.slow
def test_a_chunk_the_report_reads_that_fails_is_recomputed_and_the_report_written_in_one_run(
    reported_btf, tmp_path, capsys, monkeypatch
):
    from spectralize.flows import repair

    monkeypatch.setattr(repair, "REPORT_VERIFY_BYTES", 0)  # nothing checked before: the read finds it
    store = copy_run(reported_btf, tmp_path)
    report = tmp_path / "run-report"
    shutil.rmtree(report)  # the report is written again, so it reads its groups
    key = rot(store, "calibration/spectral", "relative_error")
    code, out, err = run_btf(capsys, store)
    assert code == 0, err
    assert f"calibration/spectral is damaged (chunk {key}: its bytes do not match the checksum" in err, (
        err
    )
    assert "recomputing it and the groups that depend on it" in err
    assert (report / "index.html").is_file()
    assert store.validate(deep=True) == []
    code, out, err = run_btf(capsys, store)
    assert code == 0 and "damaged" not in err, err


@pytest.mark.slow
def test_rot_in_a_raw_group_the_report_shows_fails_the_up_to_date_run_naming_the_chunk(
    reported_btf, tmp_path, capsys
):
    store = copy_run(reported_btf, tmp_path)
    key = rot(store, "raw/rgb", "counts")
    code, out, err = run_btf(capsys, store)
    assert code == 2, (out, err)
    assert f"group 'raw/rgb' of run store {str(store.path)!r} is damaged and no step" in err, err
    assert key in err
    assert any(p.where == "raw/rgb" for p in store.validate())  # marked: the cheap check sees it now


@pytest.mark.slow
def test_the_report_reads_only_the_groups_checked_before_it(reported_btf, tmp_path, monkeypatch):
    from spectralize.flows.repair import REPORT_GROUPS
    from spectralize.flows.report import write_run_report

    store = copy_run(reported_btf, tmp_path)
    read: list[str] = []
    original = RunStore.read

    def recording(self, group, *args, **kwargs):
        read.append(group)
        return original(self, group, *args, **kwargs)

    monkeypatch.setattr(RunStore, "read", recording)
    write_run_report(store, directory=tmp_path / "again")
    assert read and set(read) <= set(REPORT_GROUPS), sorted(set(read) - set(REPORT_GROUPS))


# -- 5. clean exits ---------------------------------------------------------------------------
def cube_store(path):
    store = RunStore.create(path)
    radiance = np.random.default_rng(0).random((3, 4, 8, 8)).astype(np.float32)
    ds = xr.Dataset(
        {"radiance": (("image", "wavelength", "y", "x"), radiance, {"units": "1"})},
        coords={
            "image": [0, 1, 2],
            "wavelength": ("wavelength", [450.0, 500.0, 550.0, 600.0], {"units": "nm"}),
        },
    )
    store.write("cube", ds, fingerprint="s", chunks={"image": 1})
    return store


@pytest.mark.parametrize(
    "fmt, out", [("netcdf", "out.nc"), ("envi", "envi"), ("netcdf-per-image", "nc")]
)
def test_export_of_a_damaged_store_leaves_nothing_behind(tmp_path, capsys, fmt, out):
    store = cube_store(tmp_path / "run.zarr")
    rot(store, "cube", "radiance", index=-1)  # the last image: earlier files are written first
    target = tmp_path / "exports" / out
    argv = ["export", str(store.path), str(target), "--group", "cube", "--format", fmt.split("-")[0]]
    code = cli.main(argv + (["--per-image"] if fmt.endswith("per-image") else []))
    text = capsys.readouterr().err
    assert code == 2 and "is damaged" in text, text
    assert not (tmp_path / "exports").exists(), list((tmp_path / "exports").rglob("*"))


def big_raw_store(path):
    store = RunStore.create(path)
    store.write(
        "raw/dark",
        make_raw_dark(frames=96, shape=(160, 160), exposure_times=(0.1, 0.2, 0.4)),
        fingerprint="r",
    )
    return store


def spawn(*args):
    env = {**os.environ, "PREFECT_LOGGING_LEVEL": "WARNING"}
    return subprocess.Popen(
        [*EXE, *args], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def lock_note(store):
    try:
        return json.loads((work_dir(store) / "lock.json").read_text())
    except (OSError, ValueError):
        return {}


def wait_for(condition, process, what, timeout=180):
    deadline = time.time() + timeout
    while not condition():
        assert process.poll() is None, f"the run ended before {what}: {process.communicate()}"
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def staged(store):
    folder = work_dir(store) / "staging"
    return folder.is_dir() and any(e.name != "zarr.json" for e in folder.iterdir())


FLOW_STATE = textwrap.dedent(
    """
    import sys
    from prefect import get_client
    with get_client(sync_client=True) as client:
        print(client.read_flow_run(sys.argv[1]).state.type.value)
    """
)


@pytest.mark.slow
def test_sigterm_stops_a_run_like_ctrl_c(prefect_api, tmp_path):
    store = big_raw_store(tmp_path / "run.zarr")
    run = spawn("run", "dark", str(store.path), "--set", "frames_per_chunk=2")
    started: list[psutil.Process] = []
    try:
        wait_for(lambda: "flow_run_id" in lock_note(store.path), run, "the flow started")
        flow_run_id = lock_note(store.path)["flow_run_id"]
        wait_for(lambda: staged(store.path), run, "the first region was staged")
        started = psutil.Process(run.pid).children(recursive=True)
        assert started, "the embedded Prefect server should be a child of the flow process"
        os.kill(run.pid, signal.SIGTERM)  # the flow process only, as a service manager does
        out, err = run.communicate(timeout=120)
        gone, alive = psutil.wait_procs(started, timeout=30)
        assert alive == [], [p.cmdline() for p in alive]
    finally:
        for process in [p for p in started if p.is_running()]:
            process.kill()
        if run.poll() is None:
            run.kill()
    assert run.returncode == 130, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1] == "spectralize run: interrupted"
    assert [line for line in err.splitlines() if "interrupted" in line] == [
        "spectralize run: interrupted"
    ]
    assert lock_note(store.path) == {}  # the lock was released as after Ctrl-C
    state = subprocess.run(
        [sys.executable, "-c", FLOW_STATE, flow_run_id], capture_output=True, text=True
    )
    assert state.stdout.strip() == "CRASHED", state.stdout + state.stderr
    assert not store.has("dark")
    from prefect.settings import PREFECT_API_URL

    # the store is whole for the next run (on the session's API: no embedded server to start)
    rerun = subprocess.run(
        [*EXE, "run", "dark", str(store.path)],
        env={**os.environ, "PREFECT_API_URL": PREFECT_API_URL.value()},
        capture_output=True,
        text=True,
    )
    assert rerun.returncode == 0, rerun.stderr
    assert store.has("dark") and store.validate() == []


def finished_regions(store):
    """The regions an unfinished resumable write has finished (its ``.done`` flags)."""
    folder = work_dir(store) / "staging"
    return [f for d in folder.glob("*.done") for f in d.iterdir()] if folder.is_dir() else []


def groups_of(path):
    """Every group of a store: its fingerprint and its data, loaded (the store's own records,
    which name the store and the time, left out)."""
    store = RunStore.open(path)
    found = {}
    for group in store.groups():
        data = store.read(group, friendly=False).load()
        data.attrs = {k: v for k, v in data.attrs.items() if not k.startswith("spectralize_")}
        found[group] = (store.fingerprint(group), data)
    return found


@pytest.mark.slow
def test_sigterm_stops_an_ingest_like_ctrl_c_and_a_second_ingest_resumes(sample, tmp_path):  # noqa: F811
    store_path = tmp_path / "run.zarr"
    ingest_run = spawn("ingest", str(sample), str(store_path))
    started: list[psutil.Process] = []
    try:
        # once a group is finished and the next one has finished regions (kept for the rerun)
        wait_for(
            lambda: (
                (store_path / "zarr.json").exists()
                and RunStore.open(store_path).groups()
                and finished_regions(store_path)
            ),
            ingest_run,
            "a group was written and another has finished regions",
        )
        started = psutil.Process(ingest_run.pid).children(recursive=True)
        os.kill(ingest_run.pid, signal.SIGTERM)
        out, err = ingest_run.communicate(timeout=120)
        gone, alive = psutil.wait_procs(started, timeout=30)
        assert alive == [], [p.cmdline() for p in alive]
    finally:
        for process in [p for p in started if p.is_running()]:
            process.kill()
        if ingest_run.poll() is None:
            ingest_run.kill()
            ingest_run.wait()
    assert ingest_run.returncode == 130, err
    assert "Traceback" not in err, err
    assert err.strip().splitlines()[-1] == "spectralize ingest: interrupted", err
    assert [line for line in err.splitlines() if "interrupted" in line] == [
        "spectralize ingest: interrupted"
    ], err
    assert lock_note(store_path) == {}  # the lock was released
    store = RunStore.open(store_path)
    written = store.groups()
    # nothing half-written looks finished: every group there is whole, and some are not there yet
    assert written and store.validate(deep=True) == []
    clean = tmp_path / "clean.zarr"
    assert ingest(sample, clean).groups  # the same folder, never interrupted
    assert set(written) < set(RunStore.open(clean).groups()), written
    resumed = subprocess.run(
        [*EXE, "ingest", str(sample), str(store_path)], capture_output=True, text=True
    )
    assert resumed.returncode == 0, resumed.stderr
    for group in written:  # finished before the signal: not written again
        assert re.search(rf"^  {re.escape(group)} +up to date", resumed.stdout, re.M), resumed.stdout
    got, want = groups_of(store_path), groups_of(clean)
    assert set(got) == set(want)
    for group, (fingerprint, data) in want.items():
        assert got[group][0] == fingerprint, group
        xr.testing.assert_identical(got[group][1], data)
    assert not list(store_path.rglob("*.partial"))
    assert RunStore.open(store_path).staging_leftovers() == []


HOLDER = textwrap.dedent(
    """
    import sys, time
    from spectralize.store import RunStore
    with RunStore.open(sys.argv[1]).lock("spectralize run dark"):
        print("locked", flush=True)
        time.sleep(300)
    """
)


def test_validate_tells_a_live_runs_staging_from_a_dead_ones(tmp_path):
    store = small_store(tmp_path / "run.zarr")
    (store.staging_dir / "dark.0123456789abcdef.99999-cafebabe").mkdir(parents=True)
    writer = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(store.path)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert writer.stdout.readline().strip() == "locked"
        live = subprocess.run([*EXE, "validate", str(store.path)], capture_output=True, text=True)
    finally:
        writer.kill()  # SIGKILL: the writer dies without cleaning up, as a crashed run does
        writer.wait()
    assert live.returncode == 0, live.stderr
    assert f"the work in progress of a live run (pid {writer.pid} on host" in live.stderr, live.stderr
    assert "spectralize run dark); leave it" in live.stderr and "spectralize clean" not in live.stderr
    dead = subprocess.run([*EXE, "validate", str(store.path)], capture_output=True, text=True)
    assert (
        "an unfinished or interrupted write" in dead.stderr
        and "spectralize clean` removes it" in dead.stderr
    )
    assert "live run" not in dead.stderr


def test_the_nightly_failure_line_counts_folders_and_stores_apart():
    outcome = {
        "/c/a": "failed: bad manifest",
        "/c/b": "ingested: raw/rgb (3 new frame(s))",
        "/c/c": "waiting: changed 3 s ago",
        "/r/a.zarr": "failed: damaged",
        "/r/b.zarr": "1 node(s) ran, 0 up to date",
    }
    line = failure_line(outcome, {"/r/a.zarr", "/r/b.zarr"})
    assert line.startswith("1 of 3 capture folder(s) and 1 of 2 run store(s) failed: ")
    assert failure_line({"/r/a.zarr": "failed: x"}, {"/r/a.zarr"}).startswith(
        "1 of 1 run store(s) failed"
    )


def test_the_nightly_flow_reports_three_folders_and_two_stores(prefect_api, capture, tmp_path):
    from spectralize.flows.schedule import process_new_runs
    from spectralize.schemas import SpectralizeError

    captures, runs = tmp_path / "captures", tmp_path / "runs"
    for name in ("a", "b", "c"):  # three folders whose manifests name a file outside
        folder = shutil.copytree(capture, captures / name, copy_function=shutil.copy2)
        table, i, _ = escape_up(folder, tmp_path / "outside")
        write_rows(folder, table)
        old = time.time() - 3600
        for path in folder.rglob("*"):
            os.utime(path, (old, old))
    small_store(runs / "good.zarr")
    bad = small_store(runs / "bad.zarr")
    rot(bad, "raw/dark", "frames")
    with pytest.raises(SpectralizeError) as info:
        process_new_runs(str(captures), flow_name="dark", output_root=str(runs), settle_seconds=60)
    assert str(info.value).startswith("3 of 3 capture folder(s) and 1 of 2 run store(s) failed: ")


# -- 4. one rule set: validate --flow runs the nodes' checks -----------------------------------
@functools.cache
def simulated_run() -> dict[str, xr.Dataset]:
    """The raw groups of the tiny simulated run (raw/rgb: image, exposure, y, x, channel, 10 bit)."""
    from spectralize.flows.pipelines import flow_inputs
    from spectralize.nodes.simulation.assembly import simulate_run
    from spectralize.nodes.simulation.recipes import get_recipe

    run = simulate_run(get_recipe("tiny"))
    return {group: run[group].load() for group in flow_inputs("btf")}


def btf_store(path, edit):
    """A store btf can run on, its raw/rgb edited by ``edit`` (``None``: as simulated).

    The store takes the edited values (its contract has no rule about their order or
    saturation): only the nodes' value checks can refuse them.
    """
    store = RunStore.create(path)
    for group, ds in simulated_run().items():
        if group == "raw/rgb" and edit is not None:
            ds = edit(ds.copy(deep=True))
        store.write(group, ds, fingerprint=f"sim-{group}")
    return store


def set_counts(value, image=None, exposure=None):
    def edit(rgb):
        pick = {k: v for k, v in (("image", image), ("exposure", exposure)) if v is not None}
        rgb["counts"][pick] = value
        return rgb

    return edit


def exposure_time(value):
    def edit(rgb):
        times = rgb["exposure_time"].values.copy()
        times[1, 2] = value  # image 1, exposure 2 (0.01 s), after 0.003 s
        return rgb.assign_coords(exposure_time=(rgb["exposure_time"].dims, times, {"units": "s"}))

    return edit


def listed(stderr: str) -> list[str]:
    """The problems ``validate`` lists (its ``  - `` lines)."""
    return [line[4:] for line in stderr.splitlines() if line.startswith("  - ")]


@pytest.mark.parametrize(
    "edit, fragment",
    [
        (
            set_counts(1023),
            "frame image=0, exposure=0, channel=0 (exposure_time 0.001 s) is entirely saturated",
        ),
        (
            set_counts(1023, image=2, exposure=1),
            "frame image=2, exposure=1, channel=0 (exposure_time 0.003 s) is entirely saturated",
        ),
        (exposure_time(0.002), "found unsorted values 0.003 then 0.002"),
        (exposure_time(0.003), "found duplicate values 0.003 then 0.003"),
        # the dark rule's threshold is the node's data-driven black level (0.1 % quantile of
        # the shortest exposures + 3 DN): the value check computes it as the node does
        (
            set_counts(0, image=2, exposure=1),
            "frame image=2, exposure=1, channel=0 (exposure_time 0.003 s) is entirely dark (<= black_level = ",
        ),
    ],
    ids=["all saturated", "partly saturated", "unsorted times", "duplicate times", "a dark frame"],
)
def test_validate_flow_btf_refuses_what_run_btf_refuses(prefect_api, tmp_path, capsys, edit, fragment):
    store = btf_store(tmp_path / "run.zarr", edit)
    validate = cli.main(["validate", str(store.path), "--flow", "btf"])
    checked = capsys.readouterr().err
    run = cli.main(["run", "btf", str(store.path)])
    ran = capsys.readouterr().err
    assert validate == 1, checked
    assert run == 2 and "in node 'recover_rgb_oecf' (computing)" in ran, ran
    problems = listed(checked)
    assert problems[0].startswith("recover_rgb_oecf: raw/rgb") and fragment in problems[0], checked
    for line in problems:  # the same text, line by line: the refusal run gives
        assert line in ran, (line, ran)
    assert f"spectralize run: error: {problems[0]}" in ran, ran
    assert not store.has("calibration/oecf_rgb")


@pytest.mark.slow
def test_a_good_store_passes_validate_flow_btf_and_run_btf(good_btf):
    # the module's btf run (the report tests copy it): validated, then run, on the same store
    path, (validated, checked), (code, ran) = good_btf
    assert validated == 0, checked
    assert code == 0, ran
    store = RunStore.open(path)
    assert store.has("calibration/oecf_rgb") and store.has("hdr") and store.validate() == []


def frames_mean(raw_dark: xr.Dataset, *, longest: float = 1.0) -> xr.Dataset:
    return xr.Dataset({"mean": raw_dark["frames"].mean("frame").astype(np.float32)})


def test_validate_flow_and_run_call_the_nodes_own_hook(prefect_api, monkeypatch, tmp_path, capsys):
    from spectralize.schemas import CalibrationError

    seen = []

    def check(inputs, parameters):
        seen.append((sorted(inputs), parameters.model_dump()))
        top = float(inputs["raw_dark"]["exposure_time"].max())
        if top <= parameters.longest:
            return []
        return [CalibrationError(f"raw/dark: exposure_time {top:g} s is above {parameters.longest:g} s")]

    installed = dict(engine.registry(refresh=True))
    node = Node(
        name="frames_mean",
        function=frames_mean,
        inputs={"raw_dark": "raw/dark"},
        outputs=("dark",),
        check=check,
    )
    installed[node.name] = RegisteredNode(node, "test")
    monkeypatch.setattr(engine, "_installed", lambda: installed)
    store = small_store(tmp_path / "run.zarr")  # exposure times 0.1 and 0.3 s
    assert cli.main(["validate", str(store.path), "--flow", "frames_mean"]) == 0
    assert seen == [(["raw_dark"], {"longest": 1.0})]  # the flow's parameters
    monkeypatch.setattr(frames_mean, "__kwdefaults__", {"longest": 0.2})
    installed[node.name] = RegisteredNode(
        Node(
            name="frames_mean",
            function=frames_mean,
            inputs=node.inputs,
            outputs=node.outputs,
            check=check,
        ),
        "test",
    )
    capsys.readouterr()
    assert cli.main(["validate", str(store.path), "--flow", "frames_mean"]) == 1
    checked = capsys.readouterr().err
    with pytest.raises(CalibrationError) as info:  # the run (the CLI's listing is cached)
        run_steps(store.path, [Step("frames_mean")])
    text = "raw/dark: exposure_time 0.3 s is above 0.2 s"
    assert f"  - {text}" in checked and str(info.value) == text, (checked, info.value)
    assert not store.has("dark")


def test_the_calibration_nodes_declare_their_value_checks():
    from spectralize.engine import registry

    checked = {name for name, item in registry().items() if item.node.check is not None}
    assert {"recover_rgb_oecf", "hdr_merge", "recover_spectral_oecf", "calibrate_spectral"} <= checked
