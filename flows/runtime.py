"""Prefect runtime: a flow runs a checked node graph against a run store.

Each node run is one Prefect task. Tasks exchange store paths and fingerprints, never
arrays. Resuming is the store's job, not Prefect's cache: a task whose output groups already
carry the fingerprint it would write is skipped, and a changed parameter or input changes
that fingerprint, so the node and everything downstream run again. This survives hard kills
(the fingerprints live in the store) and node code changes (the node version is part of the
fingerprint).

Nothing damaged or stale is trusted. How much is verified, and when:

- before a step is skipped as up to date, its input and output groups pass the store's cheap
  check (sizes, times, the checksums of files whose time changed, no damage mark);
- every chunk a step (or the report) reads is checked against its CRC-32 as it is read; a
  chunk that fails marks its group damaged (:meth:`RunStore.mark_damaged`): a group this flow
  makes is recomputed, with a warning naming the chunk, and so is everything that depends on
  it; a raw group is an error naming the chunk and the capture files its frames came from;
- ``verify=True`` (``spectralize run --verify``) first recomputes the checksum of every file
  of every group the flow reads or would skip (bit rot that kept the times, in groups no step
  reads this time), with the same outcome per group. It costs one read of those groups.
- before the report is written or confirmed up to date, the groups it shows
  (:data:`REPORT_GROUPS`) that this run did not write are checked deeply, smallest first, up to
  :data:`REPORT_VERIFY_BYTES` in all (larger ones are left to ``--verify``, and said so): a
  report never presents rot the run could have seen for about a second's read. A damaged
  group found there, or by a chunk the report reads, is recomputed with its dependants and
  the report written again, in the same run.

Input values are checked against the contract (NaN/inf, ranges) before a node's numerics
start. SIGTERM stops a run as Ctrl-C does (:mod:`.signals`).

One flow writes a store at a time (the store's lock, held for the whole run). A run whose
steps are all up to date answers before Prefect's API is started. The embedded Prefect
server dies with the flow process, even when that is killed with SIGKILL, and a flow run
left RUNNING by a killed process is marked crashed when the next run takes over its lock.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from prefect import flow, get_run_logger, task
from prefect.cache_policies import NO_CACHE
from threadpoolctl import threadpool_limits

from spectralize.engine import PlannedStep, Step, check_graph, registry
from spectralize.flows import progress
from spectralize.flows.pipelines import (  # noqa: F401  (re-exported: older imports)
    external_inputs,
    flow_inputs,
    report_directory,
    step_parameters,
)
from spectralize.schemas import GROUP_SCHEMAS, PipelineError, Problem, StoreError, validate_values
from spectralize.store import (
    SCHEMA_ATTR,
    ChecksumError,
    LockHolder,
    RunStore,
    StoreLock,
    compute_fingerprint,
)

from .memory import PeakMemory, process_peak_bytes, release_free_memory
from .signals import sigterm_as_interrupt

__all__ = [
    "StepReport",
    "RunReport",
    "run_steps",
    "output_fingerprint",
    "flow_inputs",
    "REPORT_GROUPS",
    "REPORT_VERIFY_BYTES",
]

REPORT_GROUPS = (
    "spectra",
    "evaluation",
    "truth/spectra",
    "calibration/spectral",
    "calibration/oecf_rgb",
    "calibration/oecf_spectral",
    "registration",
    "dark",
    "raw/rgb",
    "raw/spectral",
    "raw/white_reference",
    "raw/exposure_plan",
)
"""The groups :func:`~spectralize.flows.report.write_run_report` reads (a test holds it to that)."""

REPORT_VERIFY_BYTES = 2_000_000_000
"""At most this many bytes of the report's groups are checked deeply before each report: about
2 s at the 0.7-1.3 GB/s measured (datasets/README.md, what verifying costs); the demo store's
report groups (56 MB) take about 0.5 s."""


def output_fingerprint(run_fingerprint: str, group: str) -> str:
    """Fingerprint of one output group of a node run."""
    return hashlib.sha256(f"{run_fingerprint}/{group}".encode()).hexdigest()


@dataclass
class StepReport:
    """What one step did."""

    node: str
    status: str  # "ran" or "skipped"
    seconds: float
    outputs: dict[str, str]  # group -> fingerprint
    reason: str = ""  # why a step with a known result ran again (damaged output, repaired input)
    # the largest resident set of this process while the node ran [GB] (flows/memory.py);
    # None: skipped, or not measurable here. dask workers in other processes are not counted
    peak_rss_gb: float | None = None


@dataclass
class RunReport:
    """What a flow run did, step by step."""

    store: str
    flow: str
    steps: list[StepReport] = field(default_factory=list)
    report: str | None = None  # path of the HTML report, when one was written
    # this process's peak resident set since it started [GB], the nodes' peaks included
    # (resetting the high-water mark per node hides it from getrusage; flows/memory.py)
    peak_rss_gb: float | None = None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


MALLOC_ARENAS = 2
"""glibc malloc arenas of a run on local threads (unless ``MALLOC_ARENA_MAX`` is set).

