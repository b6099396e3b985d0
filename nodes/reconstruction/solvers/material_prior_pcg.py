"""Solver ``"material-prior-pcg"``: eq. 1 with neighbourhoods that separate materials, a
guided prior and non-negativity.

Three changes to eq. 1 where it is wrong on scenes of many materials (each measured in
``benchmarks/reconstruction.py``):

* appearance neighbourhoods in chromaticity, log brightness and pixel position
  (:func:`~..neighbourhoods.appearance_features`, ``"chromaticity-spatial"``) instead of
  absolute RGB: neighbours in noisy absolute RGB join pixels of different materials, and
  the paper itself proposes spatial proximity against metamers (section 6);
* scale-invariant coupling ``S(p) - (b_p / b_n) S(n)`` (``b``: RGB brightness): within a
  BTF set the same texel is seen at very different brightness, and shading changes the
  spectrum's scale, not its shape;
* the prior of :mod:`.guided_prior_pcg` towards the RGB-guided filtered bands (a locally
  affine model in RGB), then a projected-gradient refinement of the same energy on
  ``S >= 0`` (radiance is never negative).

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 3 and 6.
.. [2] He, Sun and Tang (2013), Guided Image Filtering.
.. [3] Barzilai, J., Borwein, J. M. (1988). Two-point step size gradient methods. IMA J.
   Numer. Anal. 8 (the projected gradient's step).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..operators import ReconstructionProblem
from .block_jacobi_pcg import (
    DEFAULT_RIDGE,
    BlockJacobiPreconditioner,
    _prior_mask,
    block_jacobi_pcg,
    guided_initial,
)
from .common import DEFAULT_MAX_ITERATIONS, DEFAULT_TOLERANCE, Callback, SolverResult, vdot
from .guided_prior_pcg import DEFAULT_PRIOR

__all__ = ["material_prior_pcg", "SETUP_DEFAULTS", "DEFAULT_PROJECTED_ITERATIONS"]

SETUP_DEFAULTS = {"appearance": "chromaticity-spatial", "scale_invariant": True, "k": 6}
"""Set-up options of eq. 1 this method changes (see the module docstring)."""

DEFAULT_PROJECTED_ITERATIONS = 40
"""Projected-gradient iterations on ``S >= 0`` after the unconstrained solve."""


def _projected_refinement(
    problem: ReconstructionProblem,
    x: np.ndarray,
    prior: float,
    ridge: float,
    iterations: int,
) -> np.ndarray:
    """Minimise the solver's regularised energy over ``S >= 0`` from ``x`` by projected
    gradient with Barzilai-Borwein steps, Jacobi-scaled; returns a non-negative cube."""
    dtype = x.dtype
    work = problem.astype(dtype)
    centre = np.asarray(guided_initial(problem), dtype=dtype).reshape(work.shape)
    relative = ridge + prior * _prior_mask(problem)
    preconditioner = BlockJacobiPreconditioner(work, dtype, ridge=relative)
    epsilon = preconditioner.ridge.astype(dtype)
    rhs = work.normal_rhs() + epsilon * centre
    scale = preconditioner.inverse_scalar_diagonal.reshape(work.shape)

    def gradient(cube: np.ndarray) -> np.ndarray:
        return work.normal(cube) + epsilon * cube - rhs

    x = np.maximum(x, 0)
    g = gradient(x)
    step = 1.0
    for _ in range(iterations):
        new = np.maximum(x - dtype.type(step) * scale * g, 0)
        new_g = gradient(new)
        s, y = (new - x).ravel(), (new_g - g).ravel()
        sy = vdot(s, y)
        step = float(vdot(s, s / scale.ravel()) / sy) if sy > 0 else step
        step = min(max(step, 1e-3), 10.0)
        x, g = new, new_g
    return x


def material_prior_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = DEFAULT_RIDGE,
    prior: float = DEFAULT_PRIOR,
    precondition: bool | str = True,
    projected_iterations: int = DEFAULT_PROJECTED_ITERATIONS,
) -> SolverResult:
    """Eq. 1 (set up with :data:`SETUP_DEFAULTS`) plus the guided prior, then ``S >= 0``.

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`.
    initial, tolerance, max_iterations, callback, dtype, ridge, prior, precondition
        As for :func:`~.guided_prior_pcg.guided_prior_pcg`.
    projected_iterations
        Projected-gradient iterations on ``S >= 0`` (0: none; the result may then have
        negative values).

    Returns
    -------
    SolverResult
        ``method="material-prior-pcg"``; iterations count both stages.
    """
    result = block_jacobi_pcg(
        problem,
        initial=initial,
        tolerance=tolerance,
        max_iterations=max_iterations,
        callback=callback,
        dtype=dtype,
        ridge=ridge,
        prior=prior,
        precondition=precondition,
    )
    cube = result.cube
    if projected_iterations > 0:
        cube = _projected_refinement(problem, cube, prior, ridge, int(projected_iterations))
    return dataclasses.replace(
        result,
        cube=cube,
        iterations=result.iterations + int(projected_iterations),
        method="material-prior-pcg",
        info={**result.info, "projected_iterations": int(projected_iterations)},
    )
