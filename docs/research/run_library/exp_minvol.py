"""Helper F2: min-vol NMF (minvol.py) from the run library of sets 1..8; angles to set 0's
true endmembers (all / area-weighted / dominant, refine.metrics). Tuning scenes unless
named on the command line (held out: dark-still-life)."""
import json
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from minvol import minvol, texel_shapes  # noqa: E402
from refine import TUNE, SIZE, metrics, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

LAMS = (0.0, 1.0, 3.0, 10.0)
PCS = (0, 10)
scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE
out = {}
for scene in scenes:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    held = sets[0]
    for noiseless in (False, True):
        inp = pooled_inputs(sets[1:9], noiseless=noiseless)
        em = set_endmembers(inp)
        X0, den = texel_shapes(inp, em.scale, 8)
        w = den.mean(1) / den.mean()
        tag = "clean" if noiseless else "noisy"
        m = metrics(em.atoms, held)
        print(f"{scene:16s} {tag} library      all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
        out[f"{scene}|{tag}|library"] = m
        for pcs, lam in [(k, lam) for k in PCS for lam in LAMS]:
            X = X0
            if pcs:  # denoise: keep the texel shapes' top principal components (weighted)
                mu = (w[:, None] * X0).sum(0) / w.sum()
                _, _, vt = np.linalg.svd(np.sqrt(w)[:, None] * (X0 - mu), full_matrices=False)
                X = mu + (X0 - mu) @ vt[:pcs].T @ vt[:pcs]
            E, A = minvol(X, w, em.atoms, lam_tilde=lam, rounds=60)
            m = metrics(E, held)
            res = float(np.sqrt((w[:, None] * (X - A @ E) ** 2).sum() / (w.sum() * X.shape[1])) / X.mean())
            print(f"{scene:16s} {tag} pc{pcs:2d} minvol {lam:5.2f} all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f} rel.resid {res:.3f}", flush=True)
            out[f"{scene}|{tag}|pc{pcs}|minvol {lam}"] = m
name = "_".join(s.split("-")[0] for s in scenes)
(HERE / f"minvol_angles_{name}.json").write_text(json.dumps(out, indent=1))
