"""One step of a flow: a node run against the run store, or skipped when it is up to date.

Each node run is one Prefect task (:func:`run_node`). Tasks exchange store paths and
fingerprints, never arrays. Resuming is the store's job, not Prefect's cache: a task whose
output groups already carry the fingerprint it would write (:func:`expected_outputs`) is
skipped, and a changed parameter or input changes that fingerprint, so the node and everything
downstream run again. This survives hard kills (the fingerprints live in the store) and node
code changes (the node version is part of the fingerprint). Input values are checked against
the contract (NaN/inf, ranges) before a node's numerics start (:func:`check_input_values`).
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

from prefect import task
from prefect.cache_policies import NO_CACHE

from spectralize.engine import registry
from spectralize.flows import progress
from spectralize.schemas import GROUP_SCHEMAS, Problem, SchemaError, validate_values
from spectralize.store import SCHEMA_ATTR, RunStore, compute_fingerprint

from .dask_setup import dask_scheduler
from .memory import PeakMemory, release_free_memory
from .repair import damaged_groups, damaged_input_error
from .run_log import info_logger, warn

__all__ = [
    "StepReport",
    "RunReport",
    "run_node",
    "output_fingerprint",
    "expected_outputs",
    "check_input_values",
]


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


def expected_outputs(
    node_name: str,
    parameters: dict[str, Any],
    outputs: dict[str, str],
    input_fingerprints: dict[str, str],
) -> dict[str, str]:
    """The fingerprint each output group of a node run gets (group -> fingerprint).

    Made from the node's name and version, its parsed parameters and its inputs'
    fingerprints (:func:`~spectralize.store.compute_fingerprint`), then per group
    (:func:`output_fingerprint`): an output that carries it is up to date.
    """
    node = registry()[node_name].node
    params = node.parse_parameters(parameters)
    run_fp = compute_fingerprint(
        node.name, node.version, params.model_dump(mode="json"), input_fingerprints
    )
    return {group: output_fingerprint(run_fp, group) for group in outputs.values()}


_VALUES_CHECKED: dict[tuple[str, str, str], None] = {}  # (store, group, fingerprint) checked


def check_input_values(store: RunStore, node: str, groups: Sequence[str]) -> None:
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
    log = info_logger()
    node = registry()[node_name].node
    params = node.parse_parameters(parameters)
    expected = expected_outputs(node_name, parameters, outputs, input_fingerprints)
    store = RunStore.open(store_path)
    damaged_inputs = damaged_groups(store, list(inputs.values()))
    if damaged_inputs:
        raise damaged_input_error(store, node.name, damaged_inputs)
    reason = rerun_because
    if all(store.fingerprint(group) == fp for group, fp in expected.items()):
        damaged = damaged_groups(store, list(expected))
        if damaged:
            reason = "damaged output " + ", ".join(
                f"{group} ({problems[0]}{f' and {len(problems) - 1} more' if len(problems) > 1 else ''})"
                for group, problems in damaged.items()
            )
            warn(f"{node.name}: recomputing: {reason}")
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
    # carry over (kept, the heap would grow with the images: flows/memory.py)
    release_free_memory()
    with PeakMemory() as measured:
        try:
            check_input_values(store, node.name, list(inputs.values()))
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
            release_free_memory(collect=False)  # (else the heap creeps up region by region)

    return report
