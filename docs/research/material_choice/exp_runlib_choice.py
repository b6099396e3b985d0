"""Helper F (issue 38, step 2): the per-texel material choice with the RUN library.

Set 0 of each scene (20 x 48^2, seed 0, as harness.load_case) is reconstructed by:
  present / nearest-3   oracles with the true endmembers (harness)
  default               natural-prior-pcg + material-pooled, its own set library (harness)
  default + run lib     the same with the run library of sets 1..4 (run_library/refine.py)
  sparse, run lib       choice.py's sparse joint choice (dichromatic candidates, supports
                        of <= 3 atoms, RGB + band chi^2 + size penalty) on the run library
  sparse, run lib +2    the same with 2 dictionary rounds on the chosen supports
  sparse, clean lib     on the run library learnt from NOISE-FREE band shots (the best any
                        denoising of the shots could give this library)
  sparse, true atoms    the library ceiling
nRMSE (median, p95, < 0.03) and relit CIEDE2000 (project's relit_delta_e: A, FL11, D65).
Held-out scene (no choice was made on it): dark-still-life.
"""
import json
import sys
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "run_library"))
warnings.simplefilter("ignore")

import choice as ch  # noqa: E402
from harness import SCENE_NAMES, load_case, nrmse, oracle_nearest3, oracle_present, project_rgb, stats  # noqa: E402
from refine import pooled_inputs  # noqa: E402
from runlib import default, simulate  # noqa: E402

from spectralize.nodes.evaluation.relit_colour import LIGHTS, relit_delta_e, relit_statistics  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

me, pen, ncand = 0.03, 30, 6


def sparse(case, atoms, rounds=0):
    for r in range(rounds + 1):
        cand = ch.dichromatic_candidates(case, atoms, ncand, model_error=me)
        rc, bc, subs = ch.subset_costs(case, atoms, cand, model_error=me, band_model_error=0.1)
        sup = ch.support_of(cand, subs, ch.choose(rc + bc, subs, pen))
        if r < rounds:
            atoms = ch.update_atoms(case, atoms, sup)
    return project_rgb(ch.spectra(case, atoms, sup), case["rgb"], case["C"])


def relit(est, case, truth_da):
    size = int(case["size"])
    cube = np.moveaxis(est.reshape(est.shape[0], size, size, -1), -1, 1)
    da = truth_da.copy(data=cube.astype(np.float32))
    r = relit_delta_e(da, truth_da, case["led"], targets=LIGHTS)
    return {k: (round(v["median"], 2), round(v["p95"], 2)) for k, v in relit_statistics(r).items()}


def main():
    scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else SCENE_NAMES
    rows = {}
    for name in scenes:
        c = load_case(name, 48, 0)
        sets = [simulate(name, 48, k) for k in range(5)]
        truth_da = sets[0]["truth"]
        run = set_endmembers(pooled_inputs(sets[1:]))
        clean = set_endmembers(pooled_inputs(sets[1:], noiseless=True))
        def lib(em):
            a = em.atoms.copy(); a[-1] = c["led"] * (a[-1] @ c["led"]) / (c["led"] @ c["led"]); return a
        out, _ = default(sets[0], run)
        d_run = np.moveaxis(out.transpose("image", "wavelength", "y", "x").values, 1, -1).reshape(20, -1, c["atoms"].shape[1])
        ests = {
            "present": project_rgb(oracle_present(c), c["rgb"], c["C"]),
            "nearest-3": project_rgb(oracle_nearest3(c), c["rgb"], c["C"]),
            "default": c["default"],
            "default + run lib": d_run.astype(np.float64),
            "sparse, run lib": sparse(c, lib(run)),
            "sparse, run lib +2 rounds": sparse(c, lib(run), rounds=2),
            "sparse, clean run lib": sparse(c, lib(clean)),
            "sparse, true atoms": sparse(c, c["atoms"]),
        }
        rows[name] = {}
        for k, e in ests.items():
            s = stats(nrmse(e, c["truth"]))
            d = relit(e, c, truth_da)
            rows[name][k] = {"nrmse": s, "de2000": d}
            print(f"{name:16s} {k:26s} med {s['median']:.4f} p95 {s['p95']:.3f} <.03 {100*s['frac<0.03']:5.1f}%  dE00 A {d['A']} FL11 {d['FL11']} D65 {d['D65']}", flush=True)
    (HERE / "results_runlib_choice.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
