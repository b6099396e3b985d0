"""H3 phase 1: a run-level endmember library pooled over the band shots of N sets.

Sets of one run: same scene layout (layout_seed 0), set k has capture-noise seed k and its
lights rotated in azimuth by 37*k deg (set 0 = the benchmark's set). Held-out set: k = 0.
"""
from __future__ import annotations

import pickle
import time
from pathlib import Path

import numpy as np
import xarray as xr

HERE = Path(__file__).resolve().parent
CACHE = HERE / "cache"
SCENES = ("woven-fabric", "halftone-print", "glossy-mosaic", "dark-still-life")


def simulate(scene: str, size: int, k: int):
    """Set k of the run: noise seed k, light azimuths rotated by 37 k deg."""
    path = CACHE / f"{scene}_{size}_set{k}.pkl"
    if path.exists():
        return pickle.loads(path.read_bytes())
    import spectralize.nodes.simulation.scenes as sc
    from spectralize.nodes.simulation.scenes.layout import box_average
    from spectralize.nodes.simulation.scenes.materials import sharp_led

    original = sc.set_geometry

    def rotated(n, wb):
        g = original(n, wb)
        return [{**x, "phi_i": (x["phi_i"] + 37.0 * k) % 360.0} for x in g]

    sc.set_geometry = rotated
    try:
        cap = sc.get_scene(scene, size=size, seed=k, n_images=20)
    finally:
        sc.set_geometry = original
    wl = cap.camera_matrix["wavelength"].values
    led = sharp_led(wl)
    lay = cap.layout
    n_mat = lay.reflectance.shape[0]
    fractions = np.stack(
        [box_average((lay.label == j).astype(float), lay.supersample).ravel() for j in range(n_mat)]
    ).T
    d = {
        "rgb": cap.rgb, "bands": cap.bands, "C": cap.camera_matrix, "truth": cap.truth,
        "led": led, "true_atoms": lay.reflectance * led[None], "fractions": fractions,
    }
    path.write_bytes(pickle.dumps(d))
    return d


def pooled(sets: list[dict]):
    """The sets' rgb and bands concatenated along image (image coords renumbered)."""
    rgbs, bands = [], []
    off = 0
    for s in sets:
        r = s["rgb"]
        n = r.sizes["image"]
        rgbs.append(r.assign_coords(image=np.arange(off, off + n)))
        b = s["bands"]
        bands.append(b.assign_coords(image=("shot", b["image"].values + off)))
        off += n
    rgb = xr.concat(rgbs, "image", coords="minimal", compat="override")
    bnd = xr.concat(bands, "shot", coords="minimal", compat="override")
    return rgb, bnd


def learn(sets: list[dict], **kw):
    from spectralize.nodes.reconstruction import inputs_from_xarray
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers

    rgb, bnd = pooled(sets)
    inputs = inputs_from_xarray(rgb.drop_vars(["theta_i", "phi_i", "theta_o", "phi_o"], errors="ignore"),
                                bnd, sets[0]["C"])
    t = time.process_time()
    em = set_endmembers(inputs, **kw)
    return em, time.process_time() - t


def angles(atoms: np.ndarray, true: np.ndarray) -> dict:
    a = atoms[:-1] / np.linalg.norm(atoms[:-1], axis=1, keepdims=True).clip(1e-300)
    t = true / np.linalg.norm(true, axis=1, keepdims=True).clip(1e-300)
    ang = np.degrees(np.arccos(np.clip(t @ a.T, -1, 1)))
    return {"median": float(np.median(ang.min(1))), "p90": float(np.percentile(ang.min(1), 90)),
            "learnt_median": float(np.median(ang.min(0)))}


def angles_dominant(atoms, true, fractions, min_pure=20):
    """Median angle over the materials with >= min_pure texels of fraction >= 0.9 in a set."""
    a = atoms[:-1] / np.linalg.norm(atoms[:-1], axis=1, keepdims=True).clip(1e-300)
    t = true / np.linalg.norm(true, axis=1, keepdims=True).clip(1e-300)
    ang = np.degrees(np.arccos(np.clip(t @ a.T, -1, 1))).min(1)
    label = np.where(fractions.max(1) >= 0.9, fractions.argmax(1), -1)
    npure = np.bincount(label[label >= 0], minlength=fractions.shape[1])
    has = npure >= min_pure
    return float(np.median(ang[has])) if has.any() else float("nan"), int(has.sum())


def score(est: xr.DataArray, truth: xr.DataArray) -> dict:
    e = est.transpose("image", "wavelength", "y", "x").values.astype(np.float64)
    t = truth.transpose("image", "wavelength", "y", "x").values.astype(np.float64)
    rmse = np.sqrt(np.mean((e - t) ** 2, axis=1))
    err = (rmse / t.mean(axis=(1, 2, 3))[:, None, None]).ravel()
    return {"median": float(np.median(err)), "p95": float(np.percentile(err, 95)),
            "frac<0.03": float(np.mean(err < 0.03))}


def default(s: dict, endmembers=None):
    from spectralize.nodes.reconstruction import reconstruct

    kw = {} if endmembers is None else {"endmembers": endmembers}
    t = time.process_time()
    out = reconstruct(s["rgb"], s["bands"], s["C"], illuminant=s["led"], **kw)
    return out, time.process_time() - t
