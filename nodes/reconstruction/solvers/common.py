"""What every solver of eq. 1 shares: its result record, callbacks, the vector updates,
the PCG loop and the pixel-major PCG run that both block-Jacobi solvers are.

All solvers stop when the relative residual of the normal equations ``||A^T b - A^T A S|| /
||A^T b||`` falls below ``tolerance``, or after ``max_iterations``.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM
   (preconditioned CG, algorithm 9.1).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..operators import PixelOrder
    from .preconditioner import BlockJacobiPreconditioner

__all__ = [
    "SolverResult",
    "Callback",
    "counting_iterations",
    "wants_residual",
    "needs_cube",
    "vdot",
    "VectorOps",
    "NUMPY",
    "COMPILED",
    "preconditioned_cg",
    "PixelOperator",
    "pixel_pcg",
]

Callback = Callable[[int, np.ndarray], None]
"""``callback(iteration, cube)``, called after every iteration (benchmarks' convergence curves).

A callback made by :func:`counting_iterations` gets ``cube=None``: a solver that iterates on
another layout then skips building the cube each iteration."""


def counting_iterations(count: Callable[..., None], *, residual: bool = False) -> Callback:
    """A :data:`Callback` that only wants the iteration number (e.g. a progress bar); with
    ``residual``, ``count(iteration, residual)`` also gets the relative residual after the
    iteration (the convergence rate a progress display estimates the time left from)."""

    def callback(iteration: int, cube: np.ndarray | None, *relative: float) -> None:
        count(iteration, *relative[:1]) if residual else count(iteration)

    callback.needs_cube = False  # type: ignore[attr-defined]
    callback.wants_residual = residual  # type: ignore[attr-defined]
    return callback


def wants_residual(callback: Callback | None) -> bool:
    """Whether ``callback`` takes the relative residual as a third argument."""
    return callback is not None and getattr(callback, "wants_residual", False)


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
        The implementation that solved it (its function's name, e.g. ``"prior_pcg"``); the
        preset's name is the caller's (:data:`~..methods.RECONSTRUCTION_METHODS`).
    info
        Implementation-specific settings the solve used (``ridge``, ``prior``, ``precondition``).
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
            callback(iterations, x, *history[-1:] if wants_residual(callback) else ())
        if history[-1] <= tolerance:
            break
        z = apply_preconditioner(r)
        rz_new = dot(r, z)
        vectors.direction(p, z, dtype.type(rz_new / rz))
        rz = rz_new
    return x, history, iterations


PixelOperator = Callable[[np.ndarray, np.ndarray], "np.ndarray | tuple[np.ndarray, float]"]
"""``operator(vector, out) -> out``: the regularised normal operator ``H`` applied to a
pixel-major vector ``(n_pixels, n_wavelength)``, written into ``out``; or ``-> (out,
vector . out)`` where its pass computes the curvature too (:func:`pixel_pcg` then skips a
dot)."""


def pixel_pcg(
    operator: PixelOperator,
    x: np.ndarray,
    rhs: np.ndarray,
    preconditioner: BlockJacobiPreconditioner,
    order: PixelOrder,
    *,
    precondition: bool | str,
    tolerance: float,
    max_iterations: int,
    callback: Callback | None,
) -> tuple[np.ndarray, list[float], int]:
    """Block-Jacobi preconditioned CG on ``H x = rhs`` for pixel-major vectors, in place.

    The run both PCG solvers share (:func:`~.block_jacobi_pcg.block_jacobi_pcg` and
    :func:`~.prior_pcg.prior_pcg`); they differ only in the terms of ``H``, ``rhs`` and the
    preconditioner's diagonal. Vectors are pixel-major in ``order`` (the layout of the
    compiled passes, :mod:`..kernels`), the vector updates compiled (:data:`COMPILED`); the
    operator and the preconditioner write into one shared buffer (CG uses up ``H p`` before
    it asks for ``M^-1 r`` and that before the next ``H p``).

    Parameters
    ----------
    operator
        ``H``, see :data:`PixelOperator`.
    x
        Start, pixel-major in ``order``; overwritten with the solution.
    rhs
        Right-hand side, same layout (not changed).
    preconditioner
        Its block-Jacobi preconditioner, built in ``order``.
    order
        The pixel order of the vectors (the callback gets band-major cubes).
    precondition
        ``True``: block Jacobi; ``"jacobi"``: its scalar diagonal; ``False``: none (the
        last two for measurements).
    tolerance, max_iterations, callback
        As for :func:`preconditioned_cg`; ``callback`` gets the cube ``(w, m, y, x)`` (or
        None, see :func:`counting_iterations`).

    Returns
    -------
    x, history, iterations
        As :func:`preconditioned_cg` (``x`` still pixel-major).
    """
    buffer = np.empty_like(x)

    def apply_operator(direction: np.ndarray) -> np.ndarray:
        return _applied(operator(direction, buffer))[0]

    rhs_norm = np.sqrt(COMPILED.dot(rhs, rhs)) or 1.0
    r = rhs - _applied(operator(x, buffer))[0]
    cube_wanted = needs_cube(callback)

    def band_major_callback(iteration: int, vector: np.ndarray, *relative: float) -> None:
        callback(iteration, order.to_cube(vector) if cube_wanted else None, *relative)

    band_major_callback.wants_residual = wants_residual(callback)  # type: ignore[attr-defined]
    wrapped = None if callback is None else band_major_callback
    if precondition is True:
        return _block_jacobi_cg(
            operator, x, r, rhs_norm, preconditioner, buffer, tolerance, max_iterations, wrapped
        )
    if precondition == "jacobi":
        scalar = preconditioner.inverse_scalar_diagonal_pixels()

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return residual * scalar

    elif precondition:

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return preconditioner.apply_pixels(residual, out=buffer)

    else:

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return residual.copy()

    return preconditioned_cg(
        apply_operator,
        x,
        r,
        rhs_norm,
        apply_preconditioner,
        tolerance=tolerance,
        max_iterations=max_iterations,
        dtype=x.dtype,
        callback=wrapped,
        vectors=COMPILED,
    )


def _applied(result: np.ndarray | tuple[np.ndarray, float]) -> tuple[np.ndarray, float | None]:
    """A :data:`PixelOperator`'s ``out``, and ``vector . out`` where it returned it too."""
    if isinstance(result, tuple):
        return result
    return result, None


