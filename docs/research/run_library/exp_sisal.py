"""Helper D (issue 38 item 2): SISAL vertices as the run library, noise-free first.

Per texel (sets 1..8 of the run pooled, the texel grid shared), two kinds of points at unit
channel-balanced brightness: (a) the matte shapes from the NOISE-FREE band shots
(`minvol.matte_shapes`: each image's highlight taken off through its RGB, then the shots of
each band pooled, the data the library could have without noise), and (b) the "every band
in every image" shapes (the truth spectra pooled the same way: exact linear mixtures up to
the highlight, data no capture gives; the method's ceiling). SISAL (`sisal.py`) with p
vertices in the (p-1)-dimensional principal subspace; the vertices (clipped at 0) alone and
added to the clustered library; angles to set 0's truth split by each material's purity
(`exp_present.split_angles`). Scenes on the command line (tuning: woven, halftone, glossy;
`dark-still-life` held out, run last).
"""

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from exp_present import split_angles  # noqa: E402
from minvol import _unit_brightness, matte_shapes  # noqa: E402
from refine import SIZE, TUNE, metrics, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from sisal import sisal, subspace  # noqa: E402

from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity, set_endmembers  # noqa: E402

PS = tuple(int(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 else (8, 12, 16, 24, 32)
LAMS = tuple(float(v) for v in sys.argv[3].split(",")) if len(sys.argv) > 3 else (1.0, 100.0)


def every_band_shapes(sets, scale, c):
    P = SIZE * SIZE
    num, den = 0.0, 0.0
    for s in sets:
        t = s["truth"].transpose("image", "y", "x", "wavelength").values.reshape(20, P, -1).astype(float)
        beta, _ = chromaticity(s["rgb"].values.reshape(-1, 3).astype(float), scale)
        beta = beta.reshape(20, P)
        num = num + (beta[..., None] * t).sum(0)
        den = den + (beta**2).sum(0)
    return _unit_brightness(num / den[:, None], c, scale)


def row(tag, atoms, held):
    m = metrics(atoms, held)
    s = split_angles(atoms, held)
    cells = " ".join(f"{k} {v[0]:5.1f}" for k, v in s.items() if k != "absent")
    print(f"  {tag:34s} all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f} | {cells}", flush=True)
    return {"metrics": m, "split": s}


def main(scenes):
    res = {}
    for scene in scenes:
        sets = [simulate(scene, SIZE, k) for k in range(9)]
        held = sets[0]
        inp = pooled_inputs(sets[1:9], noiseless=True)
        em = set_endmembers(inp)
        light = em.atoms[-1]
        c = np.asarray(inp.camera_matrix, dtype=np.float64)
        print(scene, flush=True)
        res[f"{scene}|library"] = row("clustered library (noise-free)", em.atoms, held)
        data = {"matte": matte_shapes(inp, em.scale, light)[0], "every-band": every_band_shapes(sets[1:9], em.scale, c)}
        for dname, X in data.items():
            for p in PS:
                c0, U, Z = subspace(X, p)
                for lam in LAMS:
                    t0 = time.process_time()
                    V, A = sisal(Z, p, lam=lam)
                    E = np.maximum(c0 + V @ U.T, 0.0)
                    dt = time.process_time() - t0
                    out = f"{(A.min(1) < -0.01).mean():.2f}"
                    r1 = row(f"{dname} p={p} lam={lam:g} ({dt:.0f}s, out {out})", np.vstack([E, light]), held)
                    r2 = row("    + clustered library", np.vstack([em.atoms[:-1], E, light]), held)
                    res[f"{scene}|{dname}|p{p}|lam{lam:g}"] = {"sisal": r1, "union": r2, "cpu_s": dt}
    name = "_".join(s.split("-")[0] for s in scenes)
    (HERE / f"sisal_{name}.json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main(sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE)
