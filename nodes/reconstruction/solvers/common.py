"""What every solver of eq. 1 shares: its result record, defaults and a dot product.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["SolverResult", "Callback", "DEFAULT_TOLERANCE", "DEFAULT_MAX_ITERATIONS"]

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
