"""The default's evidence blend with the set's learnt prior log-odds against the fixed
``c = 3`` (``DEFAULT_PRIOR_LOG_ODDS``), on a foreign lab's store, oracle and calibrated, each
with the run's endmember library as ``run btf`` passes it (evidence_blend_labs.py's groups):

    PYTHONPATH=docs/research/set_model_foreign_labs python learnt_prior_labs.py ROOT LAB

The learnt prior is docs/research/material_choice/exp_learnt_prior.py's ``em 0``: each texel
holds the default with prior probability ``pi_0``, its evidence ``Lambda_p`` the
log-likelihood ratio of the choice over the default (``choice_log_odds`` with
``prior_log_odds=0``); ``pi_0`` by EM (Dempster, Laird and Rubin 1977) over the set's texels,
E-step ``r_p = 1 / (1 + exp(c - Lambda_p))``, M-step ``pi_0 = 1 - mean r_p``, ``pi_0`` kept in
``[1e-4, 1 - 1e-4]``; then ``c = log(pi_0 / (1 - pi_0))`` (no margin). The step replaces the
library's ``material_choice_blend`` in the reconstruction API for the learnt runs only; the
``c = 3`` runs use the library as it is.

Prints per variant median / p95 / shape median per camera with and without bands and the
learnt ``c`` of every set the blend weighed; RESULT json as its last line.
"""

import json
import sys
import time
from pathlib import Path

import evidence_blend_labs as labs
import numpy as np

from spectralize.nodes.reconstruction import api
from spectralize.nodes.reconstruction.estimators import evidence_blend as eb
from spectralize.nodes.reconstruction.estimators.sparse_choice import sparse_choice

LIBRARY_STEP = api.material_choice_blend
LEARNT: list[float] = []
SHARE_BOUND = 1e-4


def em_prior(log_ratio: np.ndarray, iterations: int = 200, tolerance: float = 1e-7) -> float:
    """``c = logit(pi_0)``, ``pi_0`` the default's share by EM over the texels' ``Lambda``."""
    x = np.asarray(log_ratio, dtype=np.float64).ravel()
    share = 0.5
    for _ in range(iterations):
        c = np.log(share / (1.0 - share))
        r = 1.0 / (1.0 + np.exp(np.clip(c - x, -eb.MAX_LOG_ODDS, eb.MAX_LOG_ODDS)))
        new = float(np.clip(1.0 - r.mean(), SHARE_BOUND, 1.0 - SHARE_BOUND))
        if abs(new - share) < tolerance:
            break
        share = new
    return float(np.log(share / (1.0 - share)))


def learnt_step(inputs, cube, endmembers, candidates=eb.CHOICE_CANDIDATES):
    """``material_choice_blend`` with the set's learnt ``c`` (recorded in LEARNT)."""
    inputs.check_cubes(cube=cube)
    if len(inputs.band) == 0:
        return cube
    choice = sparse_choice(inputs, endmembers=endmembers, candidates=int(candidates))
    log_odds = eb.choice_log_odds(inputs, cube, choice, prior_log_odds=0.0)
    c = em_prior(log_odds)
    LEARNT.append(round(c, 3))
    log_odds -= c
    weight = 1.0 - 1.0 / (1.0 + np.exp(np.clip(log_odds, -eb.MAX_LOG_ODDS, eb.MAX_LOG_ODDS)))
    for b in range(inputs.n_wavelength):
        plane = cube[b]
        np.add(plane, weight * (choice[b] - plane), out=plane, casting="same_kind")
    return cube


def main(argv: list[str]) -> None:
    root, name = Path(argv[0]), argv[1]
    lab = labs.load(root, name)
    has = lab.image_sets["has_bands"]
    out: dict = {}
    for prior_name, step in (("c=3", LIBRARY_STEP), ("learnt", learnt_step)):
        api.material_choice_blend = step
        for group, groups, library in (
            ("oracle", lab.oracle, lab.oracle_library),
            ("cal", lab.calibrated, lab.store_library),
        ):
            LEARNT.clear()
            t = time.perf_counter()
            seed, spectra = labs.run(lab, {}, groups, library)
            row = {}
            for k, cam in enumerate(lab.cameras):
                for flag in (True, False):
                    labels = labs.c.camera_images(has, lab.rgb, k, flag)
                    if labels:
                        e = labs.c.errors(spectra, lab.base, lab.rgb, labels)
                        row[f"{cam} {'with' if flag else 'without'}"] = [
                            round(e["median"], 4),
                            round(e["p95"], 4),
                            round(e["shape_median"], 4),
                        ]
            variant = f"{group} {prior_name}"
            out[variant] = {"row": row, "learnt_c": list(LEARNT)}
            print(f"{variant:14s} {time.perf_counter() - t:6.1f}s", json.dumps(out[variant]), flush=True)
    api.material_choice_blend = LIBRARY_STEP
    print("RESULT", json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