glibc gives each thread that allocates concurrently an arena of its own (up to 8 per core)
and hands freed memory back to the system only from an arena's top: in a long run of
thousands of small tasks on dask threads, the resident set grew with the images solved
(full_run, issue 27: +0.19 GB per 1,000 images; the same 71 sets computed four times in one
process: 0.45 -> 0.54 GB with glibc's default, flat at 0.37 GB with two arenas), while the
Python objects did not. Two arenas keep it flat; the threads' numpy work holds no lock of
malloc's for long (the arrays are allocated once per call)."""


INNER_THREADS = 1
"""Threads of BLAS and OpenMP (numpy's and scipy's OpenBLAS, pykdtree's k-d tree) inside a
run's tasks on local threads, where as many tasks as cores already run at once.

Each of the concurrent tasks otherwise starts its own pool of BLAS threads per call; on a
set's small matrices those threads mostly spin. Measured on 4 batches of 959 images of the
5,280-image full_run store, 2 dask threads, 2 cores (issue 27): 47.4 s wall / 88.1 s CPU with
the libraries' default of one thread per core, 37.5 s / 65.2 s with one. A ``distributed``
worker already runs with one (its nanny sets ``OMP_NUM_THREADS`` and the like)."""


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
    if "MALLOC_ARENA_MAX" in os.environ or not sys.platform.startswith("linux"):
        return False
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    m_arena_max = -8  # <malloc.h>
    return bool(mallopt(ctypes.c_int(m_arena_max), ctypes.c_int(int(arenas))))


@contextlib.contextmanager
def dask_scheduler(address: str | None, log: Callable[[str], None] = print) -> Iterator[int]:
    """Local threads by default; an existing ``dask.distributed`` cluster when given its address.

    Yields how many regions (image sets) to compute at the same time: the number of worker
    threads of the cluster, or of this machine's cores (on local threads, BLAS and OpenMP run
    one thread per task meanwhile: :data:`INNER_THREADS`). On a cluster a watchdog reports a
    lost worker (a warning naming it) within seconds; when no worker is left for
    ``LOST_WORKERS_SECONDS`` it cancels the computation, which then fails with a
    :class:`StoreError` saying so instead of waiting forever for workers that will not come
    back (dask reschedules a lost worker's tasks and waits for a new worker without limit).
    """
    if not address:
        bound_malloc_arenas()  # a long threaded run's resident set stays flat (MALLOC_ARENAS)
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


LOST_WORKERS_SECONDS = 30.0


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


def _log() -> Callable[[str], None]:
    try:
        logger = get_run_logger()
    except Exception:  # called outside a Prefect run (plain .fn() call)
        return print
    return logger.info


def _expected_outputs(
    node_name: str,
    parameters: dict[str, Any],
    outputs: dict[str, str],
    input_fingerprints: dict[str, str],
) -> dict[str, str]:
    node = registry()[node_name].node
    params = node.parse_parameters(parameters)
    run_fp = compute_fingerprint(
        node.name, node.version, params.model_dump(mode="json"), input_fingerprints
    )
    return {group: output_fingerprint(run_fp, group) for group in outputs.values()}


def _damage(store: RunStore, groups: Sequence[str]) -> dict[str, list[Problem]]:
    """The groups (of those that exist) that fail the store's cheap check, with why."""
    found = {group: store.verify(group) for group in groups if store.has(group)}
    return {group: problems for group, problems in found.items() if problems}


def _damaged_input_error(store: RunStore, node: str, damaged: dict[str, list[Problem]]) -> StoreError:
    problems = []
    for group, found in damaged.items():
        made_by = store.provenance(group).get("node")
        hint = (
            f"made by node {made_by!r}: run a flow that includes it to recompute it"
            if made_by and not group.startswith("raw/")
            else "raw data: restore the file from the capture, or import the run again"
        )
        problems += [dataclasses.replace(p, hint=hint) for p in found]
    return StoreError(
        f"node {node!r} cannot run on run store {str(store.path)!r}: input group(s) "
        f"{', '.join(damaged)} are damaged (nothing was read or written)",
        problems,
    )


def _checksum_error(error: BaseException) -> ChecksumError | None:
    """The :class:`ChecksumError` that caused ``error`` (itself, or along its chain)."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        if isinstance(current, ChecksumError):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


def _made_by(planned: Sequence[PlannedStep]) -> set[str]:
    """The groups the steps of a flow write."""
    return {group for item in planned for group in item.outputs.values()}


def _handle_damage(
    store: RunStore,
    group: str,
    where: str,
    why: str,
    made: set[str],
    *,
    key: str = "",
    cause: BaseException | None = None,
) -> None:
    """Mark a damaged group; a group the flow makes is then recomputed, raw data is an error.

    ``where`` names the damaged chunk or file, ``why`` what is wrong with it, ``key`` the
    chunk's store key (for the capture files of a raw chunk); the error keeps the notes of
    ``cause`` (which node read it).
    """
    store.mark_damaged(group, f"{where}: {why}")
    if group in made:
        _warn(f"{group} is damaged ({where}: {why}); recomputing it and the groups that depend on it")
        return
    files: list[str] = []
    if group.startswith("raw/"):
        from spectralize.flows.ingest.raw_groups import capture_files_of_chunk

        files = capture_files_of_chunk(store, key or where)
    source = ""
    if files:
        more = f" and {len(files) - 3} more" if len(files) > 3 else ""
        source = f"; its frames came from capture file(s) {', '.join(files[:3])}{more}"
    folder = (store.attrs.get("capture") or {}).get("folder")
    fix = (
        f"ingest the capture folder again (`spectralize ingest {folder} {store.path}` rewrites "
        "the group from its files)"
        if folder
        else "restore it from its source, or import the run again"
    )
    error = StoreError(
        f"group {group!r} of run store {str(store.path)!r} is damaged and no step of this flow "
        f"can recompute it: {where}: {why}{source}",
        [Problem(where, "the bytes written at commit", why, fix)],
    )
    for note in getattr(cause, "__notes__", ()):
        error.add_note(note)
    raise error from cause


def _repair_chunk(store: RunStore, error: ChecksumError, made: set[str], marked: set[str]) -> None:
    """A chunk failed its checksum when read: mark its group damaged (see :func:`_handle_damage`).

    Raises the error itself when its group is unknown or was already repaired once in this
    run (a group that is damaged again right after its rewrite is a failing disk, not rot).
    """
    group = store.group_of(error.key) if error.key else None
    if group is None or group in marked:
        raise error
    marked.add(group)
    found = error.problems[0].found if error.problems else "other bytes"
    why = f"its bytes do not match the checksum recorded when it was written ({found})"
    _handle_damage(store, group, f"chunk {error.key}", why, made, key=error.key, cause=error)


def _verify_deep(store: RunStore, planned: Sequence[PlannedStep], log: Callable[[str], None]) -> None:
    """``--verify``: every checksum of every group the flow reads or writes, before trusting it."""
    groups = sorted({g for item in planned for g in (*item.inputs.values(), *item.outputs.values())})
    made = _made_by(planned)
    start, size = time.perf_counter(), 0
    for group in groups:
        if not store.has(group):
            continue
        size += store.size_on_disk(group)
        problems = store.verify(group, deep=True)
        if problems:
            first = problems[0]
            _handle_damage(store, group, first.where, f"{first.found}, expected {first.expected}", made)
    seconds = time.perf_counter() - start
    log(f"verified {len(groups)} group(s), {size / 1e6:,.1f} MB, in {seconds:.2f} s")


class _Recompute(Exception):
    """Groups were marked damaged before the report: run the steps again (they recompute them)."""


def _verify_report_groups(store: RunStore, made: set[str], fresh: set[str]) -> bool:
    """Check the report's groups deeply before the report (see the module's docstring).

    ``fresh``: groups this run wrote (not checked again). Returns ``False`` when a group the
    flow makes was found damaged (it is marked: the steps recompute it); a damaged raw group
    is an error naming the chunk (:func:`_handle_damage`).
    """
    groups = sorted((store.size_on_disk(g), g) for g in REPORT_GROUPS if g not in fresh and store.has(g))
    budget, healthy, left = REPORT_VERIFY_BYTES, True, []
    for size, group in groups:
        if size > budget:
            left.append(f"{group} ({size / 1e9:.1f} GB)")
            continue
        budget -= size
        problems = store.verify(group, deep=True)
        if problems:
            first = problems[0]
            _handle_damage(store, group, first.where, f"{first.found}, expected {first.expected}", made)
            healthy = False
    if left:
        _log()(
            f"report: not checked deeply before the report (over {REPORT_VERIFY_BYTES / 1e9:g} GB): "
            f"{', '.join(left)}; `spectralize run --verify` checks them"
        )
    return healthy


_VALUES_CHECKED: dict[tuple[str, str, str], None] = {}  # (store, group, fingerprint) checked


def _check_input_values(store: RunStore, node: str, groups: Sequence[str]) -> None:
    """NaN/inf and range rules of each input group's contract, before any numerics run."""
    problems: list[Problem] = []
    for group in groups:
        name = store.group_attrs(group).get(SCHEMA_ATTR, group)
        key = (str(store.path), group, str(store.fingerprint(group)))
        if name not in GROUP_SCHEMAS or key in _VALUES_CHECKED:
            continue
        found = validate_values(store.read(group, friendly=False), GROUP_SCHEMAS[name], group=group)
        if found:
            problems += found
        else:
            _VALUES_CHECKED[key] = None
    if problems:
        from spectralize.schemas import SchemaError

        raise SchemaError(
            f"node {node!r} cannot run on run store {str(store.path)!r}: its input values break "
            "the run-store contract (nothing was computed)",
            problems,
        )


