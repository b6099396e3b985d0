"""The calibration nodes' checks of their own results, run by the flow after each such step.

A calibration step that ran (or was up to date) has its result checked against what a sane
gantry gives (:mod:`spectralize.nodes.calibration.result_checks`); each warning goes to the
console with the number and the likely cause. ``spectralize run --strict`` turns them into an
error (exit 2) before the steps after it, the reconstruction among them, run.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping

from spectralize.schemas import CalibrationError, Problem
from spectralize.store import RunStore

__all__ = ["CHECKED_NODES", "step_warnings", "report_warnings"]

CHECKED_NODES = frozenset({"recover_rgb_oecf", "calibrate_spectral", "estimate_registration"})
"""The nodes whose results are checked."""


def step_warnings(
    store: RunStore, node: str, inputs: Mapping[str, str], outputs: Iterable[str]
) -> list[str]:
    """The warnings on ``node``'s result in ``store`` (``inputs``: argument -> group), each
    beginning with the node's name; empty for a node without result checks."""
    if node not in CHECKED_NODES:
        return []
    from spectralize.nodes.calibration.result_checks import result_warnings

    data_in = {arg: store.read(group) for arg, group in inputs.items() if store.has(group)}
    data_out = {group: store.read(group) for group in outputs if store.has(group)}
    return [f"{node}: {message}" for message in result_warnings(node, data_in, data_out)]


def report_warnings(warnings: list[str], warn: Callable[[str], None], *, strict: bool) -> None:
    """Each warning through ``warn``; with ``strict`` and any warning, a
    :class:`~spectralize.schemas.CalibrationError` naming them all (the run stops there)."""
    for message in warnings:
        warn(message)
    if strict and warnings:
        raise CalibrationError(
            f"--strict: {len(warnings)} calibration warning(s), stopped before reconstruction: "
            + "; ".join(warnings),
            [Problem(m.split(":", 1)[0], "a calibration a sane gantry gives", m) for m in warnings],
        )
