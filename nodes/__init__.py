"""spectralize.nodes: the science, as pure functions plus node declarations.

Nothing here imports Prefect: every function runs as a plain function in a notebook.
"""

from .engine import Node, Parameters, Step, check_graph, discover_nodes, get_node, registry

__all__ = ["Node", "Parameters", "Step", "check_graph", "discover_nodes", "get_node", "registry"]
