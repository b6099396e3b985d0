"""Helper F2: are the true endmembers vertices of their own convex hull? For each true atom
(unit channel-balanced brightness), the relative residual and spectral angle of its best
simplex mixture of the OTHER true atoms; and the number of principal components holding
99.9 % of the atoms' spread. A material inside the hull of the others is not a vertex a
minimum-volume (or any vertex-finding) method can recover from mixtures."""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from minvol import abundance_step  # noqa: E402
from refine import SIZE  # noqa: E402
from runlib import SCENES, simulate  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity  # noqa: E402

for scene in sys.argv[1].split(",") if len(sys.argv) > 1 else SCENES:
    s = simulate(scene, SIZE, 1)
    c = np.asarray(s["C"].values, dtype=np.float64)
    T = s["true_atoms"]
    b, _ = chromaticity(T @ c.T)
    T = T[b > 0] / b[b > 0, None]
    n = T.shape[0]
    res, ang = [], []
    for j in range(n):
        O = np.delete(T, j, 0)
        a = abundance_step(T[j : j + 1], np.ones(1), O, np.full((1, n - 1), 1.0 / (n - 1)), iters=2000)
        f = (a @ O)[0]
        res.append(np.linalg.norm(T[j] - f) / np.linalg.norm(T[j]))
        ang.append(np.degrees(np.arccos(np.clip(f @ T[j] / np.linalg.norm(f) / np.linalg.norm(T[j]), -1, 1))))
    res, ang = np.array(res), np.array(ang)
    sv = np.linalg.svd(T - T.mean(0), compute_uv=False) ** 2
    k = int(np.searchsorted(np.cumsum(sv) / sv.sum(), 0.999) + 1)
    print(f"{scene:16s} materials {n:3d}  pcs(99.9%) {k:2d}  inside the others' hull (angle < 2 deg): "
          f"{int((ang < 2).sum()):3d}  (< 5 deg: {int((ang < 5).sum())})  median angle to the others' hull {np.median(ang):4.1f} deg", flush=True)
