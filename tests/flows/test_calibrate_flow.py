"""The calibrate flow on a real store with the tiny simulated run."""

from __future__ import annotations

from spectralize.flows import run_flow
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.store import RunStore

GROUPS = ("raw/dark", "raw/white_reference", "raw/colour_checker", "raw/rgb")


def test_calibrate_flow_runs_then_skips(prefect_api, tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    run = simulate_run(get_recipe("tiny"))
    for group in GROUPS:
        store.write(group, run[group], fingerprint=f"sim-{group}")
    first = run_flow("calibrate", store.path)
    assert {s.node: s.status for s in first.steps} == {
        "dark_average": "ran",
        "recover_rgb_oecf": "ran",
        "recover_spectral_oecf": "ran",
        "calibrate_spectral": "ran",
    }
    groups = set(store.groups())
    assert {
        "dark",
        "calibration/oecf_rgb",
        "calibration/oecf_spectral",
        "calibration/spectral",
    } <= groups
    assert store.validate() == []
    assert float(store.read("calibration/spectral")["relative_error"].mean()) < 0.05
    second = run_flow("calibrate", store.path)
    assert {s.status for s in second.steps} == {"skipped"}
