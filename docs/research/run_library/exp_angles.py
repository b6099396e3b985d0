import json, sys
import numpy as np
from runlib import SCENES, simulate, learn, angles, angles_dominant
size = 48
res = {}
for scene in SCENES:
    sets = [simulate(scene, size, k) for k in range(9)]
    true, fr = sets[0]["true_atoms"], sets[0]["fractions"]
    em, c = learn(sets[:1])
    a = angles(em.atoms, true); dom, nd = angles_dominant(em.atoms, true, fr)
    print(f"{scene:16s} own(set0) J=32: med {a['median']:5.2f} p90 {a['p90']:5.2f} learnt->true {a['learnt_median']:5.2f} dominant({nd}) {dom:5.2f}  cpu {c:.2f}s", flush=True)
    res[(scene, "own", 32)] = {**a, "dominant": dom, "cpu": c}
    for J in (32, 64):
        for n in (1, 2, 4, 8):
            em, c = learn(sets[1:1 + n], n_endmembers=J)
            a = angles(em.atoms, true); dom, nd = angles_dominant(em.atoms, true, fr)
            print(f"{scene:16s} N={n} J={J}: med {a['median']:5.2f} p90 {a['p90']:5.2f} learnt->true {a['learnt_median']:5.2f} dominant({nd}) {dom:5.2f}  cpu {c:.2f}s", flush=True)
            res[(scene, n, J)] = {**a, "dominant": dom, "cpu": c}
json.dump({"|".join(map(str, k)): v for k, v in res.items()}, open("angles.json", "w"), indent=1)
