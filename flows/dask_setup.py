"""Where a run's dask work computes: local threads, or an existing ``dask.distributed`` cluster.

On local threads (the default) as many tasks run at once as the machine has cores, so each
task's BLAS and OpenMP run one thread (:data:`INNER_THREADS`), and the tasks' threads share
one glibc malloc arena (:data:`MALLOC_ARENAS`) that keeps the memory a tile frees for the
next tile (:func:`~spectralize.nodes.reconstruction.heap.keep_freed_memory`): the cores go
to the tasks, a long run's resident set stays flat, and the kernel does not fault each
tile's cubes in afresh. On a cluster the workers bring their own settings but for that one,
made as each worker starts; a watchdog reports lost workers and ends a run that has none
left instead of waiting for ever (:data:`LOST_WORKERS_SECONDS`). What these settings were
measured to change: ``docs/benchmarks_notes.md`` (full_run, paper_scale_throughput).
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from prefect import get_run_logger
from threadpoolctl import threadpool_limits

from spectralize.nodes.reconstruction.heap import glibc_mallopt, keep_freed_memory
from spectralize.schemas import StoreError

__all__ = [
    "dask_scheduler",
    "bound_malloc_arenas",
    "MALLOC_ARENAS",
    "INNER_THREADS",
    "LOST_WORKERS_SECONDS",
]

MALLOC_ARENAS = 1
"""glibc malloc arenas of a run on local threads (unless ``MALLOC_ARENA_MAX`` is set).

