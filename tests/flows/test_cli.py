"""The command line, end to end, in real subprocesses (real Prefect, real zarr)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from spectralize.schemas import RunStore

EXE = [sys.executable, "-m", "spectralize.flows.cli"]


def cli(*args, cwd):
    env = {**os.environ, "PREFECT_LOGGING_LEVEL": "WARNING"}
    return subprocess.run([*EXE, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def tree(path: Path):
    return sorted(
        (p.relative_to(path).as_posix(), p.stat().st_mtime_ns) for p in path.rglob("*") if p.is_file()
    )


def test_demo_runs_then_skips(tmp_path):
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

    second = cli("demo", "--set", "simulate.recipe=tiny", cwd=tmp_path)
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
    assert "unknown flow or node 'nope'" in unknown.stderr and "dark_average" in unknown.stderr
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
    rerun = cli("run", "dark", str(store), "--set", "ddof=0", cwd=tmp_path)
    assert rerun.returncode == 0, rerun.stderr
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
