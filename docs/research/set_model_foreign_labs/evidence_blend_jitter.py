"""How much the other sets' results move with their warm start alone:
python evidence_blend_jitter.py ROOT LAB GROUPS [EPS...]

GROUPS: 'oracle' or 'cal' (evidence_blend_labs.py's groups, with the run's library). The seed
set solved with 'material-pooled' and with the default; how far the default's seed is from
the pooled one (per pixel |S_default - S_pooled| / |S_pooled|, quantiles). Then the other sets
solved with 'material-pooled' warm-started from the pooled seed times (1 + eps n), n white
Gaussian per value (three draws per eps, default eps 1e-3 and 1e-2): median / p95 per camera
over the images the other sets own. The spread over the draws is what any change of the seed
moves those sets by, with no change of the set model at all.
"""

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import evidence_blend_labs as labs  # noqa: E402

from spectralize.nodes.reconstruction.set_reconstruction import (  # noqa: E402
    reconstruct_image_sets,
    reconstruct_seed_set,
    set_members,
)

c = labs.c
lab = labs.load(Path(sys.argv[1]), sys.argv[2])
groups, library = (
    (lab.oracle, lab.oracle_library) if sys.argv[3] == "oracle" else (lab.calibrated, lab.store_library)
)
eps_list = [float(v) for v in sys.argv[4:]] or [1e-3, 1e-2]
pooled = {"set_model": "material-pooled"}
seed_mp = reconstruct_seed_set(*groups, lab.image_sets, library, **pooled).compute()
seed_df = reconstruct_seed_set(*groups, lab.image_sets, library).compute()
a = np.asarray(seed_mp["radiance"].transpose("image", "wavelength", "y", "x").values, float)
b = np.asarray(seed_df["radiance"].transpose("image", "wavelength", "y", "x").values, float)
moved = np.linalg.norm(b - a, axis=1) / np.linalg.norm(a, axis=1)
print(
    "default seed vs pooled seed, per pixel relative change: quantiles 50/90/99/max",
    " / ".join(f"{q:.2e}" for q in np.percentile(moved, [50, 90, 99, 100])),
    f"; share of pixels moved > 1e-3: {np.mean(moved > 1e-3):.3f}",
    flush=True,
)
has = lab.image_sets["has_bands"]
seed_owned = [
    int(v)
    for v, o in zip(*set_members(lab.image_sets, int(lab.image_sets.attrs["seed_set"])), strict=True)
    if o
]


def row_of(spectra):
    row = {}
    for k, cam in enumerate(lab.cameras):
        for flag in (True, False):
            labels = [
                v for v in c.camera_images(has, lab.rgb, k, flag) if v not in seed_owned
            ]  # the other sets' images
            if labels:
                e = c.errors(spectra, lab.base, lab.rgb, labels)
                row[f"{cam} {'with' if flag else 'without'}"] = [
                    round(e["median"], 4),
                    round(e["p95"], 4),
                ]
    return row


for name, seed in (("pooled seed", seed_mp), ("default seed", seed_df)):
    spectra = reconstruct_image_sets(*groups, lab.image_sets, seed, library, **pooled)[
        "radiance"
    ].compute()
    print(f"{name:24s}", json.dumps(row_of(spectra)), flush=True)
for eps in eps_list:
    for draw in range(3):
        rng = np.random.default_rng(draw)
        seed = seed_mp.copy(deep=True)
        values = seed["radiance"].values
        seed["radiance"].values = (values * (1 + eps * rng.standard_normal(values.shape))).astype(
            values.dtype
        )
        spectra = reconstruct_image_sets(*groups, lab.image_sets, seed, library, **pooled)[
            "radiance"
        ].compute()
        print(f"pooled seed x (1+{eps:g} n) #{draw}", json.dumps(row_of(spectra)), flush=True)
