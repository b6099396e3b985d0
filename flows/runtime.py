"""Prefect runtime: a flow runs a checked node graph against a run store.

:func:`run_steps` checks the graph (:func:`plan`), takes the store's lock for the whole run
(one flow writes a store at a time), and runs each step as a Prefect task, then the report.
The parts, one concern each:

=====================  ================================================================
``steps.py``           one step: :func:`~.steps.run_node` runs a node or skips it when its
                       outputs carry the fingerprint it would write; :class:`RunReport`
``repair.py``          damage: what is verified and when, and how a damaged group is
                       recomputed (a group the flow makes) or refused (raw data)
``dask_setup.py``      where the dask work computes: local threads (BLAS threads, malloc
                       arenas) or a ``dask.distributed`` cluster watched for lost workers
``prefect_server.py``  Prefect's embedded API ends with the flow's process; a flow run left
                       RUNNING by a killed process is marked crashed
``run_log.py``         messages: Prefect's run logger inside a run, the console outside
=====================  ================================================================

A run whose steps are all up to date answers before Prefect's API is started. SIGTERM stops a
run as Ctrl-C does (:mod:`.signals`).
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from prefect import flow, get_run_logger, task
from prefect.cache_policies import NO_CACHE

from spectralize.engine import PlannedStep, Step, check_graph
from spectralize.flows import progress
from spectralize.flows.pipelines import external_inputs, flow_inputs, report_directory, step_parameters
from spectralize.schemas import PipelineError, StoreError
from spectralize.store import SCHEMA_ATTR, RunStore, StoreLock

from .dask_setup import INNER_THREADS, MALLOC_ARENAS, bound_malloc_arenas, dask_scheduler
from .memory import process_peak_bytes
from .prefect_server import embedded_server_dies_with_us, mark_crashed
from .repair import (
    REPORT_GROUPS,
    REPORT_VERIFY_BYTES,
    RecomputeBeforeReport,
    checksum_error_of,
    damaged_groups,
    groups_made_by,
    repair_chunk,
    verify_deep,
    verify_report_groups,
)
from .result_checks import report_warnings, step_warnings
from .run_log import info_logger, warn
from .signals import sigterm_as_interrupt
from .steps import RunReport, StepReport, expected_outputs, output_fingerprint, run_node

__all__ = [
    "StepReport",
    "RunReport",
    "run_steps",
    "plan",
    "write_report_task",
    # defined in .steps, .dask_setup, .repair and .pipelines, importable from here too (the
    # benchmarks import them from here, from this checkout and from older ones alike)
    "run_node",
    "output_fingerprint",
    "dask_scheduler",
    "bound_malloc_arenas",
    "MALLOC_ARENAS",
    "INNER_THREADS",
    "REPORT_GROUPS",
    "REPORT_VERIFY_BYTES",
    "flow_inputs",
    "external_inputs",
    "report_directory",
    "step_parameters",
]


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
    strict: bool = False,
) -> RunReport:
    """Run ``steps`` against the store at ``store_path`` as one Prefect flow run.

    The graph is checked first; every problem (plus ``problems`` found earlier, such as
    unknown ``--set`` keys) is raised at once in a :class:`~spectralize.schemas.PipelineError`
    and nothing is written. A store that does not exist yet is created only when the graph's
    first steps need no input groups; otherwise the missing store is the error.

    The store's lock is held for the whole run (a second writer gets
    :class:`~spectralize.store.StoreBusyError`). When every step is up to date the answer
    comes without starting Prefect. ``verify``: recompute the checksums of every group the
    flow reads or writes first (:mod:`.repair`). ``dask_address``: an existing
    ``dask.distributed`` scheduler (default: ``$DASK_SCHEDULER_ADDRESS``, else local threads;
    its workers must reach the store at the same path). SIGTERM is handled like Ctrl-C.
    The calibration nodes' results are checked after their steps (:mod:`.result_checks`):
    their warnings go to the log; ``strict`` makes them an error (a
    :class:`~spectralize.schemas.CalibrationError`) before the next step runs.
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
            strict,
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
    strict: bool = False,
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
            mark_crashed(lock.previous, path)
        if verify:
            verify_deep(store, planned, print)
        try:
            up_to_date = _up_to_date_report(store, flow_name, planned, report, strict)
        except Exception as error:  # the report read a damaged chunk: repair, then run
            found = checksum_error_of(error)
            if found is None:
                raise
            repair_chunk(store, found, groups_made_by(planned), set())
            up_to_date = None
        if up_to_date is not None:
            return up_to_date
        embedded_server_dies_with_us()
        return _graph_flow(
            str(path),
            flow_name,
            [_as_dict(item.step) for item in planned],
            retries,
            retry_delay_seconds,
            dask_address,
            report,
            strict,
        )


