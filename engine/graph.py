"""Graphs of node steps: :class:`Step`, :class:`PlannedStep` and :func:`check_graph`.

A graph is checked as a whole before anything runs (parameters, including those whose values
come from a method table; bindings; inputs; producers; schemas; cycles) and every problem is
reported at once. Run order and cycle detection use :class:`graphlib.TopologicalSorter`.
:func:`value_refusals` runs the value checks of a checked graph's nodes on the groups a store
already has (what ``spectralize validate --flow`` reports).
"""

from __future__ import annotations

import graphlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import xarray as xr

from spectralize.schemas import GROUP_SCHEMAS, ParameterError, PipelineError, Problem, SpectralizeError

from .discovery import registry
from .node import Node, Parameters

__all__ = ["Step", "PlannedStep", "check_graph", "value_refusals"]


@dataclass(frozen=True)
class Step:
    """One node run in a graph: which node, its parameters, and where it reads and writes.

    ``inputs`` and ``outputs`` rebind groups (argument or schema name -> group path); by
    default a node reads and writes the groups named like its schemas. An ``optional`` step
    (e.g. evaluation against ground truth, which only simulated runs have) is left out of
    the graph when one of its inputs is not there, instead of being an error.
    """

    node: str
    parameters: Mapping[str, Any] = field(default_factory=dict)
    inputs: Mapping[str, str] = field(default_factory=dict)
    outputs: Mapping[str, str] = field(default_factory=dict)
    optional: bool = False

    def input_groups(self, node: Node) -> dict[str, str]:
        return {arg: self.inputs.get(arg, schema) for arg, schema in node.inputs.items()}

    def output_groups(self, node: Node) -> dict[str, str]:
        return {schema: self.outputs.get(schema, schema) for schema in node.outputs}


@dataclass(frozen=True)
class PlannedStep:
    """A checked step: its node, parsed parameters and resolved groups."""

    step: Step
    node: Node
    parameters: Parameters
    inputs: dict[str, str]  # argument -> group
    outputs: dict[str, str]  # schema -> group


def _provides(have: str, wanted: str) -> bool:
    """Whether a group of schema ``have`` can be read where schema ``wanted`` is expected."""
    if have == wanted or wanted not in GROUP_SCHEMAS:
        return True
    if have not in GROUP_SCHEMAS:
        return False
    return GROUP_SCHEMAS[have].provides(GROUP_SCHEMAS[wanted])


def check_graph(
    steps: Iterable[Step],
    *,
    available: Mapping[str, str | None] | None = None,
    nodes: Mapping[str, Node] | None = None,
) -> list[PlannedStep]:
    """Check a node graph before anything runs and return its steps in run order.

    Parameters
    ----------
    steps
        The graph's steps.
    available
        Groups already in the store: group -> schema name (or ``None`` if unknown).
    nodes
        Node lookup (default: the installed registry).

    Returns
    -------
    list of PlannedStep
        In an order where every step comes after the producers of its inputs; steps that
        do not depend on each other keep the order they were given in.

    Raises
    ------
    PipelineError
        With every problem at once: unknown nodes, invalid parameters (a value not in its
        method table lists the allowed ones), missing inputs, duplicate outputs, cycles,
        schema mismatches.
    """
    available = dict(available or {})
    lookup = nodes if nodes is not None else {n: r.node for n, r in registry().items()}
    problems: list[Problem | str] = []
    planned = _resolve_steps(steps, lookup, problems)
    planned = _without_orphaned_optional_steps(planned, available)
    producer = _producers(planned, problems)
    sorter = _wire_inputs(planned, producer, available, problems)
    order = _run_order(planned, sorter, problems)
    if problems:
        raise PipelineError(f"the node graph cannot run ({len(problems)} problem(s)):", problems)
    return order


def _resolve_steps(
    steps: Iterable[Step], lookup: Mapping[str, Node], problems: list[Problem | str]
) -> list[PlannedStep]:
    """Each step's node, parsed parameters and groups; unknown nodes and bindings are problems.

    A step whose parameters are invalid is still wired (its outputs do not then show up as
    missing downstream); with a problem recorded, :func:`check_graph` returns nothing.
    """
    planned: list[PlannedStep] = []
    for step in steps:
        node = lookup.get(step.node)
        if node is None:
            problems.append(
                Problem(
                    f"step {step.node!r}",
                    f"an installed node ({', '.join(sorted(lookup)) or 'none'})",
                    "an unknown node",
                )
            )
            continue
        try:
            params = node.parse_parameters(step.parameters)
        except ParameterError as error:
            problems.extend(error.problems)
            params = None
        unknown_in = sorted(set(step.inputs) - set(node.inputs))
        unknown_out = sorted(set(step.outputs) - set(node.outputs))
        if unknown_in or unknown_out:
            problems.append(
                Problem(
                    f"step {step.node!r}",
                    f"bindings for inputs {sorted(node.inputs)} / outputs {list(node.outputs)}",
                    f"unknown inputs {unknown_in} / outputs {unknown_out}",
                )
            )
            continue
        planned.append(
            PlannedStep(
                step,
                node,
                params,  # type: ignore[arg-type]
                step.input_groups(node),
                step.output_groups(node),
            )
        )
    return planned


