"""The node engine: declarations, parameters, plugin discovery and graph checking.

A node is a pure, fully typed function plus a :class:`Node` declaration. Nodes are found
through the entry point group ``spectralize.nodes``; the built-in ones register through the
project's own ``pyproject.toml`` exactly as a third-party plugin would. Nothing here knows
about Prefect: every node runs as a plain function in a notebook.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import xarray as xr
from pydantic import BaseModel, ConfigDict, ValidationError

from spectralize.schemas import (
    GROUP_SCHEMAS,
    NodeNotFoundError,
    ParameterError,
    PipelineError,
    Problem,
    SpectralizeError,
)

__all__ = [
    "ENTRY_POINT_GROUP",
    "Parameters",
    "Node",
    "Step",
    "registry",
    "get_node",
    "discover_nodes",
    "check_graph",
]

ENTRY_POINT_GROUP = "spectralize.nodes"


class Parameters(BaseModel):
    """Base of every node's parameter model: frozen, typed, unknown keys are an error."""

    model_config = ConfigDict(frozen=True, extra="forbid")


@dataclass(frozen=True)
class Node:
    """Declaration of one node.

    Attributes
    ----------
    name
        Unique node name (``"dark_average"``).
    function
        Pure function: ``function(**inputs, **parameters) -> Dataset | {group: Dataset}``.
        Its input arguments receive lazy :class:`xarray.Dataset` objects.
    inputs
        Function argument -> schema name of the group it reads (also the default group).
    outputs
        Schema names of the groups it writes (also the default group names).
    parameters
        Parameter model (subclass of :class:`Parameters`); each field is a keyword of
        ``function``.
    version
        Bump it when the results change: it is part of every output's fingerprint.
    description
        One line for ``spectralize nodes``.
    chunks
        Output group -> chunk size per dim on disk.
    resumable_along
        Output group -> dim along which it is written region by region (resumable).
    """

    name: str
    function: Callable[..., Any]
    inputs: Mapping[str, str]
    outputs: tuple[str, ...]
    parameters: type[Parameters] = Parameters
    version: str = "1"
    description: str = ""
    chunks: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    resumable_along: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        problems = []
        try:
            signature = inspect.signature(self.function)
        except (TypeError, ValueError):
            signature = None
        if signature is not None:
            accepts_any = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
            names = set(signature.parameters)
            for argument in self.inputs:
                if argument not in names and not accepts_any:
                    problems.append(f"input {argument!r} is not an argument of "
                                    f"{self.function.__qualname__}")
            for argument in self.parameters.model_fields:
                if argument not in names and not accepts_any:
                    problems.append(f"parameter {argument!r} is not a keyword of "
                                    f"{self.function.__qualname__}")
        if not self.outputs:
            problems.append("it declares no outputs")
        for group in list(self.chunks) + list(self.resumable_along):
            if group not in self.outputs:
                problems.append(f"chunks/resumable_along name {group!r}, which is not an output")
        if problems:
            raise SpectralizeError(f"node {self.name!r} is declared wrongly: " + "; ".join(problems))

    def parse_parameters(self, values: Mapping[str, Any] | Parameters | None = None) -> Parameters:
        """Validate ``values`` into this node's frozen parameter model.

        Raises
        ------
        ParameterError
            Listing every unknown key (with the known ones) and every invalid value.
        """
        if isinstance(values, self.parameters):
            return values
        values = dict(values or {})
        try:
            return self.parameters(**values)
        except ValidationError as error:
            known = ", ".join(self.parameters.model_fields) or "none"
            problems = []
            for item in error.errors():
                key = ".".join(str(p) for p in item["loc"]) or "?"
                if item["type"] == "extra_forbidden":
                    problems.append(Problem(f"{self.name}.{key}", f"one of: {known}",
                                            "an unknown parameter"))
                else:
                    problems.append(Problem(f"{self.name}.{key}", item["msg"],
                                            repr(item.get("input"))))
            raise ParameterError(f"invalid parameters for node {self.name!r}:", problems) from None

    def __call__(self, inputs: Mapping[str, xr.Dataset] | None = None,
                 parameters: Mapping[str, Any] | Parameters | None = None) -> dict[str, xr.Dataset]:
        """Run the node's function and return ``{output schema name: Dataset}``."""
        params = self.parse_parameters(parameters)
        inputs = dict(inputs or {})
        missing = sorted(set(self.inputs) - set(inputs))
        if missing:
            raise SpectralizeError(f"node {self.name!r} needs inputs {missing}")
        result = self.function(**inputs, **params.model_dump())
        if isinstance(result, xr.Dataset):
            if len(self.outputs) != 1:
                raise SpectralizeError(
                    f"node {self.name!r} returned one Dataset but declares outputs {self.outputs}"
                )
            return {self.outputs[0]: result}
        if not isinstance(result, Mapping) or set(result) != set(self.outputs):
            found = sorted(result) if isinstance(result, Mapping) else type(result).__name__
            raise SpectralizeError(
                f"node {self.name!r} must return {{group: Dataset}} for {list(self.outputs)}, "
                f"returned {found}"
            )
        return dict(result)

    def describe_parameters(self) -> list[tuple[str, str, Any, str]]:
        """(name, type, default, description) of every parameter."""
        rows = []
        for name, info in self.parameters.model_fields.items():
            annotation = getattr(info.annotation, "__name__", None) or str(info.annotation)
            rows.append((name, annotation, info.get_default(call_default_factory=True),
                         info.description or ""))
        return rows


