"""Helper F2: min-vol NMF on the texels' MATTE shapes (minvol.matte_shapes: each image's
highlight taken off through its RGB before pooling), material atoms only (the library's
highlight atom is the light L). Noise-free and noisy band shots of sets 1..8; the fit
residual with the true atoms; min-vol from the library and from the truth; angles to set
0's truth. Scenes on the command line (default: the tuning scenes woven, halftone, glossy)."""
import json
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from minvol import abundance_step, matte_shapes, minvol  # noqa: E402
from refine import SIZE, TUNE, metrics, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity, set_endmembers  # noqa: E402

LAMS = tuple(float(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 else (0.0, 1.0, 10.0)
scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE
out = {}


def with_light(E, light):
    return np.vstack([E, light[None]])


for scene in scenes:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    held = sets[0]
    for noiseless in (True, False):
        inp = pooled_inputs(sets[1:9], noiseless=noiseless)
        em = set_endmembers(inp)
        light = em.atoms[-1]
        c = np.asarray(inp.camera_matrix, dtype=np.float64)
        b, _ = chromaticity(held["true_atoms"] @ c.T, em.scale)
        T = held["true_atoms"] / b[:, None]
        X, den = matte_shapes(inp, em.scale, light)
        w = den.mean(1) / den.mean()
        tag = "clean" if noiseless else "noisy"
        for name, E0 in (("true", T), ("library", em.atoms[:-1])):
            A = abundance_step(X, w, E0, np.full((X.shape[0], E0.shape[0]), 1.0 / E0.shape[0]), iters=300)
            res = float(np.sqrt((w[:, None] * (X - A @ E0) ** 2).sum() / (w.sum() * X.shape[1])) / X.mean())
            print(f"{scene:16s} {tag} matte shapes, fit with {name} atoms: rel.resid {res:.3f}", flush=True)
        m = metrics(em.atoms, held)
        out[f"{scene}|{tag}|library"] = m
        print(f"{scene:16s} {tag} library                   all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
        for start, E0 in (("library", em.atoms[:-1]), ("truth", T)):
            for lam in LAMS:
                E, _ = minvol(X, w, E0, lam_tilde=lam, rounds=60, fixed=())
                m = metrics(with_light(E, light), held)
                out[f"{scene}|{tag}|from {start}|lam {lam}"] = m
                print(f"{scene:16s} {tag} minvol from {start:7s} lam {lam:4.1f}: all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
name = "_".join(s.split("-")[0] for s in scenes)
(HERE / f"minvol_matte_{name}.json").write_text(json.dumps(out, indent=1))
