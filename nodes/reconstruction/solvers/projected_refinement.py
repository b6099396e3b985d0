"""The non-negativity refinement: radiance is never negative.

After the unconstrained PCG, minimise the same quadratic energy ``x^T H x / 2 - rhs^T x``
over ``x >= 0`` by projected gradient, Jacobi-scaled, with Barzilai-Borwein steps: a few
steps from the PCG's solution move only the pixels that left the feasible set.

References
----------
.. [1] Barzilai, J., Borwein, J. M. (1988). Two-point step size gradient methods. IMA J.
   Numer. Anal. 8.
.. [2] Fast Capture of Spectral Image Series, section 3 (eq. 1).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .common import PixelOperator

__all__ = ["projected_refinement", "MIN_STEP", "MAX_STEP"]

MIN_STEP = 1e-3
"""Smallest Barzilai-Borwein step (in units of the Jacobi scaling)."""

MAX_STEP = 10.0
"""Largest Barzilai-Borwein step."""


def projected_refinement(
    operator: PixelOperator,
    rhs: np.ndarray,
    scale: np.ndarray,
    x: np.ndarray,
    iterations: int,
    *,
    gradient: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Minimise ``x^T H x / 2 - rhs^T x`` over ``x >= 0`` from ``x``; returns the result.

    Each step is ``x <- max(x - t D g, 0)`` with the gradient ``g = H x - rhs``, ``D`` the
    Jacobi scaling ``scale`` (``1 / diag H``) and ``t`` the Barzilai-Borwein step
    ``(s^T D^-1 s) / (s^T y)`` of the last step ``s`` and its gradient change ``y``, clipped
    to [:data:`MIN_STEP`, :data:`MAX_STEP`].

    Parameters
    ----------
    operator
        ``H``, ``operator(vector, out) -> out`` (:data:`~.common.PixelOperator`).
    rhs
        Right-hand side, the layout of ``x``.
    scale
        ``1 / diag H``, the layout of ``x``.
    x
        Start (e.g. the PCG's solution), C-contiguous float; overwritten.
    iterations
        Projected-gradient steps.
    gradient
        ``gradient(vector, out) -> out``, ``out = H vector - rhs`` in one pass (e.g. the
        operator's compiled pass subtracting ``rhs``); None: ``operator`` then a subtraction.

    Notes
    -----
    Three buffers besides ``x`` (the gradient, the step and its gradient), allocated once;
    the step and the step's dot products are compiled passes
    (:func:`~..kernels.projected_step`, :func:`~..kernels.step_dots`) that never form the
    differences ``s`` and ``y``.
    """
    from ..kernels import projected_step, step_dots

    if gradient is None:

        def gradient(vector: np.ndarray, out: np.ndarray) -> np.ndarray:
            applied = operator(vector, out)
            applied = applied[0] if isinstance(applied, tuple) else applied
            return np.subtract(applied, rhs, out=out)

    np.maximum(x, 0, out=x)
    g, new, new_g = np.empty_like(x), np.empty_like(x), np.empty_like(x)
    g = gradient(x, g)
    step = 1.0
    for _ in range(iterations):
        projected_step(x, g, scale, step, new)
        gradient(new, new_g)
        sy, ss = step_dots(new, x, new_g, g, scale)
        step = float(ss / sy) if sy > 0 else step
        step = min(max(step, MIN_STEP), MAX_STEP)
        x, new = new, x
        g, new_g = new_g, g
    return x