glibc gives each thread that allocates concurrently an arena of its own (up to 8 per core)
and hands freed memory back to the system only from an arena's top: in a long run of
thousands of small tasks on dask threads, the resident set grew with the images solved
while the Python objects did not. Few arenas keep it flat, and one is the heap that keeps a
tile's freed blocks for the next tile
(:func:`~spectralize.nodes.reconstruction.heap.keep_freed_memory`: glibc's other arenas map
large blocks afresh); the threads' numpy work holds no lock of malloc's for long (the
arrays are allocated once per call)."""


INNER_THREADS = 1
"""Threads of BLAS and OpenMP (numpy's and scipy's OpenBLAS, pykdtree's k-d tree) inside a
run's tasks on local threads, where as many tasks as cores already run at once.

Each of the concurrent tasks otherwise starts its own pool of BLAS threads per call; on a
set's small matrices those threads mostly spin, costing CPU time and wall time alike. A
``distributed`` worker already runs with one (its nanny sets ``OMP_NUM_THREADS`` and the
like)."""

LOST_WORKERS_SECONDS = 30.0
"""How long a cluster may have no worker at all before the run's computation is cancelled."""


def bound_malloc_arenas(arenas: int = MALLOC_ARENAS) -> bool:
    """Limit this process's glibc malloc to ``arenas`` arenas (``mallopt(M_ARENA_MAX)``).

    A no-op (``False``) where ``MALLOC_ARENA_MAX`` is set in the environment (the user's
    choice, read by glibc at start) or where the C library is not glibc (macOS, musl,
    Windows). Arenas already made stay; threads started afterwards share the bounded ones.

    Returns
    -------
    bool
        Whether the limit was set.
    """
    mallopt = None if "MALLOC_ARENA_MAX" in os.environ else glibc_mallopt()
    if mallopt is None:
        return False
    m_arena_max = -8  # <malloc.h>
    return mallopt(m_arena_max, int(arenas))


@contextlib.contextmanager
def dask_scheduler(address: str | None, log: Callable[[str], None] = print) -> Iterator[int]:
    """Local threads by default; an existing ``dask.distributed`` cluster when given its address.

    Yields how many regions (image sets) to compute at the same time: the number of worker
    threads of the cluster, or of this machine's cores (on local threads, BLAS and OpenMP run
    one thread per task meanwhile: :data:`INNER_THREADS`). On a cluster a watchdog reports a
    lost worker (a warning naming it) within seconds; when no worker is left for
    :data:`LOST_WORKERS_SECONDS` it cancels the computation, which then fails with a
    :class:`StoreError` saying so instead of waiting forever for workers that will not come
    back (dask reschedules a lost worker's tasks and waits for a new worker without limit).
    """
    if not address:
        bound_malloc_arenas()  # a long threaded run's resident set stays flat (MALLOC_ARENAS)
        keep_freed_memory()  # before the tasks' threads start: they share the heap that keeps it
        with threadpool_limits(limits=INNER_THREADS):  # the cores go to the tasks
            yield max(1, os.cpu_count() or 1)
        return
    from distributed import Client

    try:
        warn = get_run_logger().warning  # bound here: the watchdog thread has no run context
    except Exception:  # outside a Prefect run (plain .fn() call)

        def warn(message: str) -> None:
            print(f"warning: {message}", file=sys.stderr, flush=True)

    try:
        client = Client(address, set_as_default=True)
    except (OSError, TimeoutError) as error:
        raise StoreError(
            f"cannot reach the dask scheduler at {address} ({type(error).__name__}: {error}); "
            "check --dask-address and that `dask scheduler` and its workers run"
        ) from None
    with client:
        # each worker, now and as it joins, keeps its tiles' freed memory (before its threads)
        client.register_worker_callbacks(setup=keep_freed_memory)
        watchdog = _WorkerWatchdog(client, address, warn)
        threads = client.nthreads()
        log(f"dask cluster {address}: {len(threads)} worker(s), {sum(threads.values())} thread(s)")
        watchdog.start()
        try:
            yield max(1, sum(threads.values()))
        except Exception as error:
            if watchdog.gave_up:
                raise StoreError(watchdog.gave_up) from error
            raise
        finally:
            watchdog.stop()
            watchdog.join(timeout=5)


class _WorkerWatchdog(threading.Thread):
    """Polls a dask cluster's workers; reports losses; cancels the work when none is left.

    Once it has given up it keeps cancelling whatever is submitted afterwards (another
    thread of the same run may start a computation after the first cancel) until stopped.
    """

    def __init__(self, client: Any, address: str, warn: Callable[[str], None], interval: float = 2.0):
        super().__init__(name="spectralize-dask-watchdog", daemon=True)
        self.client, self.address, self.warn, self.interval = client, address, warn, interval
        self.gave_up: str | None = None
        self._stop_event = threading.Event()

    def _workers(self) -> set[str]:
        return set(self.client.scheduler_info(n_workers=-1).get("workers", {}))

    def run(self) -> None:
        try:
            known = self._workers()
        except Exception:
            return
        empty_since: float | None = None
        while not self._stop_event.wait(self.interval):
            if self.gave_up:
                self._cancel_everything()
                continue
            try:
                now = self._workers()
            except Exception:
                continue
            lost = known - now
            if lost:
                wait = f"; the run is cancelled if none is back within {LOST_WORKERS_SECONDS:.0f} s"
                self.warn(
                    f"dask cluster {self.address}: lost {len(lost)} worker(s) "
                    f"({', '.join(sorted(lost))}); {len(now)} left{'' if now else wait}"
                )
            known = now
            if now:
                empty_since = None
                continue
            empty_since = empty_since or time.monotonic()
            if time.monotonic() - empty_since >= LOST_WORKERS_SECONDS:
                self.gave_up = (
                    f"dask cluster {self.address} has had no workers for "
                    f"{LOST_WORKERS_SECONDS:.0f} s (they died or were stopped): the computation "
                    "was cancelled; restart the workers and run again (finished regions are kept)"
                )
                self.warn(self.gave_up)
                self._cancel_everything()

    def _cancel_everything(self) -> None:
        client, reason = self.client, "no dask workers left"

        async def cancel() -> None:
            keys = list(client.futures)
            if keys:
                client._send_to_scheduler(
                    {"op": "cancel-keys", "keys": keys, "force": True, "reason": reason, "msg": reason}
                )
            for state in list(client.futures.values()):
                state.cancel(reason=reason, msg=self.gave_up)

        with contextlib.suppress(Exception):
            client.sync(cancel)

    def stop(self) -> None:
        self._stop_event.set()
