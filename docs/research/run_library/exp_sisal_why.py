"""Helper D (issue 38 item 2): why SISAL's vertices fail on the capture's texel shapes.

For the present materials (largest texel fraction > 0) plus the light, at unit
channel-balanced brightness, the RMS extent of the true simplex along each of its principal
directions, against the error of the points SISAL sees: the matte shapes from the
noise-free band shots (one image per band, sets 1..8) minus the same texel's "every band in
every image" shape (an exact mixture of the true atoms up to the 0.2-1.3 % residual), its
RMS over the texels along each direction. A direction in which the simplex is thinner than
the points' error cannot be located by the points' hull; vertices found there are wrong.
Run from this folder with the scenes on the command line.
"""

import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from exp_sisal import every_band_shapes  # noqa: E402
from minvol import matte_shapes  # noqa: E402
from refine import SIZE, pooled_inputs  # noqa: E402
from runlib import SCENES, simulate  # noqa: E402

from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity, set_endmembers  # noqa: E402

for scene in sys.argv[1].split(",") if len(sys.argv) > 1 else SCENES:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    held = sets[0]
    inp = pooled_inputs(sets[1:9], noiseless=True)
    em = set_endmembers(inp)
    c = np.asarray(inp.camera_matrix, dtype=np.float64)
    present = held["fractions"].max(0) > 1e-6
    T = np.vstack([held["true_atoms"][present], held["led"][None]])
    b, _ = chromaticity(T @ c.T, em.scale)
    T = T / b[:, None]
    tm = T.mean(0)
    _, s, vt = np.linalg.svd(T - tm, full_matrices=False)
    r = int((s > 1e-9 * s[0]).sum())
    extent = s[:r] / np.sqrt(T.shape[0])
    B = vt[:r]
    scale = np.sqrt(((T - tm) ** 2).sum(1).mean())
    line = f"{scene:16s} K={T.shape[0]:2d} W={T.shape[1]} hull dims {r:2d}; extents / RMS radius: " + " ".join(
        f"{e / scale:.3f}" for e in extent
    )
    print(line, flush=True)
    E = every_band_shapes(sets[1:9], em.scale, c)
    X = matte_shapes(inp, em.scale, em.atoms[-1])[0]
    err = np.sqrt((((X - E) @ B.T) ** 2).mean(0))
    thin = int((extent < err).sum())
    print(f"   shots' error / radius: " + " ".join(f"{e / scale:.3f}" for e in err), flush=True)
    print(f"   error > extent in {thin} of {r} directions; total error {np.sqrt(((X - E) ** 2).sum(1).mean()) / scale:.3f} of the radius",
          flush=True)
