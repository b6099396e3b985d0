"""Helper D (issue 38 item 2): SISAL on the texels whose mixture holds across images.

A texel's band shots are taken in different images; where its materials' shares of the light
change from image to image (shading, highlights), its pooled shape is no single mixture
(`exp_sisal_why.py`). The RGB shows where they do not change: a texel whose chromaticity is
steady over the pooled images (median absolute deviation over the 160 images of sets 1..8,
robust to a few highlights). Keep the steadiest q of the texels, measure their shapes' error
against the exact-mixture shapes (as in `exp_sisal_why.py`), and run SISAL on them
(noise-free band shots). Scenes on the command line (tuning first; dark held out, last).
"""

import json
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from exp_sisal import every_band_shapes, row  # noqa: E402
from minvol import matte_shapes  # noqa: E402
from refine import SIZE, TUNE, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from sisal import sisal, subspace  # noqa: E402

from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity, set_endmembers  # noqa: E402

QS = (1.0, 0.5, 0.25, 0.1)
PS = tuple(int(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 else (8, 12, 16, 24, 32)


def steadiness(inp, scale):
    P = inp.height * inp.width
    _, ch = chromaticity(inp.rgb_pixels().T, scale)
    ch = ch.reshape(-1, P, 2)
    return np.abs(ch - np.median(ch, axis=0)).mean(axis=0).sum(1)  # (P,)


def main(scenes):
    res = {}
    for scene in scenes:
        sets = [simulate(scene, SIZE, k) for k in range(9)]
        held = sets[0]
        inp = pooled_inputs(sets[1:9], noiseless=True)
        em = set_endmembers(inp)
        light = em.atoms[-1]
        c = np.asarray(inp.camera_matrix, dtype=np.float64)
        X = matte_shapes(inp, em.scale, light)[0]
        E = every_band_shapes(sets[1:9], em.scale, c)
        radius = np.sqrt(((E - E.mean(0)) ** 2).sum(1).mean())
        mad = steadiness(inp, em.scale)
        print(scene, flush=True)
        row("clustered library (noise-free)", em.atoms, held)
        for q in QS:
            keep = mad <= np.quantile(mad, q)
            err = float(np.sqrt(((X[keep] - E[keep]) ** 2).sum(1).mean()) / radius)
            print(f" steadiest {q:.0%} ({keep.sum()} texels): shots' error {err:.3f} of the data's radius", flush=True)
            res[f"{scene}|q{q}|error"] = err
            for p in PS:
                c0, U, Z = subspace(X[keep], p)
                V, A = sisal(Z, p, lam=1.0)
                Ev = np.maximum(c0 + V @ U.T, 0.0)
                res[f"{scene}|q{q}|p{p}"] = {
                    "sisal": row(f"q={q:g} p={p}", np.vstack([Ev, light]), held),
                    "union": row("    + clustered library", np.vstack([em.atoms[:-1], Ev, light]), held),
                }
    name = "_".join(s.split("-")[0] for s in scenes)
    (HERE / f"sisal_steady_{name}.json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main(sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE)