# -- discovery -----------------------------------------------------------------------------
@dataclass(frozen=True)
class RegisteredNode:
    node: Node
    source: str  # "entry point spectralize.nodes: dark_average = pkg.mod:OBJ (dist x 1.0)"


def discover_nodes(eps: Iterable[EntryPoint] | None = None) -> dict[str, RegisteredNode]:
    """Load every node declared in the entry point group ``spectralize.nodes``.

    A plugin that fails to import, or exports something that is not a :class:`Node`, gives
    a warning and is left out; two plugins with the same node name keep the first.
    """
    if eps is None:
        eps = entry_points(group=ENTRY_POINT_GROUP)
    found: dict[str, RegisteredNode] = {}
    for ep in eps:
        try:
            obj = ep.load()
        except Exception as error:  # a broken plugin must not break the engine
            warnings.warn(f"spectralize node plugin {ep.name!r} ({ep.value}) failed to load: "
                          f"{type(error).__name__}: {error}", RuntimeWarning, stacklevel=2)
            continue
        if not isinstance(obj, Node):
            warnings.warn(f"spectralize node plugin {ep.name!r} ({ep.value}) is a "
                          f"{type(obj).__name__}, not a spectralize Node; ignored",
                          RuntimeWarning, stacklevel=2)
            continue
        dist = getattr(ep, "dist", None)
        origin = f" ({dist.name} {dist.version})" if dist is not None else ""
        source = f"entry point {ENTRY_POINT_GROUP}: {ep.name} = {ep.value}{origin}"
        if obj.name in found:
            warnings.warn(f"node {obj.name!r} from {source} duplicates the one from "
                          f"{found[obj.name].source}; keeping the first", RuntimeWarning,
                          stacklevel=2)
            continue
        found[obj.name] = RegisteredNode(obj, source)
    return found


@lru_cache(maxsize=1)
def _installed() -> dict[str, RegisteredNode]:
    return discover_nodes()


def registry(*, refresh: bool = False) -> dict[str, RegisteredNode]:
    """Every installed node, by name (cached; ``refresh=True`` rescans the entry points)."""
    if refresh:
        _installed.cache_clear()
    return _installed()


def get_node(name: str) -> Node:
    """The installed node called ``name``.

    Raises
    ------
    NodeNotFoundError
        Listing the installed node names.
    """
    nodes = registry()
    if name not in nodes:
        known = ", ".join(sorted(nodes)) or "none"
        raise NodeNotFoundError(f"unknown node {name!r}; installed nodes: {known}")
    return nodes[name].node


