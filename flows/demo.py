"""``spectralize demo``: simulate the bundled sample run and process it."""

from __future__ import annotations

from pathlib import Path

from spectralize.schemas import RunStore

from . import run_flow
from .runtime import RunReport

__all__ = ["DEMO_STORE", "run_demo"]

DEMO_STORE = Path("demo") / "run.zarr"


def run_demo(
    path: str | Path = DEMO_STORE, *, parameters: dict | None = None
) -> tuple[RunStore, RunReport]:
    """Run the ``demo`` flow: simulate the sample run (recipe ``demo``) and process it.

    Both halves resume: a second call finds every group up to date and skips every node.
    ``parameters`` overrides node parameters (``{"simulate.recipe": "tiny"}``).
    """
    report = run_flow("demo", path, parameters=parameters)
    return RunStore.open(path), report
