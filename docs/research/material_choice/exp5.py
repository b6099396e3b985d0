"""Library from oracle labels: per-material angle vs pure texels; pooled over 1, 2, 4 sets
(seeds = other captures of the same materials)."""
import sys
import numpy as np
from harness import load_case, SCENE_NAMES
import library as lib, choice as ch
size = 48
scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else SCENE_NAMES
for name in scenes:
    cases = [load_case(name, size, 0)] + [load_case(name, size, s, run_default=False) for s in (1, 2, 3)]
    fr = cases[0]["fractions"]; true = cases[0]["atoms"][:-1]
    label = np.where(fr.max(1) >= 0.9, fr.argmax(1), -1)
    npure = np.bincount(label[label >= 0], minlength=fr.shape[1])
    for k in (1, 2, 4):
        g = lib.pooled_shapes_sets([(c, label) for c in cases[:k]], fr.shape[1])
        cos = (g * true).sum(1) / np.maximum(np.linalg.norm(g, axis=1) * np.linalg.norm(true, axis=1), 1e-300)
        ang = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        has = npure >= 20
        print(f"{name:16s} sets {k}: own-material angle median {np.median(ang[has]):5.2f} p90 {np.percentile(ang[has],90):5.2f} "
              f"(materials with >=20 pure texels: {has.sum()}/{len(has)}; pure texels per material median {np.median(npure[has]):.0f})", flush=True)
    # noise-free shots: bias check
    c0 = dict(cases[0]); 
    g = lib.pooled_shapes_sets([(c0, label)], fr.shape[1])
