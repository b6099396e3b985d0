"""Material choice with context (issue 38 prototype).

Core object: for every texel p and every candidate support T (a subset of <= 3 atoms of the
texel's candidate list, the highlight atom among the candidates), the exact NNLS fit of each
image's RGB with the atoms of T (the per-image support may be any subset of T), and
  rgb_cost[T, p]  = sum_m ||C A w_m - R_m(p)||^2 / sigma_R,m(p)^2
  band_cost[T, p] = sum_i (A w_{m_i}(p))_{b_i} - D_i(p))^2 / sigma_i^2     (the band shots)
Choices are argmins of combinations of those (sparsity penalty, pooled band costs over
RGB-similar texels, Potts smoothing), then abundances per image from the RGB alone.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from harness import mix, nnls_support

RGB_REL_NOISE = 0.004
RGB_FLOOR = 2e-4


def rgb_sigma(case: dict, model_error: float = 0.0) -> np.ndarray:
    """(M, P) per-pixel RGB noise sigma (per channel; the simulation's HDR-merge noise,
    plus a relative model error for learnt atoms)."""
    rgb = case["rgb"]
    white = case["C"] @ case["led"]
    rel = np.sqrt(RGB_REL_NOISE**2 + model_error**2)
    # one sigma per pixel: the channel-mean noise
    s2 = (rel * rgb) ** 2 + (RGB_FLOOR * white) ** 2
    return np.sqrt(s2.mean(axis=-1))


def texel_chroma(case: dict, atoms: np.ndarray):
    """Balanced chromaticity of every texel (RGB summed over the set) and of the atoms."""
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity

    rgb = case["rgb"]
    scale = np.abs(rgb.reshape(-1, 3).mean(axis=0))
    _, chroma = chromaticity(rgb.sum(axis=0), scale)
    _, centres = chromaticity(atoms[:-1] @ case["C"].T, scale)
    return chroma, centres


def chroma_candidates(case: dict, atoms: np.ndarray, n: int) -> np.ndarray:
    """(P, n + 1): the n atoms nearest the texel in chromaticity, then the highlight atom."""
    chroma, centres = texel_chroma(case, atoms)
    d = ((chroma[:, None, :] - centres[None]) ** 2).sum(-1)
    n = min(n, centres.shape[0])
    near = np.argsort(d, axis=1)[:, :n]
    return np.hstack([near, np.full((near.shape[0], 1), atoms.shape[0] - 1)])


def subsets(n_cand: int, max_size: int = 3):
    """All non-empty subsets (tuples of candidate positions) of size <= max_size, by size,
    and for each the indices of its children (size - 1 subsets; -1 = the empty set)."""
    subs = [c for r in range(1, max_size + 1) for c in combinations(range(n_cand), r)]
    index = {s: i for i, s in enumerate(subs)}
    children = []
    for s in subs:
        if len(s) == 1:
            children.append([-1])
        else:
            children.append([index[c] for c in combinations(s, len(s) - 1)])
    return subs, children


def subset_costs(case: dict, atoms: np.ndarray, cand: np.ndarray, *, max_size: int = 3,
                 model_error: float = 0.0, band_model_error: float = 0.0):
    """rgb_cost, band_cost (S, P), and the subsets. See the module docstring.

    band_model_error: relative error of the atoms' spectra added to the band noise
    (sigma_i^2 + (e * prediction)^2)."""
    rgb, C = case["rgb"], case["C"]
    M, P, _ = rgb.shape
    argb = atoms @ C.T  # (A, 3)
    subs, children = subsets(cand.shape[1], max_size)
    S = len(subs)
    sig = rgb_sigma(case, model_error)  # (M, P)
    rgb_cost = np.zeros((S, P))
    band_cost = np.zeros((S, P))
    shots, sb, si, ssig = case["shots"], case["shot_band"], case["shot_image"], case["sigma"]
    G = argb[cand]  # (P, n, 3)
    AB = atoms[cand]  # (P, n, W)
    for m in range(M):
        r = rgb[m]  # (P, 3)
        mine = np.flatnonzero(si == m)
        bands = sb[mine]
        D = shots[mine].T  # (P, k)
        vs = ssig[mine] ** 2  # (k,)
        eff_rgb = np.empty((S, P))
        eff_band = np.empty((S, P))
        empty_rgb = (r * r).sum(-1) / sig[m] ** 2
        empty_band = (D**2 / vs).sum(-1)
        for s, (sub, ch) in enumerate(zip(subs, children)):
            sub = list(sub)
            A = G[:, sub, :]  # (P, r, 3)
            AtA = A @ np.swapaxes(A, 1, 2)
            AtA += (1e-12 * np.trace(AtA, axis1=1, axis2=2)[:, None, None] + 1e-30) * np.eye(len(sub))
            w = np.linalg.solve(AtA, np.einsum("prc,pc->pr", A, r)[..., None])[..., 0]
            feas = (w >= 0).all(axis=1)
            res = r - np.einsum("pr,prc->pc", w, A)
            c_rgb = (res * res).sum(-1) / sig[m] ** 2
            pred = np.einsum("pr,prk->pk", w, AB[:, sub][:, :, bands])  # (P, k)
            var = vs[None] + (band_model_error * pred) ** 2
            c_band = ((pred - D) ** 2 / var).sum(-1)
            c_rgb = np.where(feas, c_rgb, np.inf)
            # best feasible sub-support (exact NNLS restricted to T)
            best_rgb, best_band = c_rgb, c_band
            for c in ch:
                cr = empty_rgb if c < 0 else eff_rgb[c]
                cb = empty_band if c < 0 else eff_band[c]
                take = cr < best_rgb
                best_rgb = np.where(take, cr, best_rgb)
                best_band = np.where(take, cb, best_band)
            eff_rgb[s], eff_band[s] = best_rgb, best_band
        rgb_cost += eff_rgb
        band_cost += eff_band
    return rgb_cost, band_cost, subs


def support_of(cand: np.ndarray, subs, choice: np.ndarray) -> np.ndarray:
    """(P, max_size) atom indices of the chosen subsets (-1 padded)."""
    k = max(len(s) for s in subs)
    out = -np.ones((cand.shape[0], k), dtype=np.int64)
    for s, sub in enumerate(subs):
        here = np.flatnonzero(choice == s)
        if here.size:
            out[here, : len(sub)] = cand[here][:, list(sub)]
    return out


def spectra(case: dict, atoms: np.ndarray, support: np.ndarray) -> np.ndarray:
    """Abundances per image from its RGB (exact NNLS on the support); (M, P, W)."""
    M, P, _ = case["rgb"].shape
    argb = atoms @ case["C"].T
    out = np.empty((M, P, atoms.shape[1]))
    for m in range(M):
        w = nnls_support(argb, case["rgb"][m], support)
        out[m] = mix(w, support, atoms)
    return out


# ------------------------------------------------------------------ context

def knn_features(case: dict, highlight_robust: bool = True) -> np.ndarray:
    """Per texel, the stacked per-image chromaticity (balanced RGB / brightness), (P, 2M),
    each image's block weighted by sqrt of its brightness share (dark images are noisy)."""
    rgb = case["rgb"]
    scale = np.abs(rgb.reshape(-1, 3).mean(axis=0))
    bal = rgb / scale
    b = bal.sum(-1, keepdims=True)  # (M, P, 1)
    chroma = bal[..., :2] / np.maximum(b, 1e-9 * b.mean())
    return np.moveaxis(chroma, 0, 1).reshape(rgb.shape[1], -1)