@task(name="node", cache_policy=NO_CACHE, persist_result=False)
def run_node(
    store_path: str,
    node_name: str,
    parameters: dict[str, Any],
    inputs: dict[str, str],
    outputs: dict[str, str],
    input_fingerprints: dict[str, str],
    dask_address: str | None = None,
    rerun_because: str = "",
) -> StepReport:
    """Run one node against the store, or skip it when its outputs are up to date.

    Parameters are plain JSON values and group names; the data stays in the store. The
    parameters were validated by the graph check (``plan``) before the flow started; calling
    the node checks each input group against the schema the node declares for it (structure
    only, nothing is computed) before the node's function runs.

    Up to date means: every output carries the fingerprint this run would write, and the
    inputs and outputs pass the store's cheap check. A damaged output is recomputed (with a
    warning); a damaged input is an error naming its files. ``rerun_because`` forces a run
    (an input was recomputed because it was damaged).
    """
    log = _log()
    node = registry()[node_name].node
    params = node.parse_parameters(parameters)
    expected = _expected_outputs(node_name, parameters, outputs, input_fingerprints)
    store = RunStore.open(store_path)
    damaged_inputs = _damage(store, list(inputs.values()))
    if damaged_inputs:
        raise _damaged_input_error(store, node.name, damaged_inputs)
    reason = rerun_because
    if all(store.fingerprint(group) == fp for group, fp in expected.items()):
        damaged = _damage(store, list(expected))
        if damaged:
            reason = "damaged output " + ", ".join(
                f"{group} ({problems[0]}{f' and {len(problems) - 1} more' if len(problems) > 1 else ''})"
                for group, problems in damaged.items()
            )
            _warn(f"{node.name}: recomputing: {reason}")
        elif not reason:
            log(f"{node.name}: skipped, {', '.join(expected)} already up to date")
            progress.notify("step_finished", node.name, "skipped", 0.0)
            return StepReport(node.name, "skipped", 0.0, expected)
        else:
            log(f"{node.name}: running again: {reason}")

    start = time.perf_counter()
    stage = "checking its inputs"
    # one node at a time in this process (the steps run in order), so its peak is its own;
    # what the nodes before it freed goes back to the system first, so that it does not
    # carry over (the heap kept grew with the images: issue 27, flows/memory.py)
    release_free_memory()
    with PeakMemory() as measured:
        try:
            _check_input_values(store, node.name, list(inputs.values()))
            # a re-run needs at least the room its previous result took
            store.check_free_space(
                sum(store.size_on_disk(g) for g in expected), group=", ".join(expected)
            )
            stage = f"reading {', '.join(sorted(inputs.values())) or 'no inputs'}"
            log(f"{node.name}: {stage}")
            progress.notify("stage", node.name, stage)
            # the node's solver runs (spectralize.engine.progress) become bars under its line
            with progress.node_tasks(node.name), dask_scheduler(dask_address, log) as parallel:
                data = {
                    argument: store.read(
                        group,
                        friendly=False,
                        chunks="shards" if argument in node.read_by_shard else None,
                    )
                    for argument, group in inputs.items()
                }
                stage = "computing"
                progress.notify("stage", node.name, stage)
                results = node(data, params)
                for schema, ds in results.items():
                    group = outputs[schema]
                    stage = f"writing group {group!r}"
                    log(f"{node.name}: writing {group}")
                    progress.notify("stage", node.name, f"computing and writing {group}")
                    provenance = {
                        "node": node.name,
                        "version": node.version,
                        "parameters": params.model_dump(mode="json"),
                        "inputs": dict(input_fingerprints),
                    }
                    store.write(
                        group,
                        ds,
                        schema=schema if schema in GROUP_SCHEMAS else None,
                        fingerprint=expected[group],
                        provenance=provenance,
                        chunks=node.chunks.get(schema),
                        resumable_along=node.resumable_along.get(schema),
                        concurrent_regions=parallel,
                        progress=_region_progress(log, node.name, group),
                    )
        except Exception as error:
            error.add_note(f"in node {node.name!r} ({stage}) on run store {store_path}")
            raise
    seconds = time.perf_counter() - start
    peak = None if measured.peak_gb is None else round(measured.peak_gb, 3)
    log(f"{node.name}: done in {seconds:.1f} s" + (f", peak resident {peak:.2f} GB" if peak else ""))
    progress.notify("step_peak", node.name, peak)
    progress.notify("step_finished", node.name, "ran", seconds)
    return StepReport(node.name, "ran", seconds, expected, reason, peak)


