"""``spectralize demo``: make the bundled sample run and process it."""

from __future__ import annotations

from pathlib import Path

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.schemas import RunStore, compute_fingerprint

from . import run_flow
from .runtime import RunReport

__all__ = ["DEMO_STORE", "prepare_demo_store", "run_demo"]

DEMO_STORE = Path("demo") / "run.zarr"
_DEMO_RECIPE = {"frames": 64, "shape": [48, 64], "exposure_times": [0.01, 0.05, 0.2], "seed": 0}


def prepare_demo_store(path: str | Path = DEMO_STORE) -> tuple[RunStore, bool]:
    """Create the demo store with its raw data unless it is already there.

    Returns the store and whether raw data was generated now.
    """
    path = Path(path)
    store = RunStore.create(path, attrs={"title": "spectralize demo run"}, exist_ok=True)
    fingerprint = compute_fingerprint("datasets.dark_stack", "1", _DEMO_RECIPE, {})
    if store.fingerprint("raw/dark") == fingerprint:
        return store, False
    raw = make_raw_dark(frames=_DEMO_RECIPE["frames"], shape=tuple(_DEMO_RECIPE["shape"]),
                        exposure_times=tuple(_DEMO_RECIPE["exposure_times"]),
                        seed=_DEMO_RECIPE["seed"])
    store.write("raw/dark", raw, fingerprint=fingerprint,
                provenance={"generator": "spectralize.datasets.dark_stack", **_DEMO_RECIPE},
                chunks={"exposure_time": 1, "frame": 16})
    return store, True


def run_demo(path: str | Path = DEMO_STORE) -> tuple[RunStore, bool, RunReport]:
    """Prepare the demo store and run the demo flow on it."""
    store, generated = prepare_demo_store(path)
    report = run_flow("dark", store.path)
    return store, generated, report
