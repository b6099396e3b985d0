"""Node discovery: the entry point group ``spectralize.nodes`` and the installed registry.

The built-in nodes register through the project's own ``pyproject.toml`` exactly as a
third-party plugin would. A plugin that fails to load gives a warning, never an error.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points

from spectralize.schemas import NodeNotFoundError

from .node import Node

__all__ = ["ENTRY_POINT_GROUP", "RegisteredNode", "discover_nodes", "registry", "get_node"]

ENTRY_POINT_GROUP = "spectralize.nodes"


@dataclass(frozen=True)
class RegisteredNode:
    """An installed node and where it came from."""

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
            warnings.warn(
                f"spectralize node plugin {ep.name!r} ({ep.value}) failed to load: "
                f"{type(error).__name__}: {error}",
                RuntimeWarning,
                stacklevel=2,
            )
            continue
        if not isinstance(obj, Node):
            warnings.warn(
                f"spectralize node plugin {ep.name!r} ({ep.value}) is a "
                f"{type(obj).__name__}, not a spectralize Node; ignored",
                RuntimeWarning,
                stacklevel=2,
            )
            continue
        dist = getattr(ep, "dist", None)
        origin = f" ({dist.name} {dist.version})" if dist is not None else ""
        source = f"entry point {ENTRY_POINT_GROUP}: {ep.name} = {ep.value}{origin}"
        if obj.name in found:
            warnings.warn(
                f"node {obj.name!r} from {source} duplicates the one from "
                f"{found[obj.name].source}; keeping the first",
                RuntimeWarning,
                stacklevel=2,
            )
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
