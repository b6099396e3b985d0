"""The learnt prior's set step and its warm start apart:
PYTHONPATH=docs/research/set_model_foreign_labs python learnt_prior_warm.py ROOT LAB GROUPS

As evidence_blend_warm.py, with the default's set step at ``c = 3`` (the library's) and with
the set's learnt ``c`` (learnt_prior_labs.py's step): the seed set solved with either, the
other sets solved with either, warm-started from either seed; four crossings, median / p95
per camera, all images, the other sets' and the seed set's own.
"""

import json
import sys
from pathlib import Path

import evidence_blend_labs as labs
import learnt_prior_labs as learnt

from spectralize.nodes.reconstruction import api
from spectralize.nodes.reconstruction.set_reconstruction import (
    reconstruct_image_sets,
    reconstruct_seed_set,
    set_members,
)

c = labs.c
lab = labs.load(Path(sys.argv[1]), sys.argv[2])
groups, library = (
    (lab.oracle, lab.oracle_library) if sys.argv[3] == "oracle" else (lab.calibrated, lab.store_library)
)
steps = {"c=3": learnt.LIBRARY_STEP, "learnt": learnt.learnt_step}
seeds = {}
for name, step in steps.items():
    api.material_choice_blend = step
    seeds[name] = reconstruct_seed_set(*groups, lab.image_sets, library).compute()
has = lab.image_sets["has_bands"]
seed_owned = [
    int(v)
    for v, o in zip(*set_members(lab.image_sets, int(lab.image_sets.attrs["seed_set"])), strict=True)
    if o
]
for sets_step, step in steps.items():
    api.material_choice_blend = step
    for seed_step, seed in seeds.items():
        spectra = reconstruct_image_sets(*groups, lab.image_sets, seed, library)["radiance"].compute()
        row = {}
        for k, cam in enumerate(lab.cameras):
            for flag in (True, False):
                key = f"{cam} {'with' if flag else 'without'}"
                labels = c.camera_images(has, lab.rgb, k, flag)
                rest = [v for v in labels if v not in seed_owned]
                own = [v for v in labels if v in seed_owned]
                for name, chosen in ((key, labels), (f"{key} (not seed)", rest), (f"{key} (seed)", own)):
                    if chosen:
                        e = c.errors(spectra, lab.base, lab.rgb, chosen)
                        row[name] = [round(e["median"], 4), round(e["p95"], 4)]
        print(f"sets {sets_step:7s} seed {seed_step:7s}", json.dumps(row), flush=True)
api.material_choice_blend = learnt.LIBRARY_STEP
