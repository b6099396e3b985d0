"""How accurate must the library be? TRUE endmembers with white per-band relative noise
(angle ~ noise level), then the sparse joint choice (rgb + own band evidence)."""
import numpy as np
from harness import load_case, score, fmt, SCENE_NAMES
import choice as ch
pen, ncand = 30, 6
for name in SCENE_NAMES:
    c = load_case(name, 48)
    for rel in (0.0, 0.05, 0.1, 0.2):
        rng = np.random.default_rng(1)
        atoms = c["atoms"].copy()
        atoms[:-1] *= np.maximum(1 + rel * rng.normal(size=atoms[:-1].shape), 0)
        ang = ch.spectral_angles(atoms, c["atoms"])
        me = max(0.004, rel / 3)
        cand = ch.dichromatic_candidates(c, atoms, ncand, model_error=me)
        rc, bc, subs = ch.subset_costs(c, atoms, cand, model_error=me, band_model_error=rel)
        sup = ch.support_of(cand, subs, ch.choose(rc + bc, subs, pen))
        print(f"{name:16s} rel noise {rel:.2f} angle {ang['true->learnt median']:5.2f}", fmt(score(ch.spectra(c, atoms, sup), c)), flush=True)
