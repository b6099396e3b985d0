"""Endmember libraries from the pooled band shots of a set (or several sets of a run).

specular_free_library: cluster texels on a highlight-free ("matte") chromaticity, then per
cluster the pooled dichromatic regression of its texels' band shots
    D_i(q) ~ a_{m_i}(q) g_{k, b_i} + h_{m_i}(q) L_{b_i}
(a, h >= 0 from each image's RGB with the cluster's RGB C g_k and the illuminant's C L), so
highlights do not leak into a material's shape.
"""
from __future__ import annotations

import warnings

import numpy as np


def _balanced(case):
    rgb = case["rgb"]
    scale = np.abs(rgb.reshape(-1, 3).mean(axis=0))
    return rgb / scale, scale


def matte_chroma(case: dict, min_share: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """Per texel the balanced chromaticity of its least highlighted image (the one farthest
    from the illuminant's chromaticity, among images at least min_share x the texel's
    median brightness), and the texel's median brightness. (P, 2), (P,)."""
    bal, scale = _balanced(case)
    b = bal.sum(-1)  # (M, P)
    chroma = bal[..., :2] / np.maximum(b, 1e-12)[..., None]
    lrgb = (case["C"] @ case["led"]) / scale
    lch = lrgb[:2] / lrgb.sum()
    med = np.median(b, axis=0)
    dist = ((chroma - lch) ** 2).sum(-1)
    dist = np.where(b >= min_share * med[None], dist, -1)
    m = np.argmax(dist, axis=0)
    return chroma[m, np.arange(b.shape[1])], med


def dichromatic_weights(rgb: np.ndarray, e: np.ndarray, l: np.ndarray):
    """Exact NNLS of rgb (..., 3) on two RGB atoms e (..., 3) and l (3,); returns a, h."""
    A11 = (e * e).sum(-1); A12 = (e * l).sum(-1); A22 = l @ l
    b1 = (rgb * e).sum(-1); b2 = rgb @ l
    det = A11 * A22 - A12**2
    a = (A22 * b1 - A12 * b2) / np.maximum(det, 1e-300)
    h = (A11 * b2 - A12 * b1) / np.maximum(det, 1e-300)
    ok = (a >= 0) & (h >= 0)
    a1 = np.maximum(b1 / np.maximum(A11, 1e-300), 0)
    h1 = np.maximum(b2 / A22, 0)
    r_a = ((rgb - a1[..., None] * e) ** 2).sum(-1)
    r_h = ((rgb - h1[..., None] * l) ** 2).sum(-1)
    use_a = r_a <= r_h
    a = np.where(ok, a, np.where(use_a, a1, 0)); h = np.where(ok, h, np.where(use_a, 0, h1))
    return a, h


def pooled_shapes(case, label, n: int, rounds: int = 3,
                  init: np.ndarray | None = None) -> np.ndarray:
    if isinstance(case, dict):
        case, label = [case], [label]
    return pooled_shapes_sets(list(zip(case, label)), n, rounds, init)


def pooled_shapes_sets(sets, n: int, rounds: int = 3, init=None) -> np.ndarray:
    """Per label k the shape g_k (W,) by the pooled dichromatic band regression (module
    docstring); labels < 0 left out. (n, W). sets: [(case, label), ...] pooled together
    (several sets of a run share one library)."""
    C, L = sets[0][0]["C"], sets[0][0]["led"]
    W = L.size
    lrgb = C @ L
    if init is None:  # start: the cluster's mean RGB, minimum-norm shape with that RGB
        e = np.zeros((n, 3))
        for case, label in sets:
            ok = label >= 0
            np.add.at(e, label[ok], case["rgb"].sum(0)[ok])
        g = np.maximum(np.linalg.lstsq(C, e.T, rcond=None)[0].T, 0)
    else:
        g = init.copy()
    for _ in range(rounds):
        e = g @ C.T  # (n, 3)
        num = np.zeros((n, W))
        den = np.zeros((n, W))
        for case, label in sets:
            rgb = case["rgb"]
            ok = label >= 0
            lab = np.where(ok, label, 0)
            for i in range(case["shots"].shape[0]):
                m, b = case["shot_image"][i], case["shot_band"][i]
                a, h = dichromatic_weights(rgb[m], e[lab], lrgb)
                a = np.where(ok, a, 0)
                resid = case["shots"][i] - h * L[b]
                num[:, b] += np.bincount(lab, weights=a * resid, minlength=n)
                den[:, b] += np.bincount(lab, weights=a * a, minlength=n)
        g = np.maximum(num / np.maximum(den, 1e-300), 0)
    return g


def specular_free_library(case: dict, n: int = 32, seed: int = 0, rounds: int = 3) -> np.ndarray:
    """(n + 1, W): k-means on matte chromaticity + pooled dichromatic shapes; LED last."""
    from scipy.cluster.vq import kmeans2

    chroma, bright = matte_chroma(case)
    keep = bright > 0.2 * np.median(bright)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        centres, _ = kmeans2(chroma[keep], n, minit="++", seed=np.random.default_rng(seed))
    d = ((chroma[:, None] - centres[None]) ** 2).sum(-1)
    label = np.where(keep, d.argmin(1), -1)
    g = pooled_shapes(case, label, n, rounds)
    return np.vstack([g, case["led"][None]])


def oracle_label_library(case: dict, purity: float = 0.9, rounds: int = 3) -> np.ndarray:
    """The same pooled regression with the TRUE material of each pure texel as its label:
    the library the set's band noise allows once the choice is right."""
    fr = case["fractions"]
    label = np.where(fr.max(1) >= purity, fr.argmax(1), -1)
    g = pooled_shapes(case, label, fr.shape[1], rounds)
    return np.vstack([g, case["led"][None]])
