"""A local run solves the batches of tiny image sets in a pool of processes, two at a time.

Issue 27: on threads the batches (mostly Python, holding the GIL) kept about one core busy.
"""

import os
import signal
import subprocess
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import dask
import numpy as np
import pytest

from spectralize.flows.memory import PeakMemory, process_pool, resident_bytes
from spectralize.flows.runtime import dask_scheduler
from spectralize.nodes.reconstruction import set_reconstruction
from spectralize.nodes.reconstruction.set_reconstruction import (
    PROCESS_POOL,
    reconstruct_image_sets,
    reconstruct_seed_set,
)
from spectralize.store import RunStore

from ..nodes.reconstruction.test_set_reconstruction import reconstruction_inputs


class _Gate:
    """A real process pool whose first ``parties`` submissions wait for each other: a run
    that never has that many batches in flight at once fails (the barrier breaks)."""

    def __init__(self, pool: ProcessPoolExecutor, parties: int) -> None:
        self.pool = pool
        self.barrier = threading.Barrier(parties, timeout=120)  # only guards against a hang
        self.submitted = 0
        self._lock = threading.Lock()

    def submit(self, fn, *args, **kwargs):
        with self._lock:
            self.submitted += 1
            first = self.submitted <= self.barrier.parties
        if first:
            self.barrier.wait()  # BrokenBarrierError if the other batch never comes
        return self.pool.submit(fn, *args, **kwargs)


@pytest.mark.slow  # every set twice, and two worker processes start (~30 s on 2 busy cores)
def test_two_batches_solve_at_once_in_processes_as_in_threads(tmp_path, monkeypatch):
    hdr, bands, camera, sets, _ = reconstruction_inputs()
    settings = {"tolerance": 1e-2, "max_iterations": 3}
    seed = reconstruct_seed_set(hdr, bands, camera, sets, **settings)
    monkeypatch.setattr(set_reconstruction, "BATCH_SETS_ABOVE", 0)
    pixel = hdr.sizes["y"] * hdr.sizes["x"] * 4 * (camera.sizes["wavelength"] + 1)
    monkeypatch.setattr(set_reconstruction, "BATCH_BYTES", 4 * pixel)  # one set a batch
    cube = reconstruct_image_sets(hdr, bands, camera, sets, seed, **settings)
    assert len(cube.radiance.chunks[0]) >= 3  # the seed set's chunk and two batches at least
    in_threads = cube.compute()  # no pool: each batch in a dask thread

    store = RunStore.create(tmp_path / "run.zarr")
    with process_pool(2) as pool:
        gate = _Gate(pool, 2)
        with dask.config.set({PROCESS_POOL: gate}):
            store.write("spectra", cube, resumable_along="image", concurrent_regions=2)
    assert gate.submitted == len(cube.radiance.chunks[0]) - 1  # every batch but the seed's
    written = store.read("spectra").sel(image=in_threads.image.values).load()
    for name in ("radiance", "confidence", "iterations"):
        np.testing.assert_array_equal(written[name].values, in_threads[name].values, err_msg=name)


def test_a_local_run_has_a_process_pool_only_while_it_runs():
    with dask_scheduler(None) as parallel:
        pool = dask.config.get(PROCESS_POOL, None)
        assert parallel == max(1, os.cpu_count() or 1)
        assert isinstance(pool, ProcessPoolExecutor) == (parallel > 1)
    assert dask.config.get(PROCESS_POOL, None) is None


def test_the_peak_of_a_block_counts_its_pool_workers():
    with PeakMemory() as measured:
        with process_pool(1) as pool:
            child = pool.submit(resident_bytes, "VmHWM").result()
        own = resident_bytes()
    if measured.peak_bytes is None or own is None:  # no /proc: nothing measured, nothing fails
        assert measured.peak_bytes is None
        return
    assert child > 0
    assert measured.peak_bytes >= own + child


_KILLED_PARENT = """
import os, time
from spectralize.flows.memory import process_pool
if __name__ == "__main__":
    with process_pool(1) as pool:
        print(pool.submit(os.getpid).result(), flush=True)
        pool.submit(time.sleep, 600)
        time.sleep(600)
"""


def test_pool_workers_end_with_a_killed_parent(tmp_path):
    script = tmp_path / "parent.py"
    script.write_text(_KILLED_PARENT)
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    worker = int(parent.stdout.readline())
    os.kill(parent.pid, signal.SIGKILL)  # no shutdown: the worker must notice by itself
    parent.wait()
    for _ in range(600):  # only guards against a hang; the worker polls its parent each second
        if not Path(f"/proc/{worker}").exists() or "Z" in _state(worker):
            break
        time.sleep(0.1)
    assert not Path(f"/proc/{worker}").exists() or "Z" in _state(worker)


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"