def _without_orphaned_optional_steps(
    planned: list[PlannedStep], available: Mapping[str, str | None]
) -> list[PlannedStep]:
    """Leave out optional steps whose inputs can never be there.

    Repeated until none is left: dropping one may orphan another optional step downstream of it.
    """
    while True:
        made = set(available) | {g for item in planned for g in item.outputs.values()}
        orphans = [
            item for item in planned if item.step.optional and not set(item.inputs.values()) <= made
        ]
        if not orphans:
            return planned
        planned = [item for item in planned if item not in orphans]


def _producers(planned: Sequence[PlannedStep], problems: list[Problem | str]) -> dict[str, int]:
    """Group -> index of the step that writes it; a group written by two steps is a problem."""
    producer: dict[str, int] = {}
    for index, item in enumerate(planned):
        for group in item.outputs.values():
            if group in producer:
                problems.append(
                    Problem(
                        f"group {group!r}",
                        "one producing node",
                        f"nodes {planned[producer[group]].node.name!r} and "
                        f"{item.node.name!r} both write it",
                    )
                )
            else:
                producer[group] = index
    return producer


def _wire_inputs(
    planned: Sequence[PlannedStep],
    producer: Mapping[str, int],
    available: Mapping[str, str | None],
    problems: list[Problem | str],
) -> graphlib.TopologicalSorter[int]:
    """Each step after the producers of its inputs; a missing input or one of another schema
    (written by an earlier step, or in the store) is a problem."""
    sorter: graphlib.TopologicalSorter[int] = graphlib.TopologicalSorter()
    for index, item in enumerate(planned):
        sorter.add(index)
        for argument, group in item.inputs.items():
            wanted = item.node.inputs[argument]
            where = f"node {item.node.name!r} input {argument!r} (group {group!r})"
            if group in producer:
                source = planned[producer[group]]
                sorter.add(index, producer[group])
                made_schema = next(s for s, g in source.outputs.items() if g == group)
                if not _provides(made_schema, wanted):
                    found = f"schema {made_schema!r} written by node {source.node.name!r}"
                    problems.append(Problem(where, f"schema {wanted!r}", found))
            elif group in available:
                have = available[group]
                if have is not None and not _provides(have, wanted):
                    problems.append(
                        Problem(where, f"schema {wanted!r}", f"schema {have!r} in the store")
                    )
            else:
                problems.append(
                    Problem(
                        f"node {item.node.name!r} input {argument!r}",
                        f"group {group!r} in the store or written by an earlier node",
                        "no such group",
                    )
                )
    return sorter


def _run_order(
    planned: Sequence[PlannedStep],
    sorter: graphlib.TopologicalSorter[int],
    problems: list[Problem | str],
) -> list[PlannedStep]:
    """The steps in run order, the given order kept among independent ones; a cycle is a problem."""
    order: list[PlannedStep] = []
    try:
        sorter.prepare()
    except graphlib.CycleError as error:
        cycle = " -> ".join(planned[i].node.name for i in error.args[1])
        problems.append(Problem("graph", "no cycles", f"a cycle among nodes {cycle}"))
    else:
        while sorter.is_active():
            ready = sorted(sorter.get_ready())  # keep the given order among independent steps
            order.extend(planned[i] for i in ready)
            sorter.done(*ready)
    return order


def value_refusals(
    planned: Sequence[PlannedStep], read: Callable[[str], xr.Dataset | None]
) -> list[tuple[PlannedStep, SpectralizeError]]:
    """What the value checks of a graph's nodes refuse in the groups that exist already.

    Each step's :meth:`Node.refusals` gets the input groups ``read`` returns (``None``: the
    group is not there yet, an earlier step makes it) and the step's parameters: the checks
    the node makes before computing, so the graph would stop there. A group refused for one
    step is not checked again for the later steps that read it (the same rule would be
    reported twice). Each group is read once.
    """
    groups: dict[str, xr.Dataset | None] = {}
    refused: set[str] = set()
    found: list[tuple[PlannedStep, SpectralizeError]] = []
    for item in planned:
        if item.node.check is None or refused & set(item.inputs.values()):
            continue
        inputs = {}
        for argument, group in item.inputs.items():
            if group not in groups:
                groups[group] = read(group)
            data = groups[group]
            if data is not None:
                inputs[argument] = data
        if not inputs:
            continue
        errors = item.node.refusals(inputs, item.parameters)
        if errors:
            refused.update(group for group in item.inputs.values() if groups[group] is not None)
            found += [(item, error) for error in errors]
    return found