def knn(features: np.ndarray, k: int, spatial: np.ndarray | None = None,
        spatial_weight: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Brute-force k nearest neighbours (self included): indices (P, k), squared distances."""
    f = features
    if spatial is not None and spatial_weight > 0:
        f = np.hstack([f, spatial_weight * spatial])
    sq = (f * f).sum(1)
    d = sq[:, None] + sq[None] - 2 * f @ f.T
    idx = np.argpartition(d, k - 1, axis=1)[:, :k]
    dd = np.take_along_axis(d, idx, 1)
    o = np.argsort(dd, axis=1)
    return np.take_along_axis(idx, o, 1), np.maximum(np.take_along_axis(dd, o, 1), 0)


def pooled(cost: np.ndarray, idx: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """sum over each texel's neighbours of their cost (S, P) -> (S, P)."""
    if weights is None:
        return cost[:, idx].sum(-1)
    return (cost[:, idx] * weights[None]).sum(-1)


def choose(total: np.ndarray, subs, penalty: float) -> np.ndarray:
    size = np.array([len(s) for s in subs], dtype=np.float64)
    return np.argmin(total + penalty * size[:, None], axis=0)


def potts_icm(unary: np.ndarray, size: int, edge_w: np.ndarray, cand: np.ndarray, subs,
              lam: float, sweeps: int = 5) -> np.ndarray:
    """ICM on labels = actual atom sets (so neighbours with other candidate lists compare by
    atoms, not positions). unary (S, P); edge_w (P, 4) weights to the up/down/left/right
    neighbour (0 at the border). Potts: lam * w_pq * [atomset_p != atomset_q]."""
    S, P = unary.shape
    sup = np.array([support_of(cand, subs, np.full(P, s)) for s in range(S)])  # (S, P, k)
    sup = np.sort(sup, axis=-1)
    label = np.argmin(unary, axis=0)
    y, x = np.divmod(np.arange(P), size)
    nb = np.stack([
        np.where(y > 0, np.arange(P) - size, -1),
        np.where(y < size - 1, np.arange(P) + size, -1),
        np.where(x > 0, np.arange(P) - 1, -1),
        np.where(x < size - 1, np.arange(P) + 1, -1),
    ], axis=1)
    for _ in range(sweeps):
        cur = sup[label, np.arange(P)]  # (P, k) sorted atom sets
        cost = unary.copy()
        for j in range(4):
            q = nb[:, j]
            ok = q >= 0
            qs = cur[np.where(ok, q, 0)]  # (P, k)
            differ = (sup != qs[None]).any(-1)  # (S, P)
            cost += lam * (edge_w[:, j] * ok)[None] * differ
        new = np.argmin(cost, axis=0)
        if (new == label).all():
            break
        label = new
    return label


def dichromatic_costs(case: dict, atoms: np.ndarray, model_error: float = 0.0) -> np.ndarray:
    """(J, P): per texel and atom j, sum over the set's images of the RGB chi^2 of the exact
    NNLS fit R_m ~ a_m E_j + h_m L (the dichromatic model with material j alone). A texel's
    highlight changes from image to image but its material does not, so the images' fits
    meet at the material: this ranks materials far better than the chromaticity of one
    image or of the sum (which highlights pull towards the illuminant's)."""
    rgb, C = case["rgb"], case["C"]
    M, P, _ = rgb.shape
    argb = atoms @ C.T
    J = atoms.shape[0] - 1
    sig2 = rgb_sigma(case, model_error) ** 2  # (M, P)
    h = argb[J]
    out = np.zeros((J, P))
    for j in range(J):
        e = argb[j]
        A = np.stack([e, h])  # (2, 3)
        AtA = A @ A.T
        inv = np.linalg.inv(AtA + (1e-12 * np.trace(AtA) + 1e-30) * np.eye(2))
        w = (rgb @ A.T) @ inv  # (M, P, 2)
        res2 = ((rgb - w @ A) ** 2).sum(-1)
        # one-atom fits for the infeasible ones
        a1 = np.maximum(rgb @ e / max(e @ e, 1e-300), 0); r1 = ((rgb - a1[..., None] * e) ** 2).sum(-1)
        a2 = np.maximum(rgb @ h / (h @ h), 0); r2 = ((rgb - a2[..., None] * h) ** 2).sum(-1)
        feas = (w >= 0).all(-1)
        best = np.where(feas, res2, np.minimum(r1, r2))
        out[j] = (best / sig2).sum(0)
    return out


def dichromatic_candidates(case: dict, atoms: np.ndarray, n: int, model_error: float = 0.0):
    """(P, n + 1): the n atoms with the lowest dichromatic_costs, then the highlight atom."""
    d = dichromatic_costs(case, atoms, model_error)
    n = min(n, d.shape[0])
    near = np.argsort(d, axis=0)[:n].T
    return np.hstack([near, np.full((near.shape[0], 1), atoms.shape[0] - 1)])


# ------------------------------------------------------------------ library

def spectral_angles(learnt: np.ndarray, true: np.ndarray) -> dict:
    """Angles [deg] between the true endmembers and their nearest learnt atom (and the
    reverse), highlight atoms excluded from both."""
    a = learnt[:-1] / np.linalg.norm(learnt[:-1], axis=1, keepdims=True).clip(1e-300)
    t = true[:-1] / np.linalg.norm(true[:-1], axis=1, keepdims=True).clip(1e-300)
    ang = np.degrees(np.arccos(np.clip(t @ a.T, -1, 1)))  # (Jt, Jl)
    return {
        "true->learnt median": float(np.median(ang.min(1))),
        "true->learnt p90": float(np.percentile(ang.min(1), 90)),
        "learnt->true median": float(np.median(ang.min(0))),
    }


def update_atoms(case: dict, atoms: np.ndarray, support: np.ndarray, ridge: float = 0.1,
                 keep_highlight: bool = True) -> np.ndarray:
    """Per band, the atoms that best explain every band shot with the per-image abundances
    (exact NNLS of the RGB on each texel's support), a J x J ridge regression held towards
    the previous atoms (as endmember_mixture._update_atoms, but on the chosen supports)."""
    A = atoms.shape[0]
    argb = atoms @ case["C"].T
    new = atoms.copy()
    W = {}
    for m in np.unique(case["shot_image"]):
        W[m] = nnls_support(argb, case["rgb"][m], support)
    sup = np.where(support >= 0, support, 0)
    for b in np.unique(case["shot_band"]):
        gram = np.zeros((A, A)); rhs = np.zeros(A)
        for i in np.flatnonzero(case["shot_band"] == b):
            m = case["shot_image"][i]
            w = W[m]
            dense = np.zeros((w.shape[0], A))
            np.add.at(dense, (np.arange(w.shape[0])[:, None], sup), w)
            gram += dense.T @ dense
            rhs += dense.T @ case["shots"][i]
        r = ridge * max(np.trace(gram) / A, 1e-300)
        new[:, b] = np.linalg.solve(gram + r * np.eye(A), rhs + r * atoms[:, b])
    if keep_highlight:
        new[-1] = atoms[-1]
    return np.maximum(new, 0)
