"""Helper F: library variants (angles, default + library, sparse choice with the library) on
set 0; libraries from sets 1..N. Tuning scenes only unless named on the command line."""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE)); sys.path.insert(0, str(HERE.parent / "material_choice"))
warnings.simplefilter("ignore")
from refine import TUNE, SIZE, metrics, pooled_inputs, recon, refine  # noqa: E402
from runlib import simulate  # noqa: E402
from harness import load_case, nrmse, stats  # noqa: E402
from exp_runlib_choice import sparse  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

scenes = sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE
for scene in scenes:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    held = sets[0]
    c = load_case(scene, 48, 0)
    led = held["led"]
    inp4 = pooled_inputs(sets[1:5])
    base4 = set_endmembers(inp4)
    rows = {"base N4": base4, "base N8": set_endmembers(pooled_inputs(sets[1:9]))}
    for lam in (0.003, 0.03):
        rows[f"smooth(L) lam{lam} N4"] = refine(inp4, base4, lam=lam, light=led)
    rows["clean N4"] = set_endmembers(pooled_inputs(sets[1:5], noiseless=True))
    for k, em in rows.items():
        m = metrics(em.atoms, held)
        r = recon(held, em)
        a = em.atoms.copy(); a[-1] = led * (a[-1] @ led) / (led @ led)
        s = stats(nrmse(sparse(c, a), c["truth"]))
        print(f"{scene:16s} {k:22s} ang all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f} | "
              f"default+lib {r['median']:.4f}/{r['p95']:.3f}/{r['frac<0.03']:.3f} | sparse {s['median']:.4f}/{s['p95']:.3f}/{s['frac<0.03']:.3f}", flush=True)
