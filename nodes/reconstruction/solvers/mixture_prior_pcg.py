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
six of the eight scene x mode rows; worse on three (the dark-still-life image's median by
16 %, the glossy-mosaic image's p95 by 8 %, the glossy-mosaic set's median by 3 %).

It stops earlier than eq. 1 (:data:`MIXTURE_TOLERANCE`) and refines ``S >= 0`` for fewer
steps (:data:`MIXTURE_PROJECTED_ITERATIONS`): it starts at its prior's centre, and the
iterations past that drift from it towards eq. 1's answer, which on sets carries the
highlight and neighbour errors of other images. Measured on the 4 hard scenes x 2 seeds
(single 128^2, sets 20 x 48^2): from 40 to 10 projected steps no median or p95 moves by
more than 1 %, and every output stays non-negative; tolerance 3e-3 instead of 1e-3 lowers
the sets' p95 by 1-13 % (glossy-mosaic 1.17 -> 1.09, dark-still-life 0.54 -> 0.46) and
their medians by 0-6 %, and moves no single-image median or p95 by more than 1 %. 1e-2
lowers the glossy-mosaic set's p95 further (0.86) but raises the dark-still-life set's
median by 9 %, so it is not the default.

Its guided prior towards the mixture is stronger than ``spectral-prior-pcg``'s (mean weight
:data:`MIXTURE_PRIOR` 0.3 instead of 0.1) and weighted per pixel by the pixel's relative
brightness (:data:`MIXTURE_PRIOR_WEIGHTING`): the mixture is accurate relative to a pixel's
level, so a bright pixel (a highlight, a light material, whose error the image-normalised
nRMSE counts many times over) is held near it, while in the dark pixels eq. 1's neighbour
term averages out more band noise than it adds. Measured on the 4 hard scenes x 2 seeds
(worse seed), against a uniform weight of 0.1: p95 of the glossy-mosaic image 0.270 ->
0.208, of its set 1.07 -> 0.78, of the dark-still-life image 0.147 -> 0.124 and set 0.459
-> 0.402; medians within 2 % (halftone-print image 0.0621 -> 0.0589), but for the
dark-still-life image's, 0.0210 -> 0.0213. A uniform 0.3 left the dark-still-life image's
median 5 % worse and the glossy p95s 10-14 % higher; weights by brightness squared lost
the woven-fabric and dark-still-life medians (+1-6 %).

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 ("Hybrid Methods") and 3.
.. [2] Keshava, N., Mustard, J. F. (2002). Spectral unmixing. IEEE Signal Processing
   Magazine 19(1).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..estimators.endmember_mixture import Endmembers
from ..operators import ReconstructionProblem
from .block_jacobi_pcg import DEFAULT_RIDGE
from .common import DEFAULT_MAX_ITERATIONS, Callback, SolverResult
from .spectral_prior_pcg import (
    DEFAULT_COVARIANCE_FLOOR,
    DEFAULT_SPECTRAL_PRIOR,
    SETUP_DEFAULTS,
    spectral_prior_pcg,
)

__all__ = [
    "mixture_prior_pcg",
    "SETUP_DEFAULTS",
    "MIXTURE_TOLERANCE",
    "MIXTURE_PROJECTED_ITERATIONS",
    "MIXTURE_PRIOR",
    "MIXTURE_PRIOR_WEIGHTING",
]

MIXTURE_TOLERANCE = 3e-3
"""Relative residual at which the PCG stops (eq. 1's solvers: 1e-3); see the module docstring."""

MIXTURE_PROJECTED_ITERATIONS = 10
"""Projected-gradient steps on ``S >= 0`` (``spectral-prior-pcg``: 40)."""

MIXTURE_PRIOR = 0.3
"""Mean weight of the guided prior towards the mixture, relative to the mean diagonal of
``A^T A`` (``spectral-prior-pcg``: 0.1 towards the guided filter); see the module docstring."""

MIXTURE_PRIOR_WEIGHTING = "brightness"
"""The guided prior weighs each pixel by its relative brightness (mean 1); see
:func:`~.spectral_prior_pcg.prior_brightness` and the module docstring."""


def mixture_prior_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = MIXTURE_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = DEFAULT_RIDGE,
    prior: float = MIXTURE_PRIOR,
    spectral_prior: float = DEFAULT_SPECTRAL_PRIOR,
    covariance_floor: float = DEFAULT_COVARIANCE_FLOOR,
    precondition: bool | str = True,
    projected_iterations: int = MIXTURE_PROJECTED_ITERATIONS,
    endmembers: Endmembers | None = None,
    prior_weighting: str = MIXTURE_PRIOR_WEIGHTING,
) -> SolverResult:
    """Eq. 1 + guided prior + the endmember-mixture spectral prior, then ``S >= 0``.

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`
        with its inputs (:data:`SETUP_DEFAULTS`).
    initial, tolerance, max_iterations, callback, dtype, ridge, prior, spectral_prior, \
covariance_floor, precondition, projected_iterations, prior_weighting
        As for :func:`~.spectral_prior_pcg.spectral_prior_pcg`.
    endmembers
        The mixture's dictionary, learnt before: a set solved tile by tile learns it once
        (:func:`~..estimators.endmember_mixture.set_endmembers` on a strided sample of the
        set) so that every tile mixes the same endmembers; None: learnt from the problem's
        inputs.

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
        endmembers=endmembers,
        prior_weighting=prior_weighting,
    )
    return dataclasses.replace(
        result, method="mixture-prior-pcg", info={**result.info, "prior_source": "mixture"}
    )
