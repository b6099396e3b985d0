"""Ceiling of a run-level library: oracle-label pooled atoms over 4 sets for the materials
seen pure (>= 20 texels), plus the default's learnt atoms, then the sparse choice."""
import sys
import numpy as np
from harness import load_case, score, fmt, SCENE_NAMES
import library as lib, choice as ch
scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else SCENE_NAMES
me, pen, ncand = 0.03, 30, 6
for name in scenes:
    cases = [load_case(name, 48, 0)] + [load_case(name, 48, s, run_default=False) for s in (1, 2, 3)]
    c = cases[0]; fr = c["fractions"]
    label = np.where(fr.max(1) >= 0.9, fr.argmax(1), -1)
    npure = np.bincount(label[label >= 0], minlength=fr.shape[1])
    for k in (1, 4):
        g = lib.pooled_shapes_sets([(x, label) for x in cases[:k]], fr.shape[1])[npure >= 20]
        learnt = c["learnt"][:-1]
        atoms = np.vstack([g, learnt, c["led"][None]])
        cand = ch.dichromatic_candidates(c, atoms, ncand, model_error=me)
        rc, bc, subs = ch.subset_costs(c, atoms, cand, model_error=me, band_model_error=0.1)
        sup = ch.support_of(cand, subs, ch.choose(rc + bc, subs, pen))
        print(f"{name:16s} oracle-label atoms from {k} set(s) + learnt: ", fmt(score(ch.spectra(c, atoms, sup), c)), flush=True)
