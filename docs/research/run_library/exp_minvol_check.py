"""Helper F2: does the texel-shape model hold? Min-vol NMF started from the TRUE endmembers
(+ the learnt highlight atom) on noise-free and noisy texel shapes of sets 1..8 (woven,
glossy: tuning scenes); the fit residual with the true atoms vs the library's."""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from minvol import abundance_step, minvol, texel_shapes  # noqa: E402
from refine import SIZE, metrics, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else ("woven-fabric", "glossy-mosaic")
for scene in scenes:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    held = sets[0]
    for noiseless in (True, False):
        inp = pooled_inputs(sets[1:9], noiseless=noiseless)
        em = set_endmembers(inp)
        X, den = texel_shapes(inp, em.scale, 8)
        w = den.mean(1) / den.mean()
        tag = "clean" if noiseless else "noisy"
        c = np.asarray(inp.camera_matrix, dtype=np.float64)
        true = held["true_atoms"]
        from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity
        b, _ = chromaticity(true @ c.T, em.scale)
        T = np.vstack([true / b[:, None], em.atoms[-1:]])  # true atoms per unit brightness
        for name, E0 in (("library", em.atoms), ("true", T)):
            A = abundance_step(X, w, E0, np.full((X.shape[0], E0.shape[0]), 1.0 / E0.shape[0]), iters=300)
            res = float(np.sqrt((w[:, None] * (X - A @ E0) ** 2).sum() / (w.sum() * X.shape[1])) / X.mean())
            print(f"{scene:16s} {tag} fit with {name:7s} atoms: rel.resid {res:.3f}", flush=True)
        for lam in (0.0, 1.0):
            E, A = minvol(X, w, T, lam_tilde=lam, rounds=60)
            m = metrics(E, held)
            print(f"{scene:16s} {tag} minvol from TRUE lam {lam}: all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