def _region_progress(log: Callable[[str], None], node: str, group: str) -> Callable[[str], None]:
    """The store's progress callback of one write: a log line, and the console's bar."""
    resumed: dict[str, int] = {}

    def report(message: str) -> None:
        log(f"{node}: {group}: {message}")
        progress.store_message(node, group, message, resumed)
        if " written (" in message:  # a region done: what its computation freed goes back
            release_free_memory(collect=False)  # (the heap crept up region by region: issue 27)

    return report


def _warn(message: str) -> None:
    try:
        get_run_logger().warning(message)
    except Exception:
        print(f"warning: {message}", file=sys.stderr)


def plan(store_path: str | Path, steps: Sequence[Step], *, create: bool = False) -> list[PlannedStep]:
    """Check the graph against the store before anything runs (nothing is written)."""
    path = Path(store_path)
    available: dict[str, str | None] = {}
    if path.exists() or not create:
        store = RunStore.open(path)
        for group in store.groups():
            available[group] = store.group_attrs(group).get(SCHEMA_ATTR)
    return check_graph(steps, available=available)


def run_steps(
    store_path: str | Path,
    steps: Sequence[Step],
    *,
    flow_name: str = "custom",
    problems: Sequence[Any] = (),
    retries: int = 0,
    retry_delay_seconds: float = 10.0,
    dask_address: str | None = None,
    report: bool = False,
    verify: bool = False,
) -> RunReport:
    """Run ``steps`` against the store at ``store_path`` as one Prefect flow run.

    The graph is checked first; every problem (plus ``problems`` found earlier, such as
    unknown ``--set`` keys) is raised at once in a :class:`~spectralize.schemas.PipelineError`
    and nothing is written. A store that does not exist yet is created only when the graph's
    first steps need no input groups; otherwise the missing store is the error.

    The store's lock is held for the whole run (a second writer gets
    :class:`~spectralize.store.StoreBusyError`). When every step is up to date the answer
    comes without starting Prefect. ``verify``: recompute the checksums of every group the
    flow reads or writes first (see the module's docstring). ``dask_address``: an existing
    ``dask.distributed`` scheduler (default: ``$DASK_SCHEDULER_ADDRESS``, else local threads;
    its workers must reach the store at the same path). SIGTERM is handled like Ctrl-C.
    """
    with sigterm_as_interrupt():
        return _run_steps(
            store_path,
            steps,
            flow_name,
            problems,
            retries,
            retry_delay_seconds,
            dask_address,
            report,
            verify,
        )


