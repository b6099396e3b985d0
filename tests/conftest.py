"""Shared fixtures: small real data, real zarr stores on tmp disk, a real Prefect API."""

from __future__ import annotations

import gc
import os
import sys

import pytest
from hypothesis import settings

import spectralize.flows  # noqa: F401  (sets Prefect's environment defaults before import)

# Property tests draw the same examples on every run (CI must not fail on a new random draw);
# `HYPOTHESIS_PROFILE=explore pytest` draws new examples and keeps failures in .hypothesis/.
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


@pytest.fixture(scope="session")
def prefect_api():
    """A real, temporary Prefect API (SQLite) for the whole session; started on first use."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


@pytest.fixture(scope="session", autouse=True)
def prefect_server_stopped_while_captured():
    """Stop Prefect's temporary API server at the end of the session, not at interpreter exit.

    A flow run outside :func:`prefect_api` starts Prefect's temporary server, which Prefect
    stops at exit with a log line through its console handler. That handler writes to the
    ``sys.stderr`` of the moment Prefect set up its logging: pytest's capture, closed by exit,
    so the line became a "Logging error ... I/O operation on closed file" traceback after the
    summary. Stopped here, while the capture is open, nothing is left for exit; the log lines
    and events still queued are sent first, as :func:`prefect_api`'s harness does before it
    stops its own server (session fixtures end in reverse order: that one has stopped already).
    """
    yield
    module = sys.modules.get("prefect.server.api.server")
    if module is None:
        return
    server = module.SubprocessASGIServer()  # the temporary server (a new, idle one if none ran)
    if server.running:
        from prefect.events.worker import EventsWorker
        from prefect.logging.handlers import APILogWorker

        APILogWorker.drain_all(timeout=30)
        EventsWorker.drain_all(timeout=30)
    server.stop()


@pytest.fixture(scope="module", autouse=True)
def survivors_frozen():
    """Every object alive when a test module starts (the imported libraries, session fixtures)
    kept out of the garbage collector's full collections, after one collection (``gc.freeze``).

    A flow collects garbage before each node (``flows.memory.release_free_memory``): in a
    pytest worker that has imported Prefect, dask, xarray, numba, SciPy and the notebook stack,
    a full collection walks several hundred thousand objects, a second or more per node run
    in the worker's own process. Frozen, it walks only what the module's tests made.
    Objects are still freed when their last reference goes; only cycles formed among frozen
    ones wait for the end of the session.
    """
    gc.collect()
    gc.freeze()
    yield


@pytest.fixture(scope="session", autouse=True)
def private_cache(tmp_path_factory):
    """The suite's caches (the `spectralize nodes` listing) in a temporary folder, never the
    user's; subprocesses inherit it through the environment."""
    previous = os.environ.get("SPECTRALIZE_CACHE_DIR")
    os.environ["SPECTRALIZE_CACHE_DIR"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if previous is None:
        os.environ.pop("SPECTRALIZE_CACHE_DIR", None)
    else:
        os.environ["SPECTRALIZE_CACHE_DIR"] = previous
