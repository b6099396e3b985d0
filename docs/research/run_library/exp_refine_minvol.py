"""Helper F2: shot-level min-vol (minvol.refine_minvol: F's joint LS alternation + a log-det
volume term) from the run library of sets 1..8 (noisy shots); angles to set 0's truth.
Tuning scenes unless named (held out: dark-still-life)."""
import sys
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from minvol import refine_minvol  # noqa: E402
from refine import SIZE, TUNE, metrics, pooled_inputs  # noqa: E402
from runlib import simulate  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402

LAMS = tuple(float(v) for v in sys.argv[2].split(",")) if len(sys.argv) > 2 else (0.0, 0.1, 1.0)
for scene in sys.argv[1].split(",") if len(sys.argv) > 1 else TUNE:
    sets = [simulate(scene, SIZE, k) for k in range(9)]
    inp = pooled_inputs(sets[1:9])
    em = set_endmembers(inp)
    m = metrics(em.atoms, sets[0])
    print(f"{scene:16s} library            all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
    for lam in LAMS:
        m = metrics(refine_minvol(inp, em, lam=lam).atoms, sets[0])
        print(f"{scene:16s} refine+vol lam {lam:4.1f} all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f}", flush=True)