def _require_store_or_first_steps_without_inputs(path: Path, steps: Sequence[Step], flow: str) -> None:
    needs = external_inputs(steps)
    if needs:
        raise StoreError(
            f"run store {str(path)!r} does not exist (the {flow!r} flow reads "
            f"{', '.join(needs)} from it); check the path, or make the store first"
        )


def _up_to_date_report(
    store: RunStore,
    flow_name: str,
    planned: Sequence[PlannedStep],
    report: bool,
    strict: bool = False,
) -> RunReport | None:
    """The run's report if every step is up to date and passes the cheap check, else ``None``
    (the calibration results' warnings printed, an error with ``strict``)."""
    fingerprints: dict[str, str] = {}
    run_report = RunReport(str(store.path), flow_name)
    for item in planned:
        input_fps = {}
        for group in item.inputs.values():
            fp = fingerprints.get(group) or store.fingerprint(group)
            if fp is None:
                return None
            input_fps[group] = fp
        expected = expected_outputs(
            item.node.name, item.parameters.model_dump(mode="json"), item.outputs, input_fps
        )
        if any(store.fingerprint(group) != fp for group, fp in expected.items()):
            return None
        if damaged_groups(store, [*item.inputs.values(), *expected]):
            return None
        fingerprints.update(expected)
        run_report.steps.append(StepReport(item.node.name, "skipped", 0.0, expected))
    for item in planned:
        report_warnings(
            step_warnings(store, item.node.name, item.inputs, item.outputs.values()),
            warn,
            strict=strict,
        )
    if report:
        if not verify_report_groups(store, groups_made_by(planned), set()):
            return None  # a damaged group was marked: the flow recomputes it, then reports
        run_report.report = write_report_task.fn(str(store.path))
    return run_report


@task(name="report", cache_policy=NO_CACHE, persist_result=False)
def write_report_task(store_path: str) -> str | None:
    """Write the HTML report of a processed run (skip if current).

    A run with ground truth is reported once its ``evaluation`` is finished; a real run
    (no truth) once its ``spectra`` or at least its calibration is. The report is rewritten
    when the fingerprint of the group it depends on changes.
    """
    from spectralize.flows.report import write_run_report

    log = info_logger()
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
    strict: bool = False,
) -> RunReport:
    from prefect.runtime import flow_run

    StoreLock(store_path).note(flow_run_id=str(flow_run.id))
    planned = plan(store_path, [Step(**s) for s in steps], create=False)
    store = RunStore.open(store_path)
    made, marked = groups_made_by(planned), set[str]()
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
                strict,
            )
            if earlier is not None:  # what ran in the pass stopped before the report counts
                result.steps = [
                    first if first.status == "ran" and step.status == "skipped" else step
                    for first, step in zip(earlier.steps, result.steps, strict=True)
                ]
            return result
        except RecomputeBeforeReport as stopped:
            checked_report, earlier = True, stopped.args[0]  # once: the next pass rewrites it
        except Exception as error:
            found = checksum_error_of(error)
            if found is None:
                raise
            repair_chunk(store, found, made, marked)


def _run_planned(
    store: RunStore,
    flow_name: str,
    planned: Sequence[PlannedStep],
    retries: int,
    retry_delay_seconds: float,
    dask_address: str | None,
    check_report: bool,
    report: bool,
    strict: bool = False,
) -> RunReport:
    """The steps of a flow run in order (up-to-date ones skipped), then its report.

    ``check_report``: check the report's groups this run did not write deeply first
    (:func:`verify_report_groups`); damage found there raises :class:`RecomputeBeforeReport`.
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
        report_warnings(
            step_warnings(store, item.node.name, item.inputs, step_report.outputs),
            log.warning,
            strict=strict,
        )
    ran = sum(s.status == "ran" for s in run_report.steps)
    log.info(f"{flow_name}: {ran} node(s) ran, {len(run_report.steps) - ran} skipped")
    if check_report:
        fresh = {g for step in run_report.steps if step.status == "ran" for g in step.outputs}
        if not verify_report_groups(store, groups_made_by(planned), fresh):
            raise RecomputeBeforeReport(run_report)
    if report:
        progress.notify("step_started", len(planned) + 1, len(planned) + 1, "report")
        start = time.perf_counter()
        run_report.report = write_report_task(store_path)
        progress.notify("step_finished", "report", "ran", time.perf_counter() - start)
    peak = process_peak_bytes()
    run_report.peak_rss_gb = None if peak is None else round(peak / 1e9, 3)
    return run_report