def _run_steps(
    store_path: str | Path,
    steps: Sequence[Step],
    flow_name: str,
    problems: Sequence[Any],
    retries: int,
    retry_delay_seconds: float,
    dask_address: str | None,
    report: bool,
    verify: bool,
) -> RunReport:
    path = Path(store_path).absolute()
    dask_address = dask_address or os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    if not path.exists():
        _require_store_or_first_steps_without_inputs(path, steps, flow_name)
    try:
        planned = plan(path, steps, create=True)
    except PipelineError as error:
        found = [*problems, *error.problems]
        raise PipelineError(f"the node graph cannot run ({len(found)} problem(s)):", found) from None
    if problems:
        raise PipelineError(f"the node graph cannot run ({len(problems)} problem(s)):", problems)
    if not path.exists():
        RunStore.create(path)
    store = RunStore.open(path)
    note = store.first_layout_note()
    if note:
        print(f"note: {note}", file=sys.stderr)
    with store.lock(f"spectralize run {flow_name}") as lock:
        if lock.previous is not None:
            _mark_crashed(lock.previous, path)
        if verify:
            _verify_deep(store, planned, print)
        try:
            up_to_date = _up_to_date_report(store, flow_name, planned, report)
        except Exception as error:  # the report read a damaged chunk: repair, then run
            found = _checksum_error(error)
            if found is None:
                raise
            _repair_chunk(store, found, _made_by(planned), set())
            up_to_date = None
        if up_to_date is not None:
            return up_to_date
        _embedded_server_dies_with_us()
        return _graph_flow(
            str(path),
            flow_name,
            [_as_dict(item.step) for item in planned],
            retries,
            retry_delay_seconds,
            dask_address,
            report,
        )


