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

#: The modules that take longest (real flows in subprocesses, installs, killed processes),
#: longest first, from the per-module sums of ``pytest --durations=0``. ``make test`` runs
#: them first: with ``--dist loadfile`` a module stays on one worker, so a long module handed
#: out last keeps one worker busy after the other has finished. The modules not listed
#: follow in collection order; a stale list only costs balance, never a test.
LONG_MODULES = (
    "flows/test_safety_corpus.py",
    "notebooks/test_notebook.py",
    "test_packaging.py",
    "flows/test_foreign_capture.py",
    "flows/test_store_safety.py",
    "flows/test_resume_after_kill.py",
    "flows/ingest/test_readiness.py",
    "flows/test_white_level_capture.py",
    "flows/test_shared_texel_flow.py",
    "datasets/capture/test_calibration_cameras.py",
    "nodes/reconstruction/test_tiling.py",
    "flows/test_report.py",
    "flows/test_dask_cluster.py",
    "flows/test_node_listing.py",
    "flows/test_dask_worker_loss.py",
    "flows/test_cli_fast.py",
    "flows/test_cli.py",
    "flows/ingest/test_write.py",
    "nodes/reconstruction/test_endmember_library.py",
    "store/test_staging.py",
)


def pytest_collection_modifyitems(config, items):
    """The tests of :data:`LONG_MODULES` first, in that order; the others after them, as
    collected. Each module's tests keep their order. (``make test`` passes xdist's
    ``--no-loadscope-reorder``, which would otherwise hand out the modules with the most tests
    first, and so the long modules of a few tests last.)"""
    tests = os.path.dirname(__file__)
    rank = {os.path.join(tests, *module.split("/")): i for i, module in enumerate(LONG_MODULES)}
    first = len(LONG_MODULES)
    items[:] = sorted(items, key=lambda item: rank.get(str(item.path), first))
    check_timing_modules(items)


#: What a module's text holds when it marks tests ``timing``: ``make test``'s second pass
#: collects only the modules that hold it (the Makefile's ``TIMING_MODULES``).
TIMING_MARK = "mark.timing"


def check_timing_modules(items) -> None:
    """Stop the collection if a test is marked ``timing`` in a module whose text lacks
    :data:`TIMING_MARK` (marked some other way): ``make test`` would run it in neither pass."""
    hidden = sorted(
        {
            str(item.path)
            for item in items
            if item.get_closest_marker("timing") is not None and TIMING_MARK not in item.path.read_text()
        }
    )
    if hidden:
        raise pytest.UsageError(
            f"tests marked timing in modules without the text {TIMING_MARK!r}, which the "
            f"Makefile's timing pass looks for: {', '.join(hidden)}"
        )


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
