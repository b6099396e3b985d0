"""Helper C (issue 38, item 1): ``sparse-choice`` with spatial context.

Set 0 of each scene (20 x 48^2, seed 0; the harness's set), the run library of sets 1..8
(``libs.py``, as ``../material_choice/exp_edge_candidates.py``). Rows: the ``present`` and
``nearest-3`` oracles and the default with its own library (``../material_choice/harness.py``),
``sparse-choice`` without context, and with context settings given on the command line as
``context:radius:bandwidth:terms[:candidates]`` (e.g. ``4:2:1:band``, ``8:2:100:band:3``:
3 candidates from the neighbours' choices). Held-out scene: dark-still-life
(run it only with settings chosen on the others). ``BORROWED=100``: the further cost of
each endmember the neighbours offered (``context_candidate_penalty``; 0 without it, the
rows without a ``b`` suffix). ``LIBRARY=true``: the true endmembers
instead of the run library (the choice's ceiling; rows ``true ...``). Appends to
``results_context.json``.

    OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_context.py woven-fabric 4:2:1:band 8:2:1:band
"""

import functools
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "run_library"))
sys.path.insert(0, str(HERE.parent / "material_choice"))
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from harness import load_case, nrmse, oracle_nearest3, oracle_present, project_rgb, stats  # noqa: E402
from libs import run_library  # noqa: E402
from runlib import score, simulate  # noqa: E402

from spectralize.nodes.reconstruction import inputs_from_xarray  # noqa: E402
from spectralize.nodes.reconstruction.estimators import sparse_choice as _  # noqa: E402,F401
from spectralize.nodes.reconstruction.estimators.endmember_mixture import Endmembers  # noqa: E402
from spectralize.nodes.reconstruction.estimators.sparse_choice import sparse_choice  # noqa: E402

sc = sys.modules["spectralize.nodes.reconstruction.estimators.sparse_choice"]

RESULTS = HERE / "results_context.json"


def main():
    scene = sys.argv[1]
    configs = sys.argv[2:]
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    rows = results.setdefault(scene, {})
    held = simulate(scene, 48, 0)
    inputs = inputs_from_xarray(held["rgb"], held["bands"], held["C"], illuminant=held["led"])
    lib = run_library(scene)
    if os.environ.get("LIBRARY") == "true":
        # the library's ceiling: the TRUE endmembers (reflectance x LED, the LED last)
        atoms = np.vstack([held["true_atoms"], held["led"][None]])
        lib = Endmembers(atoms, np.zeros((atoms.shape[0] - 1, 2)), np.ones(3))
        configs = [f"true {c}" for c in configs]
    if "present" not in rows:
        case = load_case(scene, 48, 0)
        assert np.array_equal(case["rgb"], held["rgb"].values.reshape(20, -1, 3).astype(np.float64))
        rows["present"] = stats(
            nrmse(project_rgb(oracle_present(case), case["rgb"], case["C"]), case["truth"])
        )
        rows["nearest-3"] = stats(
            nrmse(project_rgb(oracle_nearest3(case), case["rgb"], case["C"]), case["truth"])
        )
        rows["default"] = stats(nrmse(case["default"], case["truth"]))
    variant = ""
    if "CAND_WEIGHT" in os.environ or "CAND_FILL" in os.environ:
        # research switches of the neighbours' candidates: the least weight of a neighbour
        # whose support counts, and whether the texel's own next ranks fill the places
        weight = float(os.environ.get("CAND_WEIGHT", "0"))
        fill = os.environ.get("CAND_FILL", "1") == "1"
        sc.neighbour_candidates = functools.partial(
            sc.neighbour_candidates, min_weight=weight, fill=fill
        )
        variant = f" w{weight:g}{'' if fill else ' nofill'}"
    # the further cost of each neighbour-offered atom in a support (0 unless BORROWED is set)
    borrowed = float(os.environ.get("BORROWED", "0"))
    if borrowed:
        variant += f" b{borrowed:g}"
    configs = [c + variant for c in configs]
    base = "true 0:2:1:band" if os.environ.get("LIBRARY") == "true" else "0:2:1:band"
    for config in [base, *configs]:
        if config in rows:
            continue
        spec = next(token for token in config.split() if ":" in token)
        context, radius, bandwidth, terms, *extra = spec.split(":")
        t = time.process_time()
        cube = sparse_choice(
            inputs,
            endmembers=lib,
            context=int(context),
            context_radius=int(radius),
            context_bandwidth=float(bandwidth),
            context_terms=terms,
            context_candidates=int(extra[0]) if extra else 0,
            context_candidate_penalty=borrowed,
        )
        cpu = time.process_time() - t
        s = score(held["truth"].copy(data=np.moveaxis(cube, 0, 1).astype(np.float32)), held["truth"])
        rows[config] = {**s, "cpu_s": cpu}
        print(
            f"{scene:16s} {config:14s} med {s['median']:.4f} p95 {s['p95']:.3f} <.03 "
            f"{100 * s['frac<0.03']:.1f}%  {cpu:.1f} CPU-s",
            flush=True,
        )
        results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
        results.setdefault(scene, {}).update(rows)
        RESULTS.write_text(json.dumps(results, indent=1))
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    results.setdefault(scene, {}).update(rows)
    RESULTS.write_text(json.dumps(results, indent=1))
    for k, v in rows.items():
        print(f"  {k:14s} med {v['median']:.4f} p95 {v['p95']:.3f} <.03 {100 * v['frac<0.03']:.1f}%")


if __name__ == "__main__":
    main()
