"""spectralize.engine: node declarations, the node registry and the graph check.

Between the data contracts (:mod:`spectralize.schemas`) and the science
(:mod:`spectralize.nodes`): nodes declare what they read, write and take; the engine checks a
graph of them before anything runs. Nothing here imports Prefect.
"""

from .core import (
    ENTRY_POINT_GROUP,
    Node,
    Parameters,
    PlannedStep,
    RegisteredNode,
    Step,
    check_graph,
    discover_nodes,
    get_node,
    registry,
)

__all__ = [
    "ENTRY_POINT_GROUP",
    "Node",
    "Parameters",
    "PlannedStep",
    "RegisteredNode",
    "Step",
    "check_graph",
    "discover_nodes",
    "get_node",
    "registry",
]
