"""Prefect runtime: a flow runs a checked node graph against a run store.

Each node run is one Prefect task. Tasks exchange store paths and fingerprints, never
arrays. Resuming is the store's job, not Prefect's cache: a task whose output groups already
carry the fingerprint it would write is skipped, and a changed parameter or input changes
that fingerprint, so the node and everything downstream run again. This survives hard kills
(the fingerprints live in the store) and node code changes (the node version is part of the
fingerprint).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from prefect import flow, get_run_logger, task
from prefect.cache_policies import NO_CACHE

from spectralize.engine import PlannedStep, Step, check_graph, registry
from spectralize.schemas import PipelineError, RunStore, StoreError, compute_fingerprint
from spectralize.schemas.store import SCHEMA_ATTR

__all__ = ["StepReport", "RunReport", "run_steps", "output_fingerprint"]


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


@dataclass
class RunReport:
    """What a flow run did, step by step."""

    store: str
    flow: str
    steps: list[StepReport] = field(default_factory=list)
    report: str | None = None  # path of the HTML report, when one was written

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@contextlib.contextmanager
def dask_scheduler(address: str | None) -> Iterator[int]:
    """Local threads by default; an existing ``dask.distributed`` cluster when given its address.

    Yields how many regions (image sets) to compute at the same time: the number of worker
    threads of the cluster, or of this machine's cores.
    """
    if not address:
        yield max(1, os.cpu_count() or 1)
        return
    from distributed import Client

    with Client(address, set_as_default=True) as client:
        yield max(1, sum(client.nthreads().values()))


def _log() -> Callable[[str], None]:
    try:
        logger = get_run_logger()
    except Exception:  # called outside a Prefect run (plain .fn() call)
        return print
    return logger.info


@task(name="node", cache_policy=NO_CACHE, persist_result=False)
def run_node(
    store_path: str,
    node_name: str,
    parameters: dict[str, Any],
    inputs: dict[str, str],
    outputs: dict[str, str],
    input_fingerprints: dict[str, str],
    dask_address: str | None = None,
) -> StepReport:
    """Run one node against the store, or skip it when its outputs are up to date.

    Parameters are plain JSON values and group names; the data stays in the store. The
    parameters were validated by the graph check (``plan``) before the flow started; calling
    the node checks each input group against the schema the node declares for it (structure
    only, nothing is computed) before the node's function runs.
    """
    log = _log()
    node = registry()[node_name].node
    params = node.parse_parameters(parameters)
    run_fp = compute_fingerprint(
        node.name, node.version, params.model_dump(mode="json"), input_fingerprints
    )
    expected = {group: output_fingerprint(run_fp, group) for group in outputs.values()}
    store = RunStore.open(store_path)
    if all(store.fingerprint(group) == fp for group, fp in expected.items()):
        log(f"{node.name}: skipped, {', '.join(expected)} already up to date")
        return StepReport(node.name, "skipped", 0.0, expected)

    start = time.perf_counter()
    log(f"{node.name}: reading {', '.join(sorted(inputs.values())) or 'no inputs'}")
    with dask_scheduler(dask_address) as parallel:
        data = {argument: store.read(group) for argument, group in inputs.items()}
        results = node(data, params)
        for schema, ds in results.items():
            group = outputs[schema]
            log(f"{node.name}: writing {group}")
            provenance = {
                "node": node.name,
                "version": node.version,
                "parameters": params.model_dump(mode="json"),
                "inputs": dict(input_fingerprints),
            }
            store.write(
                group,
                ds,
                schema=schema if _known(schema) else None,
                fingerprint=expected[group],
                provenance=provenance,
                chunks=node.chunks.get(schema),
                resumable_along=node.resumable_along.get(schema),
                concurrent_regions=parallel,
                progress=lambda message, g=group: log(f"{node.name}: {g}: {message}"),
            )
    seconds = time.perf_counter() - start
    log(f"{node.name}: done in {seconds:.1f} s")
    return StepReport(node.name, "ran", seconds, expected)


def _known(schema: str) -> bool:
    from spectralize.schemas import GROUP_SCHEMAS

    return schema in GROUP_SCHEMAS


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
) -> RunReport:
    """Run ``steps`` against the store at ``store_path`` as one Prefect flow run.

    The graph is checked first; every problem (plus ``problems`` found earlier, such as
    unknown ``--set`` keys) is raised at once in a :class:`~spectralize.schemas.PipelineError`
    and nothing is written. A store that does not
    exist yet is created only when the graph's first steps need no input groups.
    """
    path = Path(store_path).absolute()
    try:
        planned = plan(path, steps, create=True)
    except PipelineError as error:
        found = [*problems, *error.problems]
        raise PipelineError(f"the node graph cannot run ({len(found)} problem(s)):", found) from None
    if problems:
        raise PipelineError(f"the node graph cannot run ({len(problems)} problem(s)):", problems)
    if not path.exists():
        if any(item.inputs for item in planned[:1]):
            raise StoreError(f"{str(path)!r} is not a run store: no such directory")
        RunStore.create(path)
    return _graph_flow(
        str(path),
        flow_name,
        [_as_dict(item.step) for item in planned],
        retries,
        retry_delay_seconds,
        dask_address,
        report,
    )


def report_directory(store_path: str | Path) -> Path:
    """Where the HTML report of a run store goes: ``<folder>/<store name>-report/``."""
    path = Path(store_path)
    return path.parent / f"{path.stem}-report"


@task(name="report", cache_policy=NO_CACHE, persist_result=False)
def write_report_task(store_path: str) -> str | None:
    """Write the HTML report of a run whose ``evaluation`` is finished (skip if current)."""
    from spectralize.flows.report import write_run_report

    log = _log()
    store = RunStore.open(store_path)
    if not store.has("evaluation"):
        log("report: no evaluation group (no ground truth?), no report written")
        return None
    directory = report_directory(store_path)
    stamp = directory / ".evaluation-fingerprint"
    index = directory / "index.html"
    fingerprint = store.fingerprint("evaluation")
    if index.exists() and stamp.exists() and stamp.read_text() == fingerprint:
        log(f"report: up to date at {index}")
        return str(index)
    start = time.perf_counter()
    path = write_run_report(store, directory=directory)
    stamp.write_text(str(fingerprint))
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
    log = get_run_logger()
    planned = plan(store_path, [Step(**s) for s in steps], create=False)
    store = RunStore.open(store_path)
    run_report = RunReport(store_path, flow_name)
    fingerprints: dict[str, str] = {}
    for index, item in enumerate(planned, start=1):
        log.info(f"[{index}/{len(planned)}] {item.node.name}")
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
        )
        fingerprints.update(step_report.outputs)
        run_report.steps.append(step_report)
    ran = sum(s.status == "ran" for s in run_report.steps)
    log.info(f"{flow_name}: {ran} node(s) ran, {len(run_report.steps) - ran} skipped")
    if report:
        run_report.report = write_report_task(store_path)
    return run_report


def step_parameters(
    steps: Sequence[Step],
    assignments: Mapping[str, Any],
    *,
    problems: list | None = None,
) -> list[Step]:
    """Apply ``--set`` style assignments to the steps of a flow.

    Keys are ``node.parameter`` or a bare ``parameter`` that exactly one step's node has.
    Unknown keys raise :class:`~spectralize.schemas.ParameterError` listing what is known,
    unless a ``problems`` list is given: then they are appended to it and the known keys are
    still applied (so a caller can report them together with the graph's problems).
    """
    collect = problems is not None
    from spectralize.schemas import ParameterError, Problem

    nodes = registry()
    steps = list(steps)
    updates: list[dict[str, Any]] = [dict(s.parameters) for s in steps]
    problems = problems if problems is not None else []
    for key, value in assignments.items():
        node_name, _, parameter = key.rpartition(".")
        matches = []
        for i, step in enumerate(steps):
            node = nodes[step.node].node if step.node in nodes else None
            fields = node.parameters.model_fields if node is not None else {}
            if (not node_name or node_name == step.node) and parameter in fields:
                matches.append(i)
        if len(matches) == 1:
            updates[matches[0]][parameter] = value
            continue
        known = sorted(
            f"{s.node}.{p}"
            for s in steps
            if s.node in nodes
            for p in nodes[s.node].node.parameters.model_fields
        )
        if not matches:
            problems.append(
                Problem(f"--set {key}", f"one of: {', '.join(known) or 'none'}", "an unknown parameter")
            )
        else:
            names = ", ".join(steps[i].node for i in matches)
            problems.append(
                Problem(
                    f"--set {key}",
                    "a parameter of exactly one node",
                    f"a parameter of nodes {names}; write NODE.{parameter}",
                )
            )
    if problems and not collect:
        raise ParameterError("invalid --set:", problems)
    return [dataclasses.replace(s, parameters=u) for s, u in zip(steps, updates, strict=True)]
