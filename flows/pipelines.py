"""The named flows a user runs with ``spectralize run FLOW STORE``.

A flow is a list of steps; the engine orders and checks them. Keep them declarative.
Nothing here imports Prefect (that is :mod:`.runtime`'s job, when a flow runs), so the
command line lists, checks and parametrises flows without paying for it. The flows' names
and descriptions (:data:`FLOW_DESCRIPTIONS`) do not even need the node engine: ``spectralize
run --help`` lists them at once; :data:`FLOWS` and :data:`BTF_STEPS` are built from the
engine's :class:`~spectralize.engine.Step` on first use.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from spectralize.engine import Step

__all__ = [
    "FlowDefinition",
    "FLOWS",
    "FLOW_DESCRIPTIONS",
    "BTF_STEPS",
    "get_flow",
    "step_parameters",
    "flow_inputs",
    "external_inputs",
    "report_directory",
]


@dataclass(frozen=True)
class FlowDefinition:
    """A named graph of node steps."""

    name: str
    description: str
    steps: tuple[Step, ...]
    report: bool = False  # write the HTML report when the run has an evaluation


#: name -> what the flow does, for ``spectralize flows`` and ``spectralize run --help``
FLOW_DESCRIPTIONS: dict[str, str] = {
    "dark": "dark-frame averaging: raw/dark -> dark",
    "calibrate": "radiometric calibration (sec. 4): dark -> OECFs -> QE, C and cross-validation",
    "btf": "full-BTF processing of a raw run store",
    "demo": "simulate the bundled sample run (recipe 'demo'), then process it",
}


def _btf_steps() -> tuple[Step, ...]:
    """The full-BTF processing of a raw run store, in paper order."""
    from spectralize.engine import Step

    return (
        Step("dark_average"),
        Step("recover_rgb_oecf"),
        Step("recover_spectral_oecf"),
        Step("calibrate_spectral"),
        Step("hdr_merge"),
        Step("estimate_registration"),
        Step("calibrate_bands"),
        Step("select_image_sets"),
        Step("endmember_library", inputs={"calibration": "calibration/spectral"}),
        Step("reconstruct_seed_set", inputs={"calibration": "calibration/spectral"}),
        Step("reconstruct_image_sets", inputs={"calibration": "calibration/spectral"}),
        # simulated runs only: evaluation against ground truth (left out without truth/spectra)
        Step("evaluate", optional=True),
    )


def _flows() -> dict[str, FlowDefinition]:
    from spectralize.engine import Step

    btf = _btf_steps()
    steps: dict[str, tuple[tuple[Step, ...], bool]] = {  # name -> (steps, write the report)
        "dark": ((Step("dark_average"),), False),
        "calibrate": (
            (
                Step("dark_average"),
                Step("recover_rgb_oecf"),
                Step("recover_spectral_oecf"),
                Step("calibrate_spectral"),
            ),
            False,
        ),
        "btf": (btf, True),
        "demo": ((Step("simulate", parameters={"recipe": "demo"}), *btf), True),
    }
    return {
        name: FlowDefinition(name, FLOW_DESCRIPTIONS[name], flow_steps, report)
        for name, (flow_steps, report) in steps.items()
    }


_LAZY = {"FLOWS": _flows, "BTF_STEPS": _btf_steps}
if TYPE_CHECKING:
    FLOWS: dict[str, FlowDefinition]
    BTF_STEPS: tuple[Step, ...]


def __getattr__(name: str) -> Any:
    """``FLOWS`` (name -> :class:`FlowDefinition`) and ``BTF_STEPS``, built on first use."""
    if name in _LAZY:
        globals()[name] = _LAZY[name]()
        return globals()[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def get_flow(name: str) -> FlowDefinition:
    """The flow called ``name``, or a one-step flow running the installed node ``name``.

    Raises
    ------
    SpectralizeError
        Listing the known flows and nodes.
    """
    from spectralize.engine import Step, registry
    from spectralize.schemas import SpectralizeError

    flows: dict[str, FlowDefinition] = globals().get("FLOWS") or __getattr__("FLOWS")
    if name in flows:
        return flows[name]
    nodes = registry()
    if name in nodes:
        return FlowDefinition(name, f"the single node {name}", (Step(name),))
    raise SpectralizeError(
        f"unknown flow or node {name!r}; flows: {', '.join(sorted(flows))}; "
        f"nodes: {', '.join(sorted(nodes)) or 'none'}"
    )


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
    from spectralize.engine import registry
    from spectralize.schemas import ParameterError, Problem

    collect = problems is not None
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


def flow_inputs(flow: str) -> list[str]:
    """The groups the named flow reads but none of its steps makes (its raw inputs)."""
    return external_inputs(get_flow(flow).steps)


def external_inputs(steps: Sequence[Step]) -> list[str]:
    """The groups ``steps`` read (optional steps aside) that none of them makes."""
    from spectralize.engine import registry

    nodes = registry()
    return sorted(
        {
            group
            for step in steps
            if step.node in nodes and not step.optional
            for group in step.input_groups(nodes[step.node].node).values()
        }
        - {
            group
            for step in steps
            if step.node in nodes
            for group in step.output_groups(nodes[step.node].node).values()
        }
    )


def report_directory(store_path: str | Path) -> Path:
    """Where the HTML report of a run store goes: ``<folder>/<store name>-report/``."""
    path = Path(store_path)
    return path.parent / f"{path.stem}-report"
