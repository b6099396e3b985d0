"""Helper F2 (issue 38, item 2): minimum-volume endmember extraction for the run library.

Clustering puts each atom at the centre of a chromaticity cluster, i.e. inside the data's
convex hull; materials that never appear pure (yarns, ink dots, beads) sit at vertices no
pixel reaches. A minimum-volume simplex method does not need pure pixels: the data term
pushes the simplex's vertices out until it encloses the texels' spectra, the volume term
keeps it as small as the data allow.

Data: per texel p (the texel grid is the same in every set of a run), the least-squares
shape g_b(p) = sum_k beta_pk D_k(p) / sum_k beta_pk^2 over the pooled sets' shots k of band
b (beta: the texel's channel-balanced RGB brightness in the shot's image, in the library's
channel scale) -- `_pooled_shape` of the library with one label per texel. On that shape
the model is linear with sum-to-one abundances: g(p) = a_p E, a_p >= 0, sum a_p = 1, the
atoms E per unit brightness (as the library's), the highlight atom among them.

Method: min-vol NMF with a log-det volume (Miao and Qi 2007's MVC-NMF in the log-det form
of Fu, Huang, Yang, Ma and Sidiropoulos 2016 / Leplat, Gillis and Ang 2019):

    min_{E >= 0, A in simplex}  sum_p w_p ||g(p) - a_p E||^2 + lam * logdet(E E^T + delta I)

initialised from the current library; A by projected fast gradient on the simplex, E by a
projected fast gradient on the majorised problem (logdet <= tr(Y E E^T), Y = (E0 E0^T +
delta I)^-1); the highlight atom is kept fixed. lam is relative (lam_tilde x the initial
fit / |initial logdet|, Leplat et al.'s normalisation); delta = 0.1 x the mean squared
atom norm.
"""

from __future__ import annotations

import numpy as np


def texel_shapes(inputs, scale: np.ndarray, n_sets: int, low_only: bool = False):
    """Per texel and band the LS shape over the pooled sets, ``(P, W)``, and its precision
    (sum of beta^2 over the band's shots) ``(P, W)``. ``inputs``: the pooled sets' inputs
    (each set the same number of images, the same texel grid). ``low_only``: only the
    shots whose image shows the texel at or below its median brightness over the pooled
    images (a highlight adds brightness; each band is shot in a different image, so a
    highlight in one band's image bends the texel's shape away from any mixture)."""
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity

    P = inputs.height * inputs.width
    rgb = inputs.rgb_pixels().T
    beta, _ = chromaticity(rgb, scale)
    W = inputs.n_wavelength
    per_texel = beta.reshape(-1, P)
    low = per_texel <= np.median(per_texel, axis=0)[None]
    num = np.zeros((P, W))
    den = np.zeros((P, W))
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
        bm = beta[m * P : (m + 1) * P]
        if low_only:
            bm = np.where(low[m], bm, 0.0)
        num[:, b] += bm * inputs.band_data[i].ravel()
        den[:, b] += bm * bm
    return num / np.maximum(den, 1e-300), den


