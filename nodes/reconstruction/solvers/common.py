"""What every solver of eq. 1 shares: its result record, defaults, a dot product and the PCG loop.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "SolverResult",
    "Callback",
    "DEFAULT_TOLERANCE",
    "DEFAULT_MAX_ITERATIONS",
    "vdot",
    "preconditioned_cg",
]

DEFAULT_TOLERANCE = 1e-3
"""Stop when the relative normal-equation residual ``||A^T b - A^T A S|| / ||A^T b||`` is below it."""

DEFAULT_MAX_ITERATIONS = 2000
"""Iteration limit of every solver."""

Callback = Callable[[int, np.ndarray], None]
"""``callback(iteration, cube)``, called after every iteration (benchmarks' convergence curves)."""


@dataclass
class SolverResult:
    """What a solver returns.

    Attributes
    ----------
    cube
        ``S``, ``(n_wavelength, n_image, height, width)``.
    iterations
        Iterations done.
    residual_history
        Relative normal-equation residual before the first and after every iteration.
    converged
        Whether the residual reached the tolerance.
    wall_time
        Seconds spent in the solver (set-up of its preconditioner and initial guess included).
    method
        Name of the method in
        :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`.
    info
        Method-specific settings the solve used (``ridge``, ``prior``, ``precondition``).
    """

    cube: np.ndarray
    iterations: int
    residual_history: np.ndarray
    converged: bool
    wall_time: float
    method: str
    info: dict = field(default_factory=dict)


def vdot(a: np.ndarray, b: np.ndarray) -> float:
    """``sum(a * b)`` as a Python float.

    einsum, not BLAS: no thread pool to wait for on a busy machine (see
    :func:`~spectralize.nodes.reconstruction.operators._einsum`).
    """
    return float(np.einsum("i,i->", a.ravel(), b.ravel(), optimize=False))


def preconditioned_cg(
    operator: Callable[[np.ndarray], np.ndarray],
    x: np.ndarray,
    r: np.ndarray,
    rhs_norm: float,
    apply_preconditioner: Callable[[np.ndarray], np.ndarray],
    *,
    tolerance: float,
    max_iterations: int,
    dtype: np.dtype,
    callback: Callback | None = None,
) -> tuple[np.ndarray, list[float], int]:
    """Preconditioned conjugate gradients on a symmetric positive definite system, in place.

    Solves ``operator(x) = rhs`` from the start ``x`` with residual ``r = rhs - operator(x)``
    (both updated in place), until the relative residual ``||r|| / rhs_norm`` is below
    ``tolerance`` or after ``max_iterations``; it stops early if ``operator`` is not positive
    along a search direction.

    Returns
    -------
    x, history, iterations
        The solution, the relative residual before the first and after every iteration, and
        the number of iterations done.

    References
    ----------
    .. [1] Shewchuk, J. R. (1994). An Introduction to the Conjugate Gradient Method Without
       the Agonizing Pain, section B3.
    """
    z = apply_preconditioner(r)
    p = z.copy()
    rz = vdot(r, z)
    history = [np.sqrt(vdot(r, r)) / rhs_norm]
    iterations = 0
    while history[-1] > tolerance and iterations < max_iterations:
        q = operator(p)
        pq = vdot(p, q)
        if not pq > 0:
            break
        step = dtype.type(rz / pq)
        x += step * p
        q *= step
        r -= q
        del q
        iterations += 1
        history.append(np.sqrt(vdot(r, r)) / rhs_norm)
        if callback is not None:
            callback(iterations, x)
        if history[-1] <= tolerance:
            break
        z = apply_preconditioner(r)
        rz_new = vdot(r, z)
        p *= dtype.type(rz_new / rz)
        p += z
        rz = rz_new
    return x, history, iterations
