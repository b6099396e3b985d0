"""A dask worker that dies without a nanny: the run ends with a clear error, it does not hang.

Real processes: a ``dask scheduler``, one ``dask worker --no-nanny --nthreads 1`` and the
``spectralize run`` command line against a real run store. The worker is SIGKILLed while it
computes; dask then waits without limit for a worker that will not come back, and only the
watchdog of :func:`spectralize.flows.dask_setup.dask_scheduler` ends the run.
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from distributed import Client

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.store import RunStore

pytestmark = pytest.mark.slow  # real processes killed mid-run

# The CLI's own main(), with the watchdog's grace period shortened from 30 s so that the
# test stays short; everything else (Prefect, the store, the dask client) is the real run.
LOST_AFTER = 6
RUN = (
    "import sys\n"
    "from spectralize.flows import dask_setup\n"
    "dask_setup.LOST_WORKERS_SECONDS = float(sys.argv[1])\n"
    "from spectralize.flows.cli import main\n"
    "sys.exit(main(sys.argv[2:]))\n"
)
HANG = 120  # seconds: a run still going after this is a hang


def _wait(condition, what: str, *processes: subprocess.Popen, timeout: float = 90) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        for process in processes:
            assert process.poll() is None, f"{process.args[:4]} ended before {what}"
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def _stop(process: subprocess.Popen | None) -> None:
    """Kill ``process`` and whatever it started (by pid), and reap it."""
    if process is None:
        return
    try:
        family = [*psutil.Process(process.pid).children(recursive=True), psutil.Process(process.pid)]
    except psutil.NoSuchProcess:
        family = []
    for member in family:
        try:
            member.kill()
        except psutil.NoSuchProcess:
            pass
    process.wait(timeout=30)
    psutil.wait_procs(family, timeout=10)


def test_a_killed_worker_ends_the_run_with_a_clear_error(prefect_api, tmp_path):
    from prefect.settings import PREFECT_API_URL

    store = RunStore.create(tmp_path / "run.zarr")
    raw = make_raw_dark(frames=96, shape=(160, 160), exposure_times=(0.1, 0.2, 0.4))
    store.write("raw/dark", raw, fingerprint="raw-v1")
    env = {
        **os.environ,
        "PREFECT_LOGGING_LEVEL": "WARNING",
        "DASK_LOGGING__DISTRIBUTED": "warning",
        "PREFECT_API_URL": PREFECT_API_URL.value(),  # the session's API: no server to start
    }
    scheduler_file = tmp_path / "scheduler.json"
    output = tmp_path / "run.log"
    scheduler = worker = run = None
    client = None
    try:
        scheduler = subprocess.Popen(
            [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0"]
            + ["--dashboard-address", ":0", "--scheduler-file", str(scheduler_file)],
            env=env,
            cwd=tmp_path,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        _wait(scheduler_file.exists, "the scheduler wrote its address", scheduler)
        _wait(lambda: scheduler_file.stat().st_size > 0, "the scheduler wrote its address", scheduler)
        address = json.loads(scheduler_file.read_text())["address"]
        worker = subprocess.Popen(
            [sys.executable, "-m", "dask", "worker", address, "--no-nanny", "--nthreads", "1"]
            + ["--dashboard-address", ":0", "--local-directory", str(tmp_path / "worker")],
            env=env,
            cwd=tmp_path,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        client = Client(address, set_as_default=False)
        client.wait_for_workers(1, timeout=60)
        (worker_address,) = client.scheduler_info(n_workers=-1)["workers"]

        with open(output, "w") as log:
            run = subprocess.Popen(
                [sys.executable, "-c", RUN, str(LOST_AFTER), "run", "dark", str(store.path)]
                + ["--set", "frames_per_chunk=2", "--dask-address", address],
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        # kill the worker while it computes this run's tasks
        _wait(
            lambda: any(client.processing().values()),
            "the worker computing",
            run,
            worker,
        )
        os.kill(worker.pid, signal.SIGKILL)
        worker.wait(timeout=30)
        try:
            code = run.wait(timeout=HANG)
        except subprocess.TimeoutExpired:
            raise AssertionError(
                f"the run hung for {HANG} s after its only worker died:\n{output.read_text()}"
            ) from None
        text = output.read_text()
    finally:
        if client is not None:
            client.close()
        for process in (run, worker, scheduler):
            _stop(process)

    assert code == 2, text
    assert f"dask cluster {address}: lost 1 worker(s) ({worker_address}); 0 left" in text, text
    assert (
        f"spectralize run: error: dask cluster {address} has had no workers for {LOST_AFTER} s "
        "(they died or were stopped): the computation was cancelled; restart the workers"
    ) in text, text
    assert f"(in node 'dark_average' (computing) on run store {store.path})" in text, text
    # the command line's own message ends the output, without a traceback (the lines
    # before it are Prefect's log of the failed task run)
    assert "Traceback" not in text[text.index("spectralize run: error: ") :], text
    # nothing half-written is left looking finished, and the lock is released
    assert not store.has("dark") and store.staging_leftovers() == []
    assert not (Path(store.path) / "dark").exists()
