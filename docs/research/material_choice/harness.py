"""Harness for issue 38 (material choice with context): one simulated 20-image set per hard
scene, the default's result, the `present` and `nearest-3` oracles, and scoring.

    from harness import load_case, score
    case = load_case("woven-fabric", size=32, seed=0)   # cached in cache/

A case is a dict of numpy arrays:
  rgb      (M, P, 3)     RGB of every image (P = size*size texels, row-major)
  truth    (M, P, W)     true spectra
  shots    (n_shot, P)   band shots; shot_band (n_shot,), shot_image (n_shot,)
  sigma    (n_shot,)     per-shot band-noise sigma (the library's estimator, band_noise_sigma)
  C        (3, W)        camera matrix;  led (W,) the set's illuminant
  atoms    (J+1, W)      TRUE endmembers: reflectance_j * led, and led (highlight) last
  fractions(P, J)        true sub-pixel fraction of each material per texel
  present  (P, J) bool   fractions > 0
  default  (M, P, W)     the default (natural-prior-pcg, set_model material-pooled)
  default_s              wall seconds of the default call
  learnt   (J'+1, W)     the default's learnt endmember library (set_endmembers on the set)
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CACHE = HERE / "cache"
SCENE_NAMES = ("woven-fabric", "halftone-print", "glossy-mosaic", "dark-still-life")


def simulate(scene: str, size: int, seed: int):
    from spectralize.nodes.simulation.scenes import get_scene

    return get_scene(scene, size=size, seed=seed, n_images=20)


def load_case(scene: str, size: int = 32, seed: int = 0, *, run_default: bool = True) -> dict:
    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"{scene}_{size}_{seed}.npz"
    if not run_default and not path.exists():
        path = CACHE / f"{scene}_{size}_{seed}_nodefault.npz"
    if path.exists():
        d = dict(np.load(path))
        d["scene"] = scene
        return d
    from spectralize.nodes.reconstruction import inputs_from_xarray, reconstruct
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import (
        band_noise_sigma,
        set_endmembers,
    )
    from spectralize.nodes.simulation.scenes.layout import box_average
    from spectralize.nodes.simulation.scenes.materials import sharp_led

    cap = simulate(scene, size, seed)
    wl = cap.camera_matrix["wavelength"].values
    led = sharp_led(wl)
    layout = cap.layout
    n_mat = layout.reflectance.shape[0]
    fractions = np.stack(
        [box_average((layout.label == j).astype(float), layout.supersample).ravel() for j in range(n_mat)]
    ).T
    inputs = inputs_from_xarray(cap.rgb, cap.bands, cap.camera_matrix)
    M = cap.rgb.sizes["image"]
    P = size * size
    d = {
        "rgb": cap.rgb.values.reshape(M, P, 3).astype(np.float64),
        "truth": np.moveaxis(cap.truth.values, 1, -1).reshape(M, P, -1).astype(np.float64),
        "shots": cap.bands.values.reshape(-1, P).astype(np.float64),
        "shot_band": np.asarray(inputs.band, dtype=np.int64),
        "shot_image": np.asarray(inputs.image, dtype=np.int64),
        "sigma": band_noise_sigma(inputs),
        "C": np.asarray(cap.camera_matrix.values, dtype=np.float64),
        "led": led,
        "atoms": np.vstack([layout.reflectance * led[None], led[None]]),
        "fractions": fractions,
        "present": fractions > 0,
        "size": np.int64(size),
        "wl": wl,
    }
    learnt = set_endmembers(inputs)
    d["learnt"] = learnt.atoms
    if run_default:
        t = time.perf_counter()
        res = reconstruct(cap.rgb, cap.bands, cap.camera_matrix, illuminant=led)
        d["default_s"] = np.float64(time.perf_counter() - t)
        d["default"] = np.moveaxis(res.values, 1, -1).reshape(M, P, -1).astype(np.float64)
    np.savez_compressed(path, **d)
    d["scene"] = scene
    return d


# ---------------------------------------------------------------- scoring

def project_rgb(spectra: np.ndarray, rgb: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Project each spectrum (..., W) onto C S = R (minimum-norm change)."""
    pinv = C.T @ np.linalg.inv(C @ C.T)
    return spectra + (rgb - spectra @ C.T) @ pinv.T


