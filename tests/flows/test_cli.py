"""The command line, end to end, in real subprocesses (real Prefect, real zarr)."""

import os
import subprocess
import sys

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


# The demo's first run, the runs that skip after it, bad input and a changed parameter:
# tests/test_packaging.py::test_demo_runs_then_skips, on the installed wheel's command line
# (its first demo is the one the wheel's own test checks, run once for both).


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
