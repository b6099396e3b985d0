"""Helper F (issue 38): the choice where it is sure, the default elsewhere; and a blend.

Set 0 (20 x 48^2, seed 0), run library from sets 1..8 (run_library/runlib.py). Per texel the
margin = (second-best support cost) - (best), both with the size penalty, from
sparse_choice's own steps. Texels with margin >= tau take the sparse choice's spectra (all
images), the others the default's (with the same run library). Blend: w x the choice +
(1 - w) x the default (with the same run library). Tuning scenes: woven,
halftone, glossy; held out: dark-still-life (run last, with the tau chosen on the others).
"""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "run_library"))
warnings.simplefilter("ignore")
from refine import pooled_inputs  # noqa: E402
from runlib import default, score, simulate  # noqa: E402

from spectralize.nodes.reconstruction import inputs_from_xarray  # noqa: E402
from spectralize.nodes.reconstruction.estimators import sparse_choice as sc  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

sc = sys.modules["spectralize.nodes.reconstruction.estimators.sparse_choice"]
TAUS = (0.0, 10.0, 30.0, 100.0, 300.0, 1e9)

for name in sys.argv[1].split(","):
    sets = [simulate(name, 48, k) for k in range(9)]
    held = sets[0]
    lib = set_endmembers(pooled_inputs(sets[1:9]))
    inputs = inputs_from_xarray(held["rgb"], held["bands"], held["C"], illuminant=held["led"])
    base, _ = default(held, lib)
    choice = sc.sparse_choice(inputs, endmembers=lib)
    atoms = sc._library(inputs, lib)
    rgb = inputs.rgb.reshape(inputs.n_image, -1, 3).astype(np.float64)
    atoms_rgb = np.einsum("aw,mcw->mac", atoms, sc._cameras(inputs))
    near = sc.dichromatic_candidates(atoms_rgb, rgb, sc._rgb_variance(rgb, 0.03), 6)
    cost, subsets = sc.support_costs(inputs, atoms, near)
    size = np.array([len(s) for s in subsets], dtype=np.float64)
    total = np.sort(cost + 30.0 * size[:, None], axis=0)
    margin = (total[1] - total[0]).reshape(48, 48)
    b = base.transpose("image", "wavelength", "y", "x").values.astype(np.float64)
    c = np.moveaxis(choice, 0, 1)
    print(f"{name}: margin quantiles 10/50/90 % {np.percentile(margin, [10, 50, 90]).round(1)}", flush=True)
    for w in (0.25, 0.5, 0.75):
        s = score(held["truth"].copy(data=(w * c + (1 - w) * b).astype(np.float32)), held["truth"])
        print(f"{name:16s} blend {w:.2f} choice + {1 - w:.2f} default: "
              f"med {s['median']:.4f} p95 {s['p95']:.3f} <.03 {100 * s['frac<0.03']:.1f}%", flush=True)
    for tau in TAUS:
        sure = (margin >= tau)[None, None]
        mixed = np.where(sure, c, b)
        s = score(held["truth"].copy(data=mixed.astype(np.float32)), held["truth"])
        print(f"{name:16s} tau {tau:8.0f} sure {100 * float((margin >= tau).mean()):5.1f}% "
              f"med {s['median']:.4f} p95 {s['p95']:.3f} <.03 {100 * s['frac<0.03']:.1f}%", flush=True)
