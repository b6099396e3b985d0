import json, sys
import numpy as np
from runlib import SCENES, simulate, learn, default, score
size = 48
scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else SCENES
out = {}
for scene in scenes:
    sets = [simulate(scene, size, k) for k in range(9)]
    s0 = sets[0]
    rows = {}
    est, c = default(s0); rows["own (default)"] = {**score(est, s0["truth"]), "cpu": c}
    em0, _ = learn(sets[:1])
    est, c = default(s0, em0); rows["own, passed in"] = {**score(est, s0["truth"]), "cpu": c}
    for n in (1, 2, 4, 8):
        em, _ = learn(sets[1:1 + n])
        est, c = default(s0, em); rows[f"run N={n}"] = {**score(est, s0["truth"]), "cpu": c}
    em, _ = learn(sets[:8])
    est, c = default(s0, em); rows["run N=8 incl. own"] = {**score(est, s0["truth"]), "cpu": c}
    em, _ = learn(sets[1:9], n_endmembers=64)
    est, c = default(s0, em); rows["run N=8 J=64"] = {**score(est, s0["truth"]), "cpu": c}
    for k, v in rows.items():
        print(f"{scene:16s} {k:20s} med {v['median']:.4f} p95 {v['p95']:.3f} <0.03 {100*v['frac<0.03']:5.1f}%  cpu {v['cpu']:.1f}s", flush=True)
    out[scene] = rows
    json.dump(out, open(f"recon_{'_'.join(scenes)}.json", "w"), indent=1)
