"""The default's set step and its warm start apart: python evidence_blend_warm.py ROOT LAB GROUPS

GROUPS: 'oracle' or 'cal' (evidence_blend_labs.py's groups, with the run's library). The seed
set solved with set model 'material-pooled' and with the default ('evidence-blend'); the
other sets solved with either set model, warm-started from either seed (the image-sets node
transports the seed's spectra to each set's initial guess): four crossings, median / p95 per
camera. The seed set's own images are the seed's copy, so they follow the seed's set model.
"""

import json
import sys
from pathlib import Path

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
models = {"pooled": {"set_model": "material-pooled"}, "default": {}}
seeds = {
    m: reconstruct_seed_set(*groups, lab.image_sets, library, **kw).compute() for m, kw in models.items()
}
has = lab.image_sets["has_bands"]
seed_owned = [
    int(v)
    for v, o in zip(*set_members(lab.image_sets, int(lab.image_sets.attrs["seed_set"])), strict=True)
    if o
]
for sets_model, kw in models.items():
    for seed_model, seed in seeds.items():
        spectra = reconstruct_image_sets(*groups, lab.image_sets, seed, library, **kw)[
            "radiance"
        ].compute()
        row = {}
        for k, cam in enumerate(lab.cameras):
            for flag in (True, False):
                key = f"{cam} {'with' if flag else 'without'}"
                labels = c.camera_images(has, lab.rgb, k, flag)
                rest = [v for v in labels if v not in seed_owned]  # solved by the other sets
                own = [v for v in labels if v in seed_owned]
                for name, chosen in ((key, labels), (f"{key} (not seed)", rest), (f"{key} (seed)", own)):
                    if chosen:
                        e = c.errors(spectra, lab.base, lab.rgb, chosen)
                        row[name] = [round(e["median"], 4), round(e["p95"], 4)]
        print(f"sets {sets_model:8s} seed {seed_model:8s}", json.dumps(row), flush=True)
