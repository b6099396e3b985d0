"""Helper D (issue 38 item 2): SISAL, a minimum-volume simplex that need not touch the data.

Bioucas-Dias (2009), "A variable splitting augmented Lagrangian approach to linear spectral
unmixing" (SISAL): with the data in a (p-1)-dimensional affine subspace and homogeneous
coordinates y~ = [z; 1], the simplex's vertex matrix M~ (p x p, last row ones) and its
inverse Q = M~^-1 give each point's abundances a = Q y~ (which sum to one exactly when
1^T Q = e_p^T). SISAL minimises

    -log |det Q| + lam * sum_{i,n} hinge(-(Q Y~)_{in})

(the volume of the simplex is |det M~| / (p-1)! = 1 / (|det Q| (p-1)!); the hinge charges
every negative abundance, so the data need not lie inside: a soft enclosure that tolerates
noise and outliers). The paper solves it by a sequence of quadratic approximations of the
log-det split with SALSA; here the same objective is solved with a Huber-smoothed hinge
(width ``tau``) by L-BFGS over the free rows of Q (the last row fixed by the sum-to-one
constraint), on whitened coordinates. Started, as in the paper, from an enclosing simplex: the SPA (successive
projection) picks inflated about their mean until every point is inside.

Data: rows of X at unit channel-balanced brightness (the library's atoms' scale), so the
sum-to-one constraint is the brightness hyperplane; the subspace is the data's mean plus
its p-1 leading principal directions.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize


def subspace(X: np.ndarray, p: int):
    """Mean and the p-1 leading principal directions of the rows of X; the data's
    coordinates there, ``(N, p-1)``."""
    c0 = X.mean(0)
    _, _, vt = np.linalg.svd(X - c0, full_matrices=False)
    U = vt[: p - 1].T
    return c0, U, (X - c0) @ U


def spa(Yh: np.ndarray, p: int) -> np.ndarray:
    """Successive projection algorithm (Araujo et al. 2001; Gillis and Vavasis 2014): p
    columns of the homogeneous data, each the largest after projecting out those taken."""
    R = Yh.copy()
    idx = []
    for _ in range(p):
        j = int(np.argmax((R * R).sum(0)))
        idx.append(j)
        u = R[:, j] / np.linalg.norm(R[:, j])
        R = R - np.outer(u, u @ R)
    return np.array(idx)


def enclosing_start(Yh: np.ndarray, p: int) -> np.ndarray:
    """A simplex enclosing every point: the SPA picks inflated about their mean."""
    V = Yh[:-1, spa(Yh, p)]
    g = V.mean(1, keepdims=True)
    s = 1.0
    for _ in range(200):
        M = np.vstack([g + s * (V - g), np.ones((1, p))])
        try:
            a = np.linalg.solve(M, Yh)
        except np.linalg.LinAlgError:
            s *= 1.5
            continue
        if a.min() >= 0:
            return M
        s *= 1.3
    raise RuntimeError("no enclosing start")


def _huber_hinge(u: np.ndarray, tau: float):
    """Value and derivative of a hinge max(u, 0) smoothed over [0, tau]."""
    val = np.where(u <= 0, 0.0, np.where(u < tau, u * u / (2 * tau), u - tau / 2))
    der = np.where(u <= 0, 0.0, np.where(u < tau, u / tau, 1.0))
    return val, der


def sisal(Z: np.ndarray, p: int, *, lam: float = 10.0, tau: float = 1e-3, maxiter: int = 3000,
          weights: np.ndarray | None = None):
    """SISAL on the points Z ``(N, p-1)``; returns the vertices ``(p, p-1)`` and the
    abundances ``(N, p)``. ``weights``: a per-point factor on the hinge (the points'
    precision, so noisier points may lie further out)."""
    N = Z.shape[0]
    # the minimum-volume simplex is affine-equivariant: solve on whitened coordinates (the
    # principal directions' spreads differ by orders of magnitude) and map the vertices back
    mu, sd = Z.mean(0), Z.std(0).clip(1e-300)
    Yh = np.vstack([((Z - mu) / sd).T, np.ones((1, N))])
    w = np.ones(N) if weights is None else weights
    M0 = enclosing_start(Yh, p)
    Q0 = np.linalg.inv(M0)
    ep = np.zeros(p)
    ep[-1] = 1.0

    def full(r):
        R = r.reshape(p - 1, p)
        return np.vstack([R, ep - R.sum(0)])

    def fg(r):
        Q = full(r)
        sign, ld = np.linalg.slogdet(Q)
        if sign == 0 or not np.isfinite(ld):
            return 1e30, np.zeros_like(r)
        A = Q @ Yh
        h, dh = _huber_hinge(-A, tau)
        f = -ld + lam * float((h * w).sum())
        G = -np.linalg.inv(Q).T - lam * (dh * w) @ Yh.T
        g = G[:-1] - G[-1][None]
        return f, g.ravel()

    out = minimize(fg, Q0[:-1].ravel(), jac=True, method="L-BFGS-B", options={"maxiter": maxiter})
    Q = full(out.x)
    M = np.linalg.inv(Q)
    return M[:-1].T * sd + mu, (Q @ Yh).T
