"""A flow on a real multi-process dask cluster whose workers run in other directories.

Real processes: a ``dask scheduler`` and two ``dask worker`` processes, each started in a
working directory of its own, and the ``spectralize run`` command line started in a third
with the store given by a relative path and the scheduler by ``DASK_SCHEDULER_ADDRESS``
(no ``--dask-address``): the recipe of the README's "On a dask cluster".
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from distributed import Client

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.store import RunStore

from .test_dask_worker_loss import _stop, _wait


@pytest.mark.slow
def test_a_flow_runs_on_workers_in_other_directories_found_by_environment(prefect_api, tmp_path):
    from prefect.settings import PREFECT_API_URL

    client_dir, worker_dirs = tmp_path / "client", [tmp_path / "w1", tmp_path / "w2"]
    for folder in (client_dir, *worker_dirs):
        folder.mkdir()
    store = RunStore.create(client_dir / "run.zarr")
    store.write(
        "raw/dark", make_raw_dark(frames=32, shape=(64, 64), exposure_times=(0.1, 0.2)), fingerprint="r"
    )
    env = {
        **os.environ,
        "PREFECT_LOGGING_LEVEL": "WARNING",
        "DASK_LOGGING__DISTRIBUTED": "warning",
        "PREFECT_API_URL": PREFECT_API_URL.value(),
    }
    scheduler_file = tmp_path / "scheduler.json"
    processes: list[subprocess.Popen] = []
    client = None
    try:
        processes.append(
            subprocess.Popen(
                [sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0"]
                + ["--dashboard-address", ":0", "--scheduler-file", str(scheduler_file)],
                env=env,
                cwd=tmp_path,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
        _wait(
            lambda: scheduler_file.exists() and scheduler_file.stat().st_size > 0,
            "the scheduler",
            *processes,
        )
        address = json.loads(scheduler_file.read_text())["address"]
        for folder in worker_dirs:
            processes.append(
                subprocess.Popen(
                    [sys.executable, "-m", "dask", "worker", address, "--nthreads", "1"]
                    + ["--dashboard-address", ":0", "--local-directory", str(folder)],
                    env=env,
                    cwd=folder,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        client = Client(address, set_as_default=False)
        client.wait_for_workers(2, timeout=90)
        assert sorted(client.run(os.getcwd).values()) == sorted(map(str, worker_dirs))
        done = subprocess.run(
            [sys.executable, "-m", "spectralize.flows.cli", "run", "dark", "run.zarr"]
            + ["--set", "frames_per_chunk=4"],
            env={**env, "DASK_SCHEDULER_ADDRESS": address},
            cwd=client_dir,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stdout + done.stderr
        worked = client.run(lambda dask_worker: dask_worker.state.transition_counter)
        assert all(count > 0 for count in worked.values()), worked  # both computed
    finally:
        if client is not None:
            client.close()
        for process in reversed(processes):
            _stop(process)
    assert store.has("dark") and store.verify("dark", deep=True) == []
    mean = store.read("dark")["mean"].values
    assert mean.shape[-2:] == (64, 64) and np.isfinite(mean).all()
