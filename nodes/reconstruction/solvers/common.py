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
    "counting_iterations",
    "needs_cube",
    "DEFAULT_TOLERANCE",
    "DEFAULT_MAX_ITERATIONS",
    "vdot",
    "VectorOps",
    "NUMPY",
    "COMPILED",
    "preconditioned_cg",
]

DEFAULT_TOLERANCE = 1e-3
"""Stop when the relative normal-equation residual ``||A^T b - A^T A S|| / ||A^T b||`` is below it."""

DEFAULT_MAX_ITERATIONS = 2000
"""Iteration limit of every solver."""

Callback = Callable[[int, np.ndarray], None]
"""``callback(iteration, cube)``, called after every iteration (benchmarks' convergence curves).

A callback made by :func:`counting_iterations` gets ``cube=None``: a solver that iterates on
another layout then skips building the cube each iteration."""


def counting_iterations(count: Callable[[int], None]) -> Callback:
    """A :data:`Callback` that only wants the iteration number (e.g. a progress bar)."""

    def callback(iteration: int, cube: np.ndarray | None) -> None:
        count(iteration)

    callback.needs_cube = False  # type: ignore[attr-defined]
    return callback


def needs_cube(callback: Callback | None) -> bool:
    """Whether ``callback`` looks at the cube (see :func:`counting_iterations`)."""
    return callback is not None and getattr(callback, "needs_cube", True)


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


@dataclass(frozen=True)
class VectorOps:
    """The vector updates of :func:`preconditioned_cg`.

    Attributes
    ----------
    dot
        ``dot(a, b)``: ``sum(a * b)`` as a float.
    step
        ``step(x, r, p, q, alpha)``: ``x += alpha p``, ``r -= alpha q`` in place; returns
        the new ``r . r``.
    direction
        ``direction(p, z, beta)``: ``p = z + beta p`` in place.
    """

    dot: Callable[[np.ndarray, np.ndarray], float]
    step: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float], float]
    direction: Callable[[np.ndarray, np.ndarray, float], None]


def _numpy_step(x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, alpha: float) -> float:
    alpha = x.dtype.type(alpha)
    x += alpha * p
    q *= alpha
    r -= q
    return vdot(r, r)


def _numpy_direction(p: np.ndarray, z: np.ndarray, beta: float) -> None:
    p *= p.dtype.type(beta)
    p += z


NUMPY = VectorOps(vdot, _numpy_step, _numpy_direction)
"""Vector updates in numpy (temporaries; any array layout)."""


def _compiled(name: str) -> Callable:
    def call(*args):
        from .. import kernels  # numba compiles on first use, not on import

        return getattr(kernels, name)(*args)

    call.__name__ = name
    return call


COMPILED = VectorOps(_compiled("dot"), _compiled("cg_step"), _compiled("cg_direction"))
"""Vector updates fused into single compiled passes (:mod:`..kernels`); C-contiguous arrays."""


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
    vectors: VectorOps = NUMPY,
) -> tuple[np.ndarray, list[float], int]:
    """Preconditioned conjugate gradients on a symmetric positive definite system, in place.

    Solves ``operator(x) = rhs`` from the start ``x`` with residual ``r = rhs - operator(x)``
    (both updated in place), until the relative residual ``||r|| / rhs_norm`` is below
    ``tolerance`` or after ``max_iterations``; it stops early if ``operator`` is not positive
    along a search direction. ``vectors`` does the vector updates (:data:`NUMPY`, or
    :data:`COMPILED` for C-contiguous float arrays). ``operator`` and
    ``apply_preconditioner`` may return the same buffer on every call, even one buffer for
    both: each result is used up before the next call of either.

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
    dot = vectors.dot
    z = apply_preconditioner(r)
    p = z.copy()
    rz = dot(r, z)
    history = [np.sqrt(dot(r, r)) / rhs_norm]
    iterations = 0
    while history[-1] > tolerance and iterations < max_iterations:
        q = operator(p)
        pq = dot(p, q)
        if not pq > 0:
            break
        rr = vectors.step(x, r, p, q, dtype.type(rz / pq))
        del q
        iterations += 1
        history.append(np.sqrt(max(rr, 0.0)) / rhs_norm)
        if callback is not None:
            callback(iterations, x)
        if history[-1] <= tolerance:
            break
        z = apply_preconditioner(r)
        rz_new = dot(r, z)
        vectors.direction(p, z, dtype.type(rz_new / rz))
        rz = rz_new
    return x, history, iterations
