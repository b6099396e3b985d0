"""Helper D (issue 38 item 2): which true materials the run library's angle is measured on.

The all-material median angle counts every material of the scene's palette. At 48^2 a
palette material may not be in the layout at all (a woven stripe colour the crop never
reaches), and those present may or may not appear pure. This splits the library's angle
(true endmember -> nearest learnt atom, highlight excluded) by each material's largest
texel fraction in the layout (the same in every set of a run): absent (0), mixed only
(0 < max < 0.9), pure somewhere (>= 0.9). Library: `set_endmembers` on sets 1..N pooled
(noise-free and real band shots), as the `endmember_library` node learns it.
Run from this folder: `OMP_NUM_THREADS=1 ../../../.venv/bin/python exp_present.py`.
"""

import json
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
warnings.simplefilter("ignore")
from refine import SIZE, metrics, pooled_inputs  # noqa: E402
from runlib import SCENES, simulate  # noqa: E402

from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers  # noqa: E402


def split_angles(atoms: np.ndarray, held: dict) -> dict:
    """Median angle [deg] per purity class and the class sizes."""
    a = atoms[:-1] / np.linalg.norm(atoms[:-1], axis=1, keepdims=True).clip(1e-300)
    t = held["true_atoms"] / np.linalg.norm(held["true_atoms"], axis=1, keepdims=True).clip(1e-300)
    ang = np.degrees(np.arccos(np.clip(t @ a.T, -1, 1))).min(1)
    top = held["fractions"].max(0)
    classes = {"absent": top < 1e-6, "mixed": (top >= 1e-6) & (top < 0.9), "pure": top >= 0.9}
    classes["present"] = ~classes["absent"]
    out = {}
    for k, m in classes.items():
        out[k] = (float(np.median(ang[m])) if m.any() else float("nan"), int(m.sum()))
    return out


def main(scenes):
    res = {}
    for scene in scenes:
        sets = [simulate(scene, SIZE, k) for k in range(9)]
        for tag, n, clean in (("clean N=4", 4, True), ("clean N=8", 8, True), ("noisy N=8", 8, False)):
            em = set_endmembers(pooled_inputs(sets[1 : n + 1], noiseless=clean))
            m = metrics(em.atoms, sets[0])
            s = split_angles(em.atoms, sets[0])
            res[f"{scene}|{tag}"] = {"metrics": m, "split": s}
            cells = "  ".join(f"{k} {v[0]:5.1f} ({v[1]})" for k, v in s.items())
            print(f"{scene:16s} {tag}: all {m['all']:5.1f} area {m['area']:5.1f} dom {m['dominant']:5.1f} | {cells}", flush=True)
    (HERE / "present_angles.json").write_text(json.dumps(res, indent=1))


if __name__ == "__main__":
    main(sys.argv[1].split(",") if len(sys.argv) > 1 else SCENES)