def _require_store_or_first_steps_without_inputs(path: Path, steps: Sequence[Step], flow: str) -> None:
    needs = external_inputs(steps)
    if needs:
        raise StoreError(
            f"run store {str(path)!r} does not exist (the {flow!r} flow reads "
            f"{', '.join(needs)} from it); check the path, or make the store first"
        )


def _up_to_date_report(
    store: RunStore, flow_name: str, planned: Sequence[PlannedStep], report: bool
) -> RunReport | None:
    """The run's report if every step is up to date and passes the cheap check, else ``None``."""
    fingerprints: dict[str, str] = {}
    run_report = RunReport(str(store.path), flow_name)
    for item in planned:
        input_fps = {}
        for group in item.inputs.values():
            fp = fingerprints.get(group) or store.fingerprint(group)
            if fp is None:
                return None
            input_fps[group] = fp
        expected = _expected_outputs(
            item.node.name, item.parameters.model_dump(mode="json"), item.outputs, input_fps
        )
        if any(store.fingerprint(group) != fp for group, fp in expected.items()):
            return None
        if _damage(store, [*item.inputs.values(), *expected]):
            return None
        fingerprints.update(expected)
        run_report.steps.append(StepReport(item.node.name, "skipped", 0.0, expected))
    if report:
        if not _verify_report_groups(store, _made_by(planned), set()):
            return None  # a damaged group was marked: the flow recomputes it, then reports
        run_report.report = write_report_task.fn(str(store.path))
    return run_report


