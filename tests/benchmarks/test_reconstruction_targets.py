"""benchmarks/reconstruction_targets.py: the noise-free capture, the targets' verdicts, and a
tiny run end to end."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def load_benchmark():
    spec = importlib.util.spec_from_file_location(
        "reconstruction_targets", ROOT / "benchmarks" / "reconstruction_targets.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("reconstruction_targets", module)
    spec.loader.exec_module(module)
    return module


targets_benchmark = load_benchmark()


def test_noise_free_capture_holds_the_truth_at_each_shot_and_c_s_as_rgb():
    from spectralize.nodes.simulation.scenes import get_scene

    capture = get_scene("glossy-mosaic", size=16, seed=0, n_images=4)
    clean = targets_benchmark.noise_free(capture)
    truth = capture.truth.values
    band = np.searchsorted(
        capture.camera_matrix["wavelength"].values, capture.bands["wavelength"].values
    )
    expected = truth[capture.bands["image"].values, band]
    np.testing.assert_allclose(clean.bands.values, expected, rtol=1e-6)
    rgb = np.einsum("cw,mwyx->myxc", capture.camera_matrix.values, truth)
    np.testing.assert_allclose(clean.rgb.values, rgb, rtol=1e-5, atol=1e-7)
    assert not np.allclose(capture.bands.values, clean.bands.values)  # the captured ones are noisy
    assert clean.rgb.dims == capture.rgb.dims and clean.bands.dims == capture.bands.dims


def _stats(median, p95, fraction=0.5):
    relit = {light: {"median": 0.5, "p95": 2.0} for light in ("A", "FL11", "D65")}
    return {"median": median, "p95": p95, "fraction_under_0.03": fraction, "relit_de2000": relit}


def test_targets_say_which_is_missed_and_by_how_much():
    default = _stats(0.05, 0.3, fraction=0.30)
    default["with_bands"] = {"median": 0.04, "p95": 0.3}
    default["without_bands"] = {"median": 0.05, "p95": 0.3}
    default["relit_de2000"]["FL11"] = {"median": 1.2, "p95": 2.5}
    row = {
        "mode": "set",
        "scene": "woven-fabric",
        "default": default,
        "others": {"cnmf": _stats(0.04, 0.5), "wiener": _stats(0.06, 0.2)},
        "oracles": {"present": _stats(0.02, 0.1, 0.9), "nearest-3": _stats(0.04, 0.6)},
        "noise_free": _stats(0.03, 0.2, 0.6),
    }
    out = targets_benchmark.targets(row)
    assert out["le_every_other_method"] == {
        "met": False,
        "beaten_by_default_over_other": {"cnmf (median)": 1.25, "wiener (p95)": 1.5},
    }
    assert out["median_le_2x_present"]["met"] is False
    assert out["median_le_2x_present"]["default_over_present"] == 2.5
    assert out["median_le_2x_present"]["noise_free_over_present"] == 1.5
    assert (
        out["fraction_under_0.03"]["met"] is False and out["fraction_under_0.03"]["points_short"] == 10.0
    )
    assert out["relit_A_FL11_median_le_1.0"]["met"] is False
    assert out["relit_A_FL11_median_le_1.0"]["worst_over_bound"] == 1.2
    assert out["relit_A_FL11_p95_le_3.0"]["met"] is True
    assert out["without_within_1.1x_of_with"] == {
        "met": False,
        "without_over_with": {"median": 1.25, "p95": 1.0},
    }
    single = targets_benchmark.targets({**row, "mode": "single"})
    assert list(single) == ["le_every_other_method"]


@pytest.mark.slow
def test_quick_run_gives_every_row_its_oracles_noise_free_limit_and_targets(tmp_path):
    output = tmp_path / "targets.json"
    report = targets_benchmark.main(["--quick", "--output", str(output)])
    assert json.loads(output.read_text()) == json.loads(json.dumps(report))
    assert [(r["mode"], r["scene"], r["seed"]) for r in report["rows"]] == [
        ("single", "woven-fabric", 0),
        ("set", "woven-fabric", 0),
    ]
    for row in report["rows"]:
        # perfect measurements and the true materials leave less error than the default's
        assert row["noise_free"]["median"] < row["default"]["median"]
        assert row["oracles"]["present"]["median"] < row["default"]["median"]
        assert {"sparse-choice", "wiener"} <= set(row["others"])
    set_row = report["rows"][1]
    assert "sparse-choice+run-library" in set_row["others"]
    assert {"median_le_2x_present", "fraction_under_0.03", "without_within_1.1x_of_with"} <= set(
        set_row["targets"]
    )
    assert report["summary"]["rows"] == 2