def nrmse(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-pixel RMSE over bands / the image's mean truth; (M, P)."""
    rmse = np.sqrt(np.mean((est - truth) ** 2, axis=-1))
    return rmse / truth.mean(axis=(1, 2))[:, None]


def stats(e: np.ndarray) -> dict:
    e = np.asarray(e).ravel()
    return {
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
        "frac<0.03": float(np.mean(e < 0.03)),
    }


def score(est: np.ndarray, case: dict, project: bool = True) -> dict:
    if project:
        est = project_rgb(est, case["rgb"], case["C"])
    return stats(nrmse(est, case["truth"]))


def fmt(s: dict) -> str:
    return f"med {s['median']:.4f}  p95 {s['p95']:.4f}  <0.03 {100 * s['frac<0.03']:5.1f}%"


# ---------------------------------------------------------------- abundances

def nnls_support(atoms_rgb: np.ndarray, rgb: np.ndarray, support: np.ndarray) -> np.ndarray:
    """Exact NNLS per pixel over a per-pixel candidate list.

    atoms_rgb (A, 3); rgb (N, 3); support (N, k) int atom indices (-1 = unused).
    Returns weights (N, k). Exact by enumerating active sets of size <= 3 (RGB has 3
    equations; a NNLS solution has at most 3 non-zero weights generically).
    """
    from itertools import combinations

    N, k = support.shape
    best = np.full(N, np.inf)
    wbest = np.zeros((N, k))
    valid = support >= 0
    sup = np.where(valid, support, 0)
    G = atoms_rgb[sup]  # (N, k, 3)
    for r in (1, 2, 3):
        for comb in combinations(range(k), r):
            comb = list(comb)
            A = G[:, comb, :]  # (N, r, 3)
            ok = valid[:, comb].all(axis=1)
            AtA = A @ np.swapaxes(A, 1, 2)  # (N, r, r)
            Atb = np.einsum("nrc,nc->nr", A, rgb)
            AtA = AtA + (1e-12 * np.trace(AtA, axis1=1, axis2=2)[:, None, None] + 1e-30) * np.eye(r)
            try:
                w = np.linalg.solve(AtA, Atb[..., None])[..., 0]
            except np.linalg.LinAlgError:
                continue
            feas = ok & (w >= 0).all(axis=1)
            res = rgb - np.einsum("nr,nrc->nc", w, A)
            cost = np.einsum("nc,nc->n", res, res)
            better = feas & (cost < best)
            if better.any():
                best[better] = cost[better]
                wbest[better] = 0
                for i, c in enumerate(comb):
                    wbest[better, c] = w[better, i]
    return wbest


def mix(weights: np.ndarray, support: np.ndarray, atoms: np.ndarray) -> np.ndarray:
    return np.einsum("nk,nkw->nw", weights, atoms[np.where(support >= 0, support, 0)])


def spectra_from_support(case: dict, atoms: np.ndarray, support: np.ndarray) -> np.ndarray:
    """Given a per-texel support (P, k) into `atoms`, abundances per image from its RGB by
    exact NNLS; spectra (M, P, W) (not yet projected)."""
    M, P, _ = case["rgb"].shape
    argb = atoms @ case["C"].T
    out = np.empty((M, P, atoms.shape[1]))
    for m in range(M):
        w = nnls_support(argb, case["rgb"][m], support)
        out[m] = mix(w, support, atoms)
    return out


def present_support(case: dict) -> np.ndarray:
    """(P, k) padded: the true materials of each texel plus the highlight atom."""
    pres = case["present"]
    J = pres.shape[1]
    k = int(pres.sum(axis=1).max()) + 1
    sup = -np.ones((pres.shape[0], k), dtype=np.int64)
    for p in range(pres.shape[0]):
        idx = np.append(np.flatnonzero(pres[p]), J)
        sup[p, : idx.size] = idx
    return sup


def oracle_present(case: dict) -> np.ndarray:
    """`present`: scipy NNLS over each texel's true materials + LED, per image (as
    benchmarks/reconstruction_oracle.py)."""
    from scipy.optimize import nnls

    atoms, C, rgb = case["atoms"], case["C"], case["rgb"]
    pres = case["present"]
    J = pres.shape[1]
    argb = atoms @ C.T
    M, P, _ = rgb.shape
    out = np.empty((M, P, atoms.shape[1]))
    for p in range(P):
        use = np.append(np.flatnonzero(pres[p]), J)
        A = argb[use].T
        for m in range(M):
            w, _ = nnls(A, rgb[m, p])
            out[m, p] = w @ atoms[use]
    return out


def oracle_nearest3(case: dict) -> np.ndarray:
    """`nearest-3`: the three true endmembers nearest in chromaticity + LED (per image)."""
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import (
        Endmembers,
        chromaticity,
        rgb_abundances,
    )

    atoms, C = case["atoms"], case["C"]
    M, P, _ = case["rgb"].shape
    rgb = case["rgb"].reshape(M * P, 3)
    J = atoms.shape[0] - 1
    scale = np.abs(rgb.mean(axis=0))
    _, chroma = chromaticity(rgb, scale)
    projected = atoms @ C.T
    _, centres = chromaticity(projected[:J], scale=scale)
    em = Endmembers(atoms, centres, scale)
    near = em.candidates(chroma, 3)
    w = rgb_abundances(em, near, C, rgb)
    return np.einsum("pk,pkw->pw", w, atoms[near]).reshape(M, P, -1)


if __name__ == "__main__":
    import sys

    size = int(sys.argv[1]) if len(sys.argv) > 1 else 32
    for s in SCENE_NAMES:
        t = time.perf_counter()
        c = load_case(s, size=size)
        print(s, f"{time.perf_counter() - t:.1f}s", "default", f"{float(c['default_s']):.1f}s",
              "materials", c["present"].shape[1], "per texel median",
              np.median(c["present"].sum(1)), flush=True)
        print("  present  ", fmt(score(oracle_present(c), c)))
        print("  nearest-3", fmt(score(oracle_nearest3(c), c)))
        print("  default  ", fmt(score(c["default"], c, project=False)))
