"""Reliability: SIGKILL the flow process in the middle of reconstruction, then rerun.

Real processes: the CLI in a subprocess, a real zarr store. Every run is on the session's
Prefect API (no embedded server to start; the killed run's flow run is marked crashed there by
the rerun): tests/flows/test_store_safety.py kills a run together with its embedded server.
"""

import os
import shutil
import signal
import subprocess
import sys
import time
from importlib import util
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from spectralize.store import RunStore, work_dir

pytestmark = pytest.mark.slow  # real processes killed mid-run

_HELPERS = Path(__file__).parents[1] / "nodes" / "reconstruction" / "test_set_reconstruction.py"
_spec = util.spec_from_file_location("set_reconstruction_inputs", _HELPERS)
_module = util.module_from_spec(_spec)
_spec.loader.exec_module(_module)
reconstruction_inputs = _module.reconstruction_inputs

# slow every set down a little so the kill lands between sets
SETTINGS = ["--set", "tolerance=1e-6", "--set", "max_iterations=3000"]


def cli(*args, api=None, **kwargs):
    """The CLI in a subprocess: on its own embedded Prefect API, or on ``api``."""
    env = {**os.environ, "PREFECT_LOGGING_LEVEL": "INFO"}
    if api is not None:
        env["PREFECT_API_URL"] = api
    return subprocess.Popen(
        [sys.executable, "-m", "spectralize.flows.cli", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        **kwargs,
    )


def prepared_store(path: Path) -> RunStore:
    from spectralize.nodes.reconstruction.endmember_library import endmember_library
    from spectralize.nodes.reconstruction.set_reconstruction import reconstruct_seed_set

    hdr, bands, camera, sets, _ = reconstruction_inputs()
    store = RunStore.create(path)
    store.write("hdr", hdr, fingerprint="hdr")
    store.write("bands", bands, fingerprint="bands")
    store.write("camera_matrix", xr.Dataset({"camera_matrix": camera.camera_matrix}), fingerprint="c")
    store.write("image_sets", sets, fingerprint="sets")
    library = endmember_library(hdr, bands, camera, sets)
    store.write("endmember_library", library, fingerprint="library")
    store.write("spectra_seed", reconstruct_seed_set(hdr, bands, camera, sets), fingerprint="seed")
    return store


def region_flags(store: Path) -> list[Path]:
    """Flag chunks of finished regions (not zarr's ``*.partial`` files of a write in flight)."""
    return sorted(
        p for p in (work_dir(store) / "staging").glob("spectra.*.done/c/*") if p.name.isdigit()
    )


def test_killed_reconstruction_resumes_without_recomputing_finished_sets(prefect_api, tmp_path):
    from prefect.settings import PREFECT_API_URL

    killed = prepared_store(tmp_path / "killed.zarr").path
    clean = tmp_path / "clean.zarr"
    shutil.copytree(killed, clean)

    # an uninterrupted run, for comparison
    api = PREFECT_API_URL.value()
    reference = cli("run", "reconstruct_image_sets", str(clean), *SETTINGS, api=api)
    out, _ = reference.communicate(timeout=600)
    assert reference.returncode == 0, out

    # the same run, killed with SIGKILL once some sets are written and others are not
    process = cli("run", "reconstruct_image_sets", str(killed), *SETTINGS, api=api)
    n_sets = int(RunStore.open(killed).read("image_sets").sizes["set"])
    deadline = time.time() + 600
    try:
        while time.time() < deadline and not region_flags(killed):
            assert process.poll() is None, "the flow ended before any set was written"
            time.sleep(0.02)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the flow process and any child of it
        process.wait()
    finished = [int(p.name) for p in region_flags(killed)]
    assert finished and len(finished) < n_sets, finished
    regions = next((work_dir(killed) / "staging").glob("spectra.*.regions"))
    written = {  # each finished region's staged file
        p.relative_to(regions).as_posix(): p.stat().st_mtime_ns for p in regions.glob("*/radiance.npy")
    }
    assert not RunStore.open(killed).has("spectra")  # nothing looks finished

    rerun = cli("run", "reconstruct_image_sets", str(killed), *SETTINGS, api=api)
    out, _ = rerun.communicate(timeout=600)
    assert rerun.returncode == 0, out
    # the store's message, or the progress display's rendering of it
    assert f"{len(finished)}/" in out and "resuming" in out

    store = RunStore.open(killed)
    # the staged chunks of the sets finished before the kill were adopted, not written again
    # (the rerun's message above); at commit every region is packed into shards, so the
    # finished group's files are all new
    final = store.path / "spectra"
    assert len(written) >= len(finished)  # the finished sets were staged before the kill
    assert not list(final.rglob("*.partial"))  # what the kill left half-written is gone
    # and the cube equals the uninterrupted run's
    got = store.read("spectra")
    want = RunStore.open(clean).read("spectra")
    np.testing.assert_allclose(got.radiance.values, want.radiance.values, rtol=1e-5, atol=1e-7)
    assert got.image.values.tolist() == want.image.values.tolist()
