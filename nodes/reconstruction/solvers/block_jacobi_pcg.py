"""Eq. 1 by block-Jacobi preconditioned CG, with an optional guided prior.

Conjugate gradients on ``A^T A`` applied directly (one pass of each term instead of ``A``
then ``A^T``), preconditioned by the exact inverse of the per-pixel diagonal blocks
(:mod:`.preconditioner`), in float32, started from the filtered bands projected onto the RGB
constraint, with a tiny ridge towards that start that only acts on directions eq. 1 leaves
undetermined. With ``prior=0`` it reaches the paper-CG's solution, faster.

With ``prior > 0`` it adds a Tikhonov prior towards the RGB-guided filtered bands ``S_0``
(:func:`~.guided_estimate.guided_initial`) on every band and image that has a shot, and
starts there. Why: k nearest neighbours in noisy RGB tie pixels of different materials, so
the truth can be far from the minimiser of eq. 1; the locally-affine-in-RGB model of the
guided filter keeps a material's per-pixel mix of diffuse and specular reflection, and
eq. 1 corrects it where the filter, RGB and neighbour terms agree.

The presets ``"block-jacobi-pcg"`` (eq. 1 alone) and ``"guided-prior-pcg"`` of
:data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS` run it.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization", and section 6
   (convergence speed with large filters as the main limitation).
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM
   (preconditioned CG, algorithm 9.1).
.. [3] He, K., Sun, J., Tang, X. (2013). Guided Image Filtering. IEEE TPAMI 35(6).
"""

from __future__ import annotations

import time

import numpy as np

from ..operators import ReconstructionProblem
from .common import Callback, SolverResult, pixel_pcg
from .guided_estimate import guided_initial, projected_filtered_initial, shot_mask
from .preconditioner import BlockJacobiPreconditioner

__all__ = ["block_jacobi_pcg"]


def block_jacobi_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = 1e-3,
    max_iterations: int = 2000,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = 1e-4,
    prior: float = 0.0,
    precondition: bool = True,
) -> SolverResult:
    """Eq. 1, plus an optional guided prior, by block-Jacobi preconditioned CG.

    Minimises eq. 1 plus ``epsilon_r ||S - S_start||^2 + epsilon_p M ||S - S_0||^2``:
    ``epsilon_r = ridge * mean(diag A^T A)`` towards the starting cube, ``epsilon_p = prior *
    mean(diag A^T A)`` towards the guided estimate ``S_0`` on the bands and images ``M``
    that have a shot (:func:`~.guided_estimate.shot_mask`).

    The tiny ``ridge`` leaves every direction that eq. 1 determines unchanged (to about
    ``epsilon / lambda``) and keeps the spectra of directions it does not determine at all
    (e.g. a neighbourhood component of an image without bands that no filter sees) at the
    start, instead of letting rounding errors of a float32 CG drift along them;
    ``ridge=0, prior=0`` solves eq. 1 exactly. The keyword defaults are eq. 1 alone; the
    presets of :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS` set
    every one.

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`.
    initial
        Starting cube (a warm start); default ``S_0`` when ``prior > 0`` (it stays the
        prior's centre either way), else :func:`~.guided_estimate.projected_filtered_initial`.
    tolerance
        Relative normal-equation residual to stop at.
    max_iterations
        Iteration limit.
    callback
        Called as ``callback(iteration, cube)`` after every iteration.
    dtype
        Working precision (float32 halves memory traffic; float64 for checks).
    ridge
        Ridge towards the start, relative to the mean diagonal of ``A^T A``.
    prior
        Weight of the prior towards ``S_0``, relative to the mean diagonal of ``A^T A``, on
        the bands and images that have a shot (0: eq. 1 alone).
    precondition
        ``True``: block Jacobi; ``False``: none (a measurement of what it buys).

    Returns
    -------
    SolverResult
        ``method="block_jacobi_pcg"``; the cube is in ``dtype``; ``info`` records the
        absolute ridge, the prior and the preconditioner.
    """
    started = time.perf_counter()
    dtype = np.dtype(dtype)
    work = problem.astype(dtype)
    relative_ridge: float | np.ndarray = ridge
    centre = None
    if prior > 0:
        centre = np.asarray(guided_initial(problem), dtype=dtype).reshape(work.shape)
        relative_ridge = ridge + prior * shot_mask(problem)
    if initial is None:
        initial = centre if centre is not None else projected_filtered_initial(problem)
    # the iteration runs on pixel-major vectors stored in appearance order (:mod:`..kernels`)
    order = work.pixel_order("appearance")
    x = order.to_pixels(np.asarray(initial, dtype=dtype).reshape(work.shape))
    del initial  # the caller's start is the caller's; one computed here is not kept
    preconditioner = BlockJacobiPreconditioner(work, dtype, ridge=relative_ridge, order=order)
    # epsilon_r + epsilon_p M, absolute (per band and image: the preconditioner's ridge)
    epsilon = (np.asarray(relative_ridge, dtype=np.float64) * preconditioner.mean_diagonal).astype(dtype)
    regularised = bool(np.any(epsilon > 0))
    rhs = order.to_pixels(work.normal_rhs())
    if regularised:  # epsilon_r S_start + epsilon_p M S_0
        towards = dtype.type(preconditioner.ridge_of(ridge))
        rhs += towards * x
        if centre is not None:
            ridge_cube = np.broadcast_to(epsilon, work.shape) - towards
            rhs += order.to_pixels(ridge_cube * centre)
            del centre, ridge_cube
    ridge_argument = epsilon if regularised else 0.0

    def operator(vector: np.ndarray, out: np.ndarray) -> np.ndarray:
        return work.normal_pixels(vector, order=order, epsilon=ridge_argument, out=out)

    x, history, iterations = pixel_pcg(
        operator,
        x,
        rhs,
        preconditioner,
        order,
        precondition=precondition,
        tolerance=tolerance,
        max_iterations=max_iterations,
        callback=callback,
    )
    return SolverResult(
        order.to_cube(x),
        iterations,
        np.asarray(history),
        history[-1] <= tolerance,
        time.perf_counter() - started,
        "block_jacobi_pcg",
        {"ridge": float(np.min(epsilon)), "prior": float(prior), "precondition": precondition},
    )
