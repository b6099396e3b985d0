"""What every solver of eq. 1 shares: its result record, callbacks, and the pixel-major PCG
run (one loop) that both block-Jacobi solvers are.

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

from spectralize.schemas.errors import ParameterError

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
    "PixelOperator",
    "IterateCallback",
    "CgStep",
    "pixel_pcg",
]

Callback = Callable[[int, np.ndarray | None], None]
"""``callback(iteration, cube)``, called after every iteration (benchmarks' convergence curves).

A callback made by :func:`counting_iterations` gets ``cube=None``: a solver that iterates on
another layout then skips building the cube each iteration; one made with ``residual=True``
also gets the relative residual as a third argument (:func:`wants_residual`)."""


def counting_iterations(count: Callable[..., None], *, residual: bool = False) -> Callback:
    """A :data:`Callback` that only wants the iteration number (e.g. a progress bar); with
    ``residual``, ``count(iteration, residual)`` also gets the relative residual after the
    iteration (the convergence rate a progress display estimates the time left from)."""

    def callback(iteration: int, cube: np.ndarray | None, *relative: float) -> None:
        count(iteration, *relative[:1]) if residual else count(iteration)

    callback.needs_cube = False  # type: ignore[attr-defined]
    callback.wants_residual = residual  # type: ignore[attr-defined]
    return callback


def wants_residual(callback: Callable[..., object] | None) -> bool:
    """Whether ``callback`` takes the relative residual as a third argument."""
    return callback is not None and getattr(callback, "wants_residual", False)


def needs_cube(callback: Callable[..., object] | None) -> bool:
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


PixelOperator = Callable[[np.ndarray, np.ndarray], "np.ndarray | tuple[np.ndarray, float]"]
"""``operator(vector, out) -> out``: the regularised normal operator ``H`` applied to a
pixel-major vector ``(n_pixels, n_wavelength)``, written into ``out``; or ``-> (out,
vector . out)`` where its pass computes the curvature too (:func:`pixel_pcg` then skips a
dot)."""

IterateCallback = Callable[[int, np.ndarray], None]
"""A :data:`Callback` as the PCG loop calls it: with the pixel-major iterate (see
:func:`pixel_pcg`)."""

CgStep = Callable[
    [np.ndarray, np.ndarray, np.ndarray, np.ndarray, float], tuple[float, float, np.ndarray]
]
"""``step(x, r, p, q, alpha) -> (r . r, r . z, z)``: CG's update ``x += alpha p``,
``r -= alpha q`` in place, then the preconditioned residual ``z = M^-1 r`` of the updated
``r`` (it may take ``q``'s place, used up by then) and the two dots."""


def pixel_pcg(
    operator: PixelOperator,
    x: np.ndarray,
    rhs: np.ndarray,
    preconditioner: BlockJacobiPreconditioner,
    order: PixelOrder,
    *,
    precondition: bool,
    tolerance: float,
    max_iterations: int,
    callback: Callback | None,
) -> tuple[np.ndarray, list[float], int]:
    """Block-Jacobi preconditioned CG on ``H x = rhs`` for pixel-major vectors, in place.

    The run both PCG solvers share (:func:`~.block_jacobi_pcg.block_jacobi_pcg` and
    :func:`~.prior_pcg.prior_pcg`); they differ only in the terms of ``H``, ``rhs`` and the
    preconditioner's diagonal. Vectors are pixel-major in ``order`` (the layout of the
    compiled passes, :mod:`..kernels`); the operator and the preconditioner write into one
    shared buffer (CG uses up ``H p`` before it asks for ``M^-1 r`` and that before the
    next ``H p``). It stops when the relative residual ``||r|| / ||rhs||`` is below
    ``tolerance``, after ``max_iterations``, or early if ``H`` is not positive along a
    search direction.

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
        ``True``: block Jacobi; ``False``: none (a measurement of what it buys).
    tolerance, max_iterations
        Relative residual to stop at; iteration limit.
    callback
        Called after every iteration with the cube ``(w, m, y, x)`` (or None, see
        :func:`counting_iterations`).

    Returns
    -------
    x, history, iterations
        The solution (still pixel-major), the relative residual before the first and after
        every iteration, and the number of iterations done.

    Raises
    ------
    ParameterError
        For a ``precondition`` that is not a bool.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
    .. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM
       (preconditioned CG, algorithm 9.1).
    """
    if not isinstance(precondition, bool | np.bool_):
        raise ParameterError.single(
            "precondition", "True (block Jacobi) or False (none)", repr(precondition)
        )
    from ..kernels import dot  # numba compiles on first use, not on import

    buffer = np.empty_like(x)
    rhs_norm = np.sqrt(dot(rhs, rhs)) or 1.0
    r = rhs - _applied(operator(x, buffer))[0]
    if precondition:
        z = preconditioner.apply_pixels(r, out=buffer)
        step = _block_jacobi_step(preconditioner)
    else:
        z, step = r, _unpreconditioned_step
    return _conjugate_gradients(
        operator,
        x,
        r,
        z,
        rhs_norm,
        buffer,
        step,
        tolerance=tolerance,
        max_iterations=max_iterations,
        callback=_band_major(callback, order),
    )


def _conjugate_gradients(
    operator: PixelOperator,
    x: np.ndarray,
    r: np.ndarray,
    z: np.ndarray,
    rhs_norm: float,
    buffer: np.ndarray,
    step: CgStep,
    *,
    tolerance: float,
    max_iterations: int,
    callback: IterateCallback | None,
) -> tuple[np.ndarray, list[float], int]:
    """The PCG loop of :func:`pixel_pcg`, in place, from ``x``, its residual ``r`` and
    ``z = M^-1 r``.

    Per iteration: ``H p`` into ``buffer`` with ``p . H p`` from the operator's own pass
    where it returns it (else one dot), then ``step`` (CG's update of ``x`` and ``r``, the
    preconditioner and both dots, one pass for block Jacobi), then the new direction.

    References
    ----------
    .. [1] Shewchuk, J. R. (1994). An Introduction to the Conjugate Gradient Method Without
       the Agonizing Pain, section B3.
    """
    from ..kernels import cg_direction, dot

    rz = dot(r, z)
    p = z.copy()
    history = [np.sqrt(dot(r, r)) / rhs_norm]
    iterations = 0
    while history[-1] > tolerance and iterations < max_iterations:
        q, pq = _applied(operator(p, buffer))
        if pq is None:
            pq = dot(p, q)
        if not pq > 0:
            break
        rr, rz_new, z = step(x, r, p, q, rz / pq)
        iterations += 1
        history.append(np.sqrt(max(rr, 0.0)) / rhs_norm)
        if callback is not None:
            callback(iterations, x, *history[-1:] if wants_residual(callback) else ())
        if history[-1] <= tolerance:
            break
        cg_direction(p, z, x.dtype.type(rz_new / rz))
        rz = rz_new
    return x, history, iterations


def _applied(result: np.ndarray | tuple[np.ndarray, float]) -> tuple[np.ndarray, float | None]:
    """A :data:`PixelOperator`'s ``out``, and ``vector . out`` where it returned it too."""
    if isinstance(result, tuple):
        return result
    return result, None


def _block_jacobi_step(preconditioner: BlockJacobiPreconditioner) -> CgStep:
    """:data:`CgStep` with the block-Jacobi preconditioner, one compiled pass
    (:meth:`~.preconditioner.BlockJacobiPreconditioner.step_pixels`; ``z`` takes ``q``'s
    place)."""

    def step(
        x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, alpha: float
    ) -> tuple[float, float, np.ndarray]:
        rr, rz = preconditioner.step_pixels(x, r, p, q, alpha)
        return rr, rz, q

    return step


def _unpreconditioned_step(
    x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, alpha: float
) -> tuple[float, float, np.ndarray]:
    """:data:`CgStep` without a preconditioner: ``z = r``, ``r . z = r . r``."""
    from ..kernels import cg_step

    rr = float(cg_step(x, r, p, q, x.dtype.type(alpha)))
    return rr, rr, r


def _band_major(callback: Callback | None, order: PixelOrder) -> IterateCallback | None:
    """``callback`` for pixel-major iterates: it gets them as band-major cubes (or None
    where it does not look at them, :func:`needs_cube`)."""
    if callback is None:
        return None
    given: Callback = callback
    cube_wanted = needs_cube(given)

    def band_major_callback(iteration: int, vector: np.ndarray, *relative: float) -> None:
        given(iteration, order.to_cube(vector) if cube_wanted else None, *relative)

    band_major_callback.wants_residual = wants_residual(given)  # type: ignore[attr-defined]
    return band_major_callback