def simplex_project(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` projected onto the unit simplex (Duchi et al. 2008)."""
    n, k = v.shape
    u = -np.sort(-v, axis=1)
    css = np.cumsum(u, axis=1) - 1.0
    ind = np.arange(1, k + 1)
    cond = u - css / ind > 0
    rho = k - 1 - np.argmax(cond[:, ::-1], axis=1)
    theta = css[np.arange(n), rho] / (rho + 1)
    return np.maximum(v - theta[:, None], 0.0)


def abundance_step(X, w, E, A, iters=30):
    """Projected fast gradient on the simplex for sum_p w_p ||x_p - a_p E||^2."""
    G = E @ E.T
    L = np.linalg.eigvalsh(G)[-1] * w.max() + 1e-300
    XE = X @ E.T
    Y = A.copy()
    t = 1.0
    for _ in range(iters):
        grad = w[:, None] * (Y @ G - XE)
        An = simplex_project(Y - grad / L)
        tn = (1 + np.sqrt(1 + 4 * t * t)) / 2
        Y = An + (t - 1) / tn * (An - A)
        A, t = An, tn
    return A


def atom_step(X, w, A, E, lam, delta, fixed, iters=30):
    """Projected fast gradient on sum_p w_p ||x_p - a_p E||^2 + lam tr(Y E E^T), E >= 0,
    Y = (E E^T + delta I)^-1 at the current E (majoriser of the log-det); rows ``fixed``
    kept."""
    Aw = A * w[:, None]
    H = A.T @ Aw
    R = Aw.T @ X
    Yinv = np.linalg.inv(E @ E.T + delta * np.eye(E.shape[0]))
    Q = H + lam * Yinv
    L = np.linalg.eigvalsh(Q)[-1] + 1e-300
    keep = E[fixed].copy()
    Z = E.copy()
    t = 1.0
    for _ in range(iters):
        En = np.maximum(Z - (Q @ Z - R) / L, 0.0)
        En[fixed] = keep
        tn = (1 + np.sqrt(1 + 4 * t * t)) / 2
        Z = En + (t - 1) / tn * (En - E)
        E, t = En, tn
    return E


def objective(X, w, A, E, lam, delta):
    fit = float((w[:, None] * (X - A @ E) ** 2).sum())
    _, ld = np.linalg.slogdet(E @ E.T + delta * np.eye(E.shape[0]))
    return fit, ld, fit + lam * ld


def minvol(X, w, E0, *, lam_tilde=0.1, rounds=50, fixed=(-1,), delta_rel=0.1, verbose=False):
    """Min-vol NMF from ``E0`` (rows: atoms, highlight last). Returns the atoms."""
    E = np.maximum(E0.astype(np.float64), 0.0)
    delta = delta_rel * float(np.mean((E * E).sum(1)))
    A = abundance_step(X, w, E, np.full((X.shape[0], E.shape[0]), 1.0 / E.shape[0]), iters=200)
    fit0, ld0, _ = objective(X, w, A, E, 0.0, delta)
    lam = lam_tilde * fit0 / max(abs(ld0), 1e-12)
    fixed = [f % E.shape[0] for f in fixed]
    for r in range(rounds):
        E = atom_step(X, w, A, E, lam, delta, fixed)
        A = abundance_step(X, w, E, A)
        if verbose and (r % 10 == 0 or r == rounds - 1):
            print(r, objective(X, w, A, E, lam, delta), flush=True)
    return E, A


def matte_shapes(inputs, scale: np.ndarray, light: np.ndarray, rounds: int = 3):
    """Per texel the matte (highlight-free) shape over the pooled sets, ``(P, W)`` at unit
    channel-balanced brightness, and its precision ``(P, W)``.

    Each band is shot in a different image, so a highlight in one band's image bends the
    texel's pooled shape away from any mixture of the materials. Per texel p and image m the
    RGB is fitted as ``s_pm C x_p + h_pm C L`` (``s, h >= 0``; ``x_p`` the current matte
    shape, ``L`` the light / highlight atom); each shot's highlight ``h_pm L_b`` is taken
    off and the shape re-pooled with the weights ``s_pm`` (dichromatic model, Shafer 1985),
    ``rounds`` times from the plain pooled shape.
    """
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import chromaticity

    P = inputs.height * inputs.width
    W = inputs.n_wavelength
    c = np.asarray(inputs.camera_matrix, dtype=np.float64)
    rgb = inputs.rgb_pixels().T.reshape(-1, P, 3)
    light = np.asarray(light, dtype=np.float64)
    lc = c @ light
    x, den = texel_shapes(inputs, scale, 0)
    for _ in range(rounds):
        x = _unit_brightness(x, c, scale)
        q = x @ c.T  # (P, 3)
        qq, ql, ll = (q * q).sum(1), q @ lc, lc @ lc
        det = np.maximum(qq * ll - ql * ql, 1e-300)
        s = ((rgb * q).sum(-1) * ll - (rgb @ lc) * ql) / det  # (M, P)
        h = ((rgb @ lc) * qq[None] - (rgb * q).sum(-1) * ql) / det
        neg = h < 0
        h = np.where(neg, 0.0, h)
        s = np.where(neg, (rgb * q).sum(-1) / np.maximum(qq, 1e-300), s)
        s = np.maximum(s, 0.0)
        num = np.zeros((P, W))
        den = np.zeros((P, W))
        for i, (band, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
            num[:, band] += s[m] * (inputs.band_data[i].ravel() - h[m] * light[band])
            den[:, band] += s[m] * s[m]
        x = np.maximum(num / np.maximum(den, 1e-300), 0.0)
    return _unit_brightness(x, c, scale), den


def _unit_brightness(x: np.ndarray, c: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Rows of ``x`` scaled to unit channel-balanced brightness; rows whose brightness is
    not clearly positive (dark noisy texels) are set to the mean row's shape."""
    b = ((x @ c.T) / scale).sum(1)
    ok = b > 1e-3 * np.median(np.abs(b))
    out = np.empty_like(x)
    out[ok] = x[ok] / b[ok, None]
    mean = x[ok].sum(0) / b[ok].sum()
    out[~ok] = mean
    return out


def refine_minvol(inputs, em, *, lam=0.1, rounds=3, rgb_error=0.02, delta_rel=0.1, candidates=3, spatial=2):
    """Shot-level variant: helper F's alternation (refine.py: per pixel and image NNLS
    abundances from the RGB among the chromaticity candidates, then a joint least-squares
    atom update over every band shot and the RGB through C) with the log-det volume term
    majorised as ``lam x scale x delta x tr(Y E E^T)`` (``Y = (E E^T + delta I)^-1`` at the
    round's atoms; ``scale``: the mean diagonal of the band grams), highlight atom kept."""
    from refine import abundances

    from spectralize.nodes.reconstruction.estimators.endmember_mixture import Endmembers, band_noise_sigma

    sigma = band_noise_sigma(inputs)
    atoms = em.atoms.copy()
    delta = delta_rel * float(np.mean((atoms * atoms).sum(1)))
    for _ in range(rounds):
        cur = Endmembers(atoms, em.centres, em.scale)
        dense, rgb = abundances(inputs, cur, candidates, spatial)
        new = _atom_update_vol(inputs, atoms, dense, rgb, sigma, lam=lam, rgb_error=rgb_error, delta=delta)
        new[-1] = atoms[-1]
        atoms = new
    return Endmembers(atoms, em.centres, em.scale)


def _atom_update_vol(inputs, atoms, dense, rgb, sigma, *, lam, rgb_error, delta, ridge=0.01):
    A, W = atoms.shape
    P = inputs.height * inputs.width
    grams = np.zeros((W, A, A))
    rhs = np.zeros((W, A))
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
        wm = dense[m * P : (m + 1) * P]
        grams[b] += wm.T @ wm / sigma[i] ** 2
        rhs[b] += wm.T @ inputs.band_data[i].ravel().astype(np.float64) / sigma[i] ** 2
    H = np.zeros((W * A, W * A))
    for b in range(W):
        H[b * A : (b + 1) * A, b * A : (b + 1) * A] = grams[b]
    R = rhs.copy()
    scale = np.trace(grams.sum(0)) / (A * W)
    c = np.asarray(inputs.camera_matrix, dtype=np.float64)
    if rgb_error:
        omega = 1.0 / np.maximum((rgb_error * np.abs(rgb).sum(1) / 3.0) ** 2, 1e-30)
        g_rgb = (dense * omega[:, None]).T @ dense
        H += np.kron(c.T @ c, g_rgb)
        R += (((dense * omega[:, None]).T @ rgb) @ c).T
    if lam:
        Y = np.linalg.inv(atoms @ atoms.T + delta * np.eye(A))
        H += lam * scale * delta * np.kron(np.eye(W), Y)
    H += ridge * scale * np.eye(W * A)
    R += ridge * scale * atoms.T
    x = np.linalg.solve(H, R.ravel())
    return np.maximum(x.reshape(W, A).T, 0.0)