def _block_jacobi_cg(
    operator: PixelOperator,
    x: np.ndarray,
    r: np.ndarray,
    rhs_norm: float,
    preconditioner: BlockJacobiPreconditioner,
    buffer: np.ndarray,
    tolerance: float,
    max_iterations: int,
    callback: Callback | None,
) -> tuple[np.ndarray, list[float], int]:
    """:func:`preconditioned_cg` with the block-Jacobi preconditioner, in fewer passes.

    The same iteration, its passes fused: ``p . H p`` from the operator's own pass where it
    returns it (else one dot), CG's update of ``x`` and ``r`` with ``M^-1 r`` and both dots
    in one pass (:meth:`~.preconditioner.BlockJacobiPreconditioner.step_pixels`, ``z`` in
    the operator's buffer), then the new direction: three passes over the cube per
    iteration besides the operator, instead of six.
    """
    z = preconditioner.apply_pixels(r, out=buffer)
    rz = COMPILED.dot(r, z)
    p = z.copy()
    history = [np.sqrt(COMPILED.dot(r, r)) / rhs_norm]
    iterations = 0
    while history[-1] > tolerance and iterations < max_iterations:
        q, pq = _applied(operator(p, buffer))
        if pq is None:
            pq = COMPILED.dot(p, q)
        if not pq > 0:
            break
        rr, rz_new = preconditioner.step_pixels(x, r, p, q, rz / pq)  # z now in ``buffer``
        iterations += 1
        history.append(np.sqrt(max(rr, 0.0)) / rhs_norm)
        if callback is not None:
            callback(iterations, x, *history[-1:] if wants_residual(callback) else ())
        if history[-1] <= tolerance:
            break
        COMPILED.direction(p, buffer, x.dtype.type(rz_new / rz))
        rz = rz_new
    return x, history, iterations