# -- graphs --------------------------------------------------------------------------------
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
    step: Step
    node: Node
    parameters: Parameters
    inputs: dict[str, str]    # argument -> group
    outputs: dict[str, str]   # schema -> group


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

    Raises
    ------
    PipelineError
        With every problem at once: unknown nodes, invalid parameters, missing inputs,
        duplicate outputs, cycles, schema mismatches.
    """
    steps = list(steps)
    available = dict(available or {})
    lookup = nodes if nodes is not None else {n: r.node for n, r in registry().items()}
    problems: list[Problem | str] = []
    planned: list[PlannedStep] = []
    for step in steps:
        node = lookup.get(step.node)
        if node is None:
            problems.append(Problem(f"step {step.node!r}",
                                    f"an installed node ({', '.join(sorted(lookup)) or 'none'})",
                                    "an unknown node"))
            continue
        try:
            params = node.parse_parameters(step.parameters)
        except ParameterError as error:
            problems.extend(error.problems)
            continue
        unknown_in = sorted(set(step.inputs) - set(node.inputs))
        unknown_out = sorted(set(step.outputs) - set(node.outputs))
        if unknown_in or unknown_out:
            problems.append(Problem(f"step {step.node!r}",
                                    f"bindings for inputs {sorted(node.inputs)} / outputs "
                                    f"{list(node.outputs)}",
                                    f"unknown inputs {unknown_in} / outputs {unknown_out}"))
            continue
        planned.append(PlannedStep(step, node, params, step.input_groups(node),
                                   step.output_groups(node)))

    # Leave out optional steps whose inputs can never be there (repeat: dropping one may
    # orphan another optional step downstream of it).
    while True:
        made = set(available) | {g for item in planned for g in item.outputs.values()}
        orphans = [item for item in planned if item.step.optional
                   and not set(item.inputs.values()) <= made]
        if not orphans:
            break
        planned = [item for item in planned if item not in orphans]

    producer: dict[str, PlannedStep] = {}
    for item in planned:
        for group in item.outputs.values():
            if group in producer:
                problems.append(Problem(f"group {group!r}", "one producing node",
                                        f"nodes {producer[group].node.name!r} and "
                                        f"{item.node.name!r} both write it"))
            else:
                producer[group] = item

    for item in planned:
        for argument, group in item.inputs.items():
            wanted = item.node.inputs[argument]
            if group in producer:
                made = next(s for s, g in producer[group].outputs.items() if g == group)
                if not _provides(made, wanted):
                    problems.append(Problem(
                        f"node {item.node.name!r} input {argument!r} (group {group!r})",
                        f"schema {wanted!r}",
                        f"schema {made!r} written by node {producer[group].node.name!r}"))
            elif group in available:
                have = available[group]
                if have is not None and not _provides(have, wanted):
                    problems.append(Problem(
                        f"node {item.node.name!r} input {argument!r} (group {group!r})",
                        f"schema {wanted!r}", f"schema {have!r} in the store"))
            else:
                problems.append(Problem(
                    f"node {item.node.name!r} input {argument!r}",
                    f"group {group!r} in the store or written by an earlier node",
                    "no such group"))

    # Topological order (Kahn); what is left over lies on a cycle.
    order: list[PlannedStep] = []
    remaining = list(planned)
    done_groups: set[str] = set()
    while remaining:
        ready = [item for item in remaining
                 if all(g not in producer or g in done_groups for g in item.inputs.values())]
        if not ready:
            names = " -> ".join(item.node.name for item in remaining)
            problems.append(Problem("graph", "no cycles",
                                    f"a cycle among nodes {names}"))
            break
        for item in ready:
            order.append(item)
            remaining.remove(item)
            done_groups.update(item.outputs.values())
    if problems:
        raise PipelineError(f"the node graph cannot run ({len(problems)} problem(s)):", problems)
    return order
