"""Helper F2: why true endmembers fit the texels' pooled shapes only to 6-9 % (noise-free):
the same LS shape with EVERY band taken in EVERY image (the truth of sets 1..8; not
capturable) vs one image per band (as the band shots are), fitted with the true atoms + the
light as a simplex mixture; then min-vol NMF from the library on the every-band shapes
(the ceiling of the method on data it cannot have). Tuning scenes woven, halftone, glossy."""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from minvol import abundance_step, minvol, texel_shapes  # noqa: E402
from refine import SIZE, TUNE, metrics, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity, set_endmembers  # noqa: E402

for scene in sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    inp = pooled_inputs(sets[1:9], noiseless=True)
    em = set_endmembers(inp)
    c = np.asarray(inp.camera_matrix, dtype=np.float64)
    T = np.vstack([sets[0]["true_atoms"], sets[0]["led"][None]])
    b, _ = chromaticity(T @ c.T, em.scale)
    T = T / b[:, None]
    P = SIZE * SIZE
    num = np.zeros((P, T.shape[1]))
    den = np.zeros(P)
    for s in sets[1:9]:
        t = s["truth"].transpose("image", "y", "x", "wavelength").values.reshape(20, P, -1).astype(float)
        beta, _ = chromaticity(s["rgb"].values.reshape(-1, 3).astype(float), em.scale)
        beta = beta.reshape(20, P)
        num += (beta[..., None] * t).sum(0)
        den += (beta**2).sum(0)
    x_all = num / den[:, None]
    x_one, dd = texel_shapes(inp, em.scale, 8)
    for name, X in (("every band in every image", x_all), ("one image per band (shots)", x_one)):
        A = abundance_step(X, np.ones(P), T, np.full((P, T.shape[0]), 1.0 / T.shape[0]), iters=500)
        res = float(np.sqrt(((X - A @ T) ** 2).mean()) / X.mean())
        print(f"{scene:16s} {name:28s} true-atom simplex fit rel.resid {res:.4f}", flush=True)
    m = metrics(em.atoms, sets[0])
    print(f"{scene:16s} library (noise-free shots)       all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
    for lam in (0.0, 1.0, 10.0):
        E, _ = minvol(x_all, np.ones(P), em.atoms, lam_tilde=lam, rounds=60)
        m = metrics(E, sets[0])
        print(f"{scene:16s} minvol on every-band shapes lam {lam:4.1f} all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
