"""The command line, end to end, in real subprocesses (real Prefect, real zarr)."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from spectralize.store import RunStore

EXE = [sys.executable, "-m", "spectralize.flows.cli"]


def cli(*args, cwd, api=None):
    """``spectralize *args`` in a subprocess; with ``api``, on that Prefect API (the session's:
    no embedded server to start), else on its own embedded one, as a user's first run."""
    # Prefect's own console level is the command's to set: quiet unless -v
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_LOGGING_")}
    if api is not None:
        env["PREFECT_API_URL"] = api
    return subprocess.run([*EXE, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def tree(path: Path):
    return sorted(
        (p.relative_to(path).as_posix(), p.stat().st_mtime_ns) for p in path.rglob("*") if p.is_file()
    )


@pytest.mark.slow
def test_demo_runs_then_skips(prefect_api, tmp_path):
    from prefect.settings import PREFECT_API_URL

    # the first demo as a user runs it (its own embedded Prefect server); the runs after it
    # on the session's API, as what they check (skips, a changed parameter) is the store's
    api = PREFECT_API_URL.value()
    first = cli("demo", "--set", "simulate.recipe=tiny", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    assert "simulate                 ran" in first.stdout
    assert "dark_average             ran" in first.stdout
    store = tmp_path / "demo" / "run.zarr"
    assert f"results: {store}" in first.stdout
    for node in ("recover_rgb_oecf", "calibrate_bands", "reconstruct_image_sets", "evaluate"):
        assert f"{node:<24} ran" in first.stdout
    report = tmp_path / "demo" / "run-report" / "index.html"
    assert f"report: {report}" in first.stdout and report.is_file()
    # not a terminal: progress as plain lines on stderr, the images written (the time left
    # from the second region on: tests/flows/test_progress.py); Prefect's INFO lines stay off
    assert "[1/14] simulate" in first.stderr and "[14/14] report" in first.stderr
    written = re.findall(
        r"reconstruct_image_sets: spectra: ([\d,]+)/([\d,]+) images written", first.stderr
    )
    assert len(written) >= 2 and written[0][0] != written[0][1] and written[-1][0] == written[-1][1]
    assert "Finished in state" not in first.stderr and "| INFO" not in first.stderr

    second = cli("demo", "--set", "simulate.recipe=tiny", cwd=tmp_path, api=api)
    assert second.returncode == 0, second.stderr
    assert "simulate                 skipped" in second.stdout
    assert "dark_average             skipped" in second.stdout
    assert "ran " not in second.stdout

    valid = cli("validate", str(store), cwd=tmp_path)
    assert valid.returncode == 0 and "valid" in valid.stdout

    # bad input: unknown flow, unknown parameter, bad value -> non-zero, all listed, no writes
    before = tree(store)
    unknown = cli("run", "nope", str(store), cwd=tmp_path)
    assert unknown.returncode == 2
    assert "unknown flow or node 'nope'" in unknown.stderr
    assert "flows: btf, calibrate, dark, demo" in unknown.stderr  # nodes: counted, not listed
    bad = cli(
        "run",
        "dark",
        str(store),
        "--set",
        "bogus=1",
        "--set",
        "dark_average.frames_per_chunk=0",
        cwd=tmp_path,
    )
    assert bad.returncode == 2
    assert "--set bogus" in bad.stderr and "dark_average.frames_per_chunk" in bad.stderr
    assert tree(store) == before

    # a changed parameter re-runs the node through `run`
    rerun = cli("run", "dark", str(store), "--set", "ddof=0", "-v", cwd=tmp_path, api=api)
    assert rerun.returncode == 0, rerun.stderr
    assert "| INFO" in rerun.stderr  # -v: Prefect's lines instead of the progress lines
    assert not re.search(r"^\[1/1\] dark_average", rerun.stderr, re.MULTILINE)
    assert "dark_average             ran" in rerun.stdout
    assert RunStore.open(store).provenance("dark")["parameters"]["ddof"] == 0


def test_nodes_lists_the_dark_node_from_its_entry_point(tmp_path):
    out = cli("nodes", cwd=tmp_path)
    assert out.returncode == 0
    assert "dark_average" in out.stdout
    assert (
        "from:    entry point spectralize.nodes: dark_average = spectralize.nodes.calibration.declarations:DARK_AVERAGE"
        in out.stdout
    )
    assert "--set dark_average.frames_per_chunk=16" in out.stdout


def test_validate_lists_every_problem_and_fails(tmp_path):
    import numpy as np
    import xarray as xr

    not_a_store = cli("validate", str(tmp_path), cwd=tmp_path)
    assert not_a_store.returncode == 2 and "not a zarr v3 store" in not_a_store.stderr

    store = RunStore.create(tmp_path / "run.zarr")
    broken = xr.Dataset({"frames": (("frame", "y", "x"), np.zeros((2, 3, 3), np.float32))})
    broken.to_zarr(store.path, group="raw/dark", zarr_format=3, consolidated=False)
    out = cli("validate", str(store.path), cwd=tmp_path)
    assert out.returncode == 1
    for fragment in (
        "raw/dark:frames: expected dims",
        "expected dtype uint16",
        "expected attrs['units'] == 'DN'",
        "raw/dark:exposure_time",
        "attr 'camera'",
        "attr 'bit_depth'",
    ):
        assert fragment in out.stderr


@pytest.mark.parametrize("argv", [["run"], ["frobnicate"]])
def test_usage_errors_exit_non_zero(tmp_path, argv):
    assert cli(*argv, cwd=tmp_path).returncode != 0


@pytest.mark.slow
def test_a_node_that_fails_prints_one_clear_error_and_no_traceback(prefect_api, tmp_path):
    from prefect.settings import PREFECT_API_URL

    from spectralize.nodes.simulation.assembly import simulate_run
    from spectralize.nodes.simulation.recipes import get_recipe

    run = simulate_run(get_recipe("tiny"))
    raw_rgb = run["raw/rgb"]
    raw_rgb["counts"] = raw_rgb["counts"] * 0 + 1023  # every frame saturated
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("raw/rgb", raw_rgb, fingerprint="lab import")
    for group in ("raw/colour_checker", "raw/white_reference"):  # the cameras' targets, intact
        store.write(group, run[group], fingerprint="lab import")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_LOGGING_")}
    env["PREFECT_API_URL"] = PREFECT_API_URL.value()  # the session's API: no server to start
    out = subprocess.run(
        [*EXE, "run", "recover_rgb_oecf", str(store.path)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2
    assert "spectralize run: error: recover_rgb_oecf: raw/rgb:counts" in out.stderr
    assert "entirely saturated" in out.stderr and "Use shorter exposures" in out.stderr
    # Prefect's own failure lines (with their tracebacks) stay off the console without -v
    assert "Traceback" not in out.stdout + out.stderr
    assert "calibration/oecf_rgb" not in RunStore.open(store.path).groups()