_REAPER = """
import sys, time, psutil
pid, started = int(sys.argv[1]), float(sys.argv[2])
sys.stdin.read()  # returns when the flow process exits, however it exits
try:
    server = psutil.Process(pid)
    if abs(server.create_time() - started) < 1e-3:
        try:
            server.wait(5)  # a normal exit stops it itself
        except psutil.TimeoutExpired:
            server.terminate()
            try:
                server.wait(5)
            except psutil.TimeoutExpired:
                server.kill()
except psutil.Error:
    pass
"""
_REAPERS: dict[int, subprocess.Popen] = {}


def _embedded_server_dies_with_us() -> None:
    """Start Prefect's embedded API now and make sure it ends with this process.

    Prefect starts it as a child process and stops it at exit, but a SIGKILL of the flow
    process would leave it running (reparented, listening). A tiny watcher process holds
    the read end of a pipe from this process: when this process is gone, however it died,
    the pipe closes and the watcher stops the server. Nothing happens with a configured
    Prefect server (``PREFECT_API_URL``).
    """
    from prefect.settings import PREFECT_API_URL, PREFECT_SERVER_EPHEMERAL_ENABLED

    if PREFECT_API_URL.value() or not PREFECT_SERVER_EPHEMERAL_ENABLED.value():
        return
    import psutil
    from prefect.server.api.server import SubprocessASGIServer

    server = SubprocessASGIServer()
    server.start()
    process = server.server_process
    if process is None or process.pid in _REAPERS:
        return
    started = psutil.Process(process.pid).create_time()
    _REAPERS[process.pid] = subprocess.Popen(
        [sys.executable, "-c", _REAPER, str(process.pid), repr(started)],
        stdin=subprocess.PIPE,
        start_new_session=True,  # not stopped by a Ctrl-C meant for the flow
    )


def _mark_crashed(previous: LockHolder, path: Path) -> None:
    """Mark the flow run of a killed writer crashed (it would stay RUNNING in Prefect)."""
    if not previous.flow_run_id:
        return
    try:
        from prefect import get_client
        from prefect.states import Crashed

        _embedded_server_dies_with_us()
        with get_client(sync_client=True) as client:
            flow_run = client.read_flow_run(previous.flow_run_id)
            if flow_run.state is not None and flow_run.state.is_final():
                return
            client.set_flow_run_state(
                flow_run.id,
                Crashed(
                    message=f"its process ({previous.describe()}) died without finishing; "
                    f"found when the next run took over {path.name}"
                ),
                force=True,
            )
    except Exception as error:  # a different Prefect API, or the run was deleted
        print(
            f"spectralize: could not mark flow run {previous.flow_run_id} of {previous.describe()} "
            f"as crashed: {type(error).__name__}: {error}",
            file=sys.stderr,
        )
        return
    print(
        f"spectralize: flow run {previous.flow_run_id} of {previous.describe()} was left "
        "RUNNING by a process that is gone; marked it crashed",
        file=sys.stderr,
    )


@task(name="report", cache_policy=NO_CACHE, persist_result=False)
def write_report_task(store_path: str) -> str | None:
    """Write the HTML report of a processed run (skip if current).

    A run with ground truth is reported once its ``evaluation`` is finished; a real run
    (no truth) once its ``spectra`` or at least its calibration is. The report is rewritten
    when the fingerprint of the group it depends on changes.
    """
    from spectralize.flows.report import write_run_report

    log = _log()
    store = RunStore.open(store_path)
    basis = next((g for g in ("evaluation", "spectra", "calibration/spectral") if store.has(g)), None)
    if basis is None:
        log("report: neither evaluation, spectra nor calibration/spectral yet, no report written")
        return None
    directory = report_directory(store_path)
    stamp = directory / ".report-fingerprint"
    index = directory / "index.html"
    fingerprint = f"{basis}:{store.fingerprint(basis)}"
    if index.exists() and stamp.exists() and stamp.read_text() == fingerprint:
        log(f"report: up to date at {index}")
        return str(index)
    start = time.perf_counter()
    path = write_run_report(store, directory=directory)
    stamp.write_text(fingerprint)
    log(f"report: written to {path} in {time.perf_counter() - start:.1f} s")
    return str(path)


