"""Solver ``"mixture-prior-pcg"`` (the default): eq. 1 set up to separate materials, with a
soft spectral prior centred on the endmember-mixture estimate.

The energy of :mod:`.spectral_prior_pcg` (eq. 1 with neighbourhoods in chromaticity and
position, scale-invariant coupling, the guided prior, and ``S >= 0``) with its per-pixel
Gaussian prior ``sum_p w_p (S_p - m_p)^T Q (S_p - m_p)`` learnt from
:func:`~..estimators.endmember_mixture`: ``m_p`` is that estimate (every pixel a
non-negative mixture of a few endmember spectra learnt from all pixels' band shots, the
weights from its RGB) and ``Q`` the inverse covariance of its level-normalised spectra.

Why: the mixture pools the band shots of every pixel of a material, where eq. 1's filter
term pools only a filter's support and its neighbour term only ``k`` pixels, so its
spectra carry far less band noise; what it cannot know (which materials a pixel holds when
RGB alone does not tell, metamers, local detail) the filter and neighbour terms of eq. 1
add. Unlike the ``"scene"`` prior of ``spectral-prior-pcg``, it exists for a sparse set
too (images with a few band shots, or none). Measured in ``benchmarks/reconstruction.py``
(README, "Reconstruction on the hard scenes"): against ``spectral-prior-pcg`` a lower median
on the woven-fabric and halftone-print images and on three of the four sets, a lower p95 on
six of the eight scene x mode rows; about 10 % worse on two (the dark-still-life image's
median, the glossy-mosaic image's p95).

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 ("Hybrid Methods") and 3.
.. [2] Keshava, N., Mustard, J. F. (2002). Spectral unmixing. IEEE Signal Processing
   Magazine 19(1).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..operators import ReconstructionProblem
from .block_jacobi_pcg import DEFAULT_RIDGE
from .common import DEFAULT_MAX_ITERATIONS, DEFAULT_TOLERANCE, Callback, SolverResult
from .guided_prior_pcg import DEFAULT_PRIOR
from .material_prior_pcg import DEFAULT_PROJECTED_ITERATIONS
from .spectral_prior_pcg import (
    DEFAULT_COVARIANCE_FLOOR,
    DEFAULT_SPECTRAL_PRIOR,
    SETUP_DEFAULTS,
    spectral_prior_pcg,
)

__all__ = ["mixture_prior_pcg", "SETUP_DEFAULTS"]


def mixture_prior_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = DEFAULT_RIDGE,
    prior: float = DEFAULT_PRIOR,
    spectral_prior: float = DEFAULT_SPECTRAL_PRIOR,
    covariance_floor: float = DEFAULT_COVARIANCE_FLOOR,
    precondition: bool | str = True,
    projected_iterations: int = DEFAULT_PROJECTED_ITERATIONS,
) -> SolverResult:
    """Eq. 1 + guided prior + the endmember-mixture spectral prior, then ``S >= 0``.

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`
        with its inputs (:data:`SETUP_DEFAULTS`).
    initial, tolerance, max_iterations, callback, dtype, ridge, prior, spectral_prior, \
covariance_floor, precondition, projected_iterations
        As for :func:`~.spectral_prior_pcg.spectral_prior_pcg`.

    Returns
    -------
    SolverResult
        ``method="mixture-prior-pcg"``; iterations count both stages.
    """
    result = spectral_prior_pcg(
        problem,
        initial=initial,
        tolerance=tolerance,
        max_iterations=max_iterations,
        callback=callback,
        dtype=dtype,
        ridge=ridge,
        prior=prior,
        spectral_prior=spectral_prior,
        covariance_floor=covariance_floor,
        prior_source="mixture",
        precondition=precondition,
        projected_iterations=projected_iterations,
    )
    return dataclasses.replace(
        result, method="mixture-prior-pcg", info={**result.info, "prior_source": "mixture"}
    )
