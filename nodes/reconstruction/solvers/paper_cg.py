"""The paper's conjugate gradients on the normal equations (CGNR), preset ``"paper-cg"``.

Kept as the reference mode: ``A`` and ``A^T`` applied as two functions, float64, started
from zero, no preconditioner.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM
   (CGNR, algorithm 8.4).
"""

from __future__ import annotations

import time

import numpy as np

from ..operators import ReconstructionProblem
from .common import Callback, SolverResult, vdot, wants_residual

__all__ = ["paper_cg"]


def paper_cg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = 1e-3,
    max_iterations: int = 2000,
    callback: Callback | None = None,
) -> SolverResult:
    """The paper's solver: CG on ``A^T A S = A^T b`` with ``A``, ``A^T`` as functions.

    Float64, started from ``initial`` or zero, no preconditioner (CGNR).

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`.
    initial
        Starting cube ``(n_wavelength, n_image, height, width)`` (default: zeros).
    tolerance
        Relative normal-equation residual to stop at.
    max_iterations
        Iteration limit.
    callback
        Called as ``callback(iteration, cube)`` after every iteration (for benchmarks).

    Returns
    -------
    SolverResult
        ``method="paper_cg"``; the cube is float64.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
    """
    started = time.perf_counter()
    problem = problem.astype(np.float64)
    x = (
        np.zeros(problem.shape)
        if initial is None
        else np.array(initial, dtype=np.float64, copy=True).reshape(problem.shape)
    )
    target = problem.target()
    rhs_norm = np.sqrt(vdot(g := problem.apply_adjoint(target), g)) or 1.0
    applied = problem.apply(x)
    residual_blocks = (
        [t - a for t, a in zip(target[0], applied[0], strict=True)],
        target[1] - applied[1],
        target[2] - applied[2],
    )
    r = problem.apply_adjoint(residual_blocks)
    del g, applied, residual_blocks
    p = r.copy()
    rr = vdot(r, r)
    history = [np.sqrt(rr) / rhs_norm]
    iterations = 0
    while history[-1] > tolerance and iterations < max_iterations:
        q = problem.apply(p)
        qq = sum(vdot(b, b) for b in q[0]) + vdot(q[1], q[1]) + vdot(q[2], q[2])
        if qq <= 0:
            break
        step = rr / qq
        x += step * p
        r -= step * problem.apply_adjoint(q)
        rr_new = vdot(r, r)
        p *= rr_new / rr
        p += r
        rr = rr_new
        iterations += 1
        history.append(np.sqrt(rr) / rhs_norm)
        if callback is not None:
            callback(iterations, x, *history[-1:] if wants_residual(callback) else ())
    return SolverResult(
        x,
        iterations,
        np.asarray(history),
        history[-1] <= tolerance,
        time.perf_counter() - started,
        "paper_cg",
    )
