"""The named flows a user runs with ``spectralize run FLOW STORE``.

A flow is a list of steps; the engine orders and checks them. Keep them declarative.
"""

from __future__ import annotations

from dataclasses import dataclass

from spectralize.nodes.engine import Step
from spectralize.schemas import SpectralizeError

__all__ = ["FlowDefinition", "FLOWS", "get_flow"]


@dataclass(frozen=True)
class FlowDefinition:
    """A named graph of node steps."""

    name: str
    description: str
    steps: tuple[Step, ...]


FLOWS: dict[str, FlowDefinition] = {
    flow.name: flow
    for flow in (
        FlowDefinition(
            name="dark",
            description="dark-frame averaging: raw/dark -> dark",
            steps=(Step("dark_average"),),
        ),
    )
}


def get_flow(name: str) -> FlowDefinition:
    """The flow called ``name``, or a one-step flow running the installed node ``name``.

    Raises
    ------
    SpectralizeError
        Listing the known flows and nodes.
    """
    from spectralize.nodes.engine import registry

    if name in FLOWS:
        return FLOWS[name]
    nodes = registry()
    if name in nodes:
        return FlowDefinition(name, f"the single node {name}", (Step(name),))
    raise SpectralizeError(f"unknown flow or node {name!r}; flows: {', '.join(sorted(FLOWS))}; "
                           f"nodes: {', '.join(sorted(nodes)) or 'none'}")
