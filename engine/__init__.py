"""spectralize.engine: node declarations, the node registry and the graph check.

Between the data contracts (:mod:`spectralize.schemas`) and the science
(:mod:`spectralize.nodes`): nodes declare what they read, write and take; the engine checks a
graph of them before anything runs, and each node's inputs against their schemas before the
node runs. Nothing here imports Prefect.

==================  ==========================================================================
``node.py``         :class:`Node`, :class:`Parameters`, :class:`Choices`: a declaration, its
                    parameters derived from the function's signature, input checks
``discovery.py``    entry point group ``spectralize.nodes``: :func:`registry`, :func:`get_node`
``graph.py``        :class:`Step`, :func:`check_graph` (run order and cycles by ``graphlib``)
``progress.py``     :func:`progress.task`: nodes report long work (a solver run) to whoever
                    listens (:func:`progress.listening`; the command line's bars), else nothing
==================  ==========================================================================

Declaring a node
----------------
The keyword-only arguments of the node's function are its parameters: types, defaults and
constraints are written once, in the signature, and :class:`Node` derives the frozen,
validated parameter model from it (unknown keys are an error). A parameter whose values are
the keys of a method table takes them from the table with :class:`Choices`, so a typo fails
in :func:`check_graph`, before anything runs, with the allowed values listed::

    from typing import Annotated

    import xarray as xr
    from pydantic import Field

    from spectralize.engine import Choices, Node

    SOLVER_METHODS = {"cg": ..., "lsqr": ...}

    def reconstruct(
        bands: xr.Dataset,
        *,
        method: Annotated[str, Choices(SOLVER_METHODS, "solver method")] = "cg",
        alpha_hat: Annotated[float, Field(gt=0, description="eq. 7 weight")] = 1.0,
    ) -> xr.Dataset: ...

    RECONSTRUCT = Node(name="reconstruct", function=reconstruct,
                       inputs={"bands": "bands"}, outputs=("spectra",))

    RECONSTRUCT.parse_parameters({"method": "fastest"})
    # ParameterError: reconstruct.method: expected one of: 'cg', 'lsqr' (solver method),
    #                 found 'fastest'

Inputs (``bands`` above) are not parameters. A description comes from ``Field(description=)``
or else from the first line of the argument's numpydoc entry. An explicit
``parameters=SomeParameters`` model still works (and may use :class:`Choices` too).
"""

from . import progress
from .discovery import ENTRY_POINT_GROUP, RegisteredNode, discover_nodes, get_node, registry
from .graph import PlannedStep, Step, check_graph, value_refusals
from .node import Choices, Node, Parameters, ValueCheck, choices_of, parameters_from_signature

__all__ = [
    "ENTRY_POINT_GROUP",
    "Choices",
    "Node",
    "Parameters",
    "PlannedStep",
    "RegisteredNode",
    "Step",
    "ValueCheck",
    "check_graph",
    "choices_of",
    "discover_nodes",
    "get_node",
    "parameters_from_signature",
    "progress",
    "registry",
    "value_refusals",
]