def _as_dict(step: Step) -> dict[str, Any]:
    return {
        "node": step.node,
        "parameters": dict(step.parameters),
        "inputs": dict(step.inputs),
        "outputs": dict(step.outputs),
        "optional": step.optional,
    }


@flow(name="spectralize", flow_run_name="{flow_name}: {store_path}", validate_parameters=False)
def _graph_flow(
    store_path: str,
    flow_name: str,
    steps: list[dict[str, Any]],
    retries: int = 0,
    retry_delay_seconds: float = 10.0,
    dask_address: str | None = None,
    report: bool = False,
) -> RunReport:
    from prefect.runtime import flow_run

    StoreLock(store_path).note(flow_run_id=str(flow_run.id))
    planned = plan(store_path, [Step(**s) for s in steps], create=False)
    store = RunStore.open(store_path)
    made, marked = _made_by(planned), set[str]()
    checked_report, earlier = False, None
    while True:  # a chunk that fails its checksum when read: its group is recomputed
        try:
            result = _run_planned(
                store,
                flow_name,
                planned,
                retries,
                retry_delay_seconds,
                dask_address,
                report and not checked_report,
                report,
            )
            if earlier is not None:  # what ran in the pass stopped before the report counts
                result.steps = [
                    first if first.status == "ran" and step.status == "skipped" else step
                    for first, step in zip(earlier.steps, result.steps, strict=True)
                ]
            return result
        except _Recompute as stopped:
            checked_report, earlier = True, stopped.args[0]  # once: the next pass rewrites it
        except Exception as error:
            found = _checksum_error(error)
            if found is None:
                raise
            _repair_chunk(store, found, made, marked)


def _run_planned(
    store: RunStore,
    flow_name: str,
    planned: Sequence[PlannedStep],
    retries: int,
    retry_delay_seconds: float,
    dask_address: str | None,
    check_report: bool,
    report: bool,
) -> RunReport:
    """The steps of a flow run in order (up-to-date ones skipped), then its report.

    ``check_report``: check the report's groups this run did not write deeply first
    (:func:`_verify_report_groups`); damage found there raises :class:`_Recompute`.
    """
    log = get_run_logger()
    store_path = str(store.path)
    run_report = RunReport(store_path, flow_name)
    fingerprints: dict[str, str] = {}
    repaired: set[str] = set()  # groups recomputed because they were damaged, or made from such
    for index, item in enumerate(planned, start=1):
        log.info(f"[{index}/{len(planned)}] {item.node.name}")
        progress.notify("step_started", index, len(planned) + bool(report), item.node.name)
        input_fps = {}
        for group in item.inputs.values():
            fp = fingerprints.get(group) or store.fingerprint(group)
            if fp is None:
                raise StoreError(f"input group {group!r} of node {item.node.name!r} is missing")
            input_fps[group] = fp
        node_task = run_node.with_options(
            name=item.node.name,
            retries=retries,
            retry_delay_seconds=retry_delay_seconds,
            task_run_name=item.node.name,
        )
        step_report = node_task(
            store_path,
            item.node.name,
            item.parameters.model_dump(mode="json"),
            item.inputs,
            item.outputs,
            input_fps,
            dask_address,
            ", ".join(f"input {g} was recomputed" for g in item.inputs.values() if g in repaired),
        )
        if step_report.reason:
            repaired.update(step_report.outputs)
        fingerprints.update(step_report.outputs)
        run_report.steps.append(step_report)
    ran = sum(s.status == "ran" for s in run_report.steps)
    log.info(f"{flow_name}: {ran} node(s) ran, {len(run_report.steps) - ran} skipped")
    if check_report:
        fresh = {g for step in run_report.steps if step.status == "ran" for g in step.outputs}
        if not _verify_report_groups(store, _made_by(planned), fresh):
            raise _Recompute(run_report)
    if report:
        progress.notify("step_started", len(planned) + 1, len(planned) + 1, "report")
        start = time.perf_counter()
        run_report.report = write_report_task(store_path)
        progress.notify("step_finished", "report", "ran", time.perf_counter() - start)
    peak = process_peak_bytes()
    run_report.peak_rss_gb = None if peak is None else round(peak / 1e9, 3)
    return run_report
