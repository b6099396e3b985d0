"""``spectralize validate --flow F``: the value checks of F's nodes, run on a store.

``validate --flow F`` must not pass a store that ``F`` then rejects. The contract's own value
rules (NaN/inf, ranges) are :meth:`RunStore.validate`'s; what a node refuses beyond them is
its value check (:attr:`spectralize.engine.Node.check`), the hook the node runs before its
function. Here the same hooks run, with the flow's parameters, on the groups the store has
(:func:`spectralize.engine.value_refusals`), so one rule set decides both.

References
----------
Fast Capture of Spectral Image Series, sec. 4 (the exposure series of the calibration).
"""

from __future__ import annotations

from spectralize.schemas import Problem, SpectralizeError
from spectralize.store import SCHEMA_ATTR, RunStore

__all__ = ["flow_value_problems", "refusal_lines"]


def refusal_lines(error: SpectralizeError) -> list[Problem | str]:
    """An error as ``validate`` lists it: its summary line, then its problems (run's text)."""
    return ([error.summary] if error.summary else []) + list(error.problems)


def flow_value_problems(store: RunStore, flow: str) -> list[Problem | str]:
    """What the nodes of ``flow`` would refuse before computing, for the groups present.

    Each group is read once; a group refused for one node is not checked again for the
    nodes after it.
    """
    from spectralize.engine import check_graph, value_refusals
    from spectralize.flows.pipelines import get_flow

    available = {group: store.group_attrs(group).get(SCHEMA_ATTR) for group in store.groups()}
    planned = check_graph(get_flow(flow).steps, available=available)
    found = value_refusals(
        planned, lambda group: store.read(group, friendly=False) if store.has(group) else None
    )
    return [line for _, error in found for line in refusal_lines(error)]
