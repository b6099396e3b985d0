"""Solvers of eq. 1: three implementations, one method per module.

``paper_cg`` (:mod:`.paper_cg`)
    The paper's solver, kept as the reference: CGNR, float64, started from zero.
``block_jacobi_pcg`` (:mod:`.block_jacobi_pcg`)
    Eq. 1, plus an optional guided prior, by block-Jacobi preconditioned CG on ``A^T A``
    in float32.
``prior_pcg`` (:mod:`.prior_pcg`)
    The same PCG on eq. 1 plus the guided and spectral priors (scene, mixture, training
    samples, or the mixture with the natural-spectra prior), then the non-negativity
    refinement.

The named presets that run them (``"natural-prior-pcg"``, the default, and the others)
are data in :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`.
Shared parts: :mod:`.common` (result record, the PCG loop and its pixel-major run),
:mod:`.preconditioner` (block Jacobi), :mod:`.guided_estimate` (starts and the guided
prior's centre), :mod:`.spectral_prior` (the spectral prior term), :mod:`.natural_prior`
(the natural-spectra prior) with :mod:`.band_evidence` (its per-pixel weight) and
:mod:`.projected_refinement` (``S >= 0``).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM.
"""

from .block_jacobi_pcg import block_jacobi_pcg
from .common import SolverResult, counting_iterations
from .guided_estimate import guided_initial, projected_filtered_initial, shot_mask
from .paper_cg import paper_cg
from .preconditioner import BlockJacobiPreconditioner, normal_mean_diagonal
from .prior_pcg import prior_pcg
from .projected_refinement import projected_refinement
from .spectral_prior import SpectralPrior, prior_brightness, spectral_prior_term

__all__ = [
    "SolverResult",
    "counting_iterations",
    "paper_cg",
    "block_jacobi_pcg",
    "prior_pcg",
    "BlockJacobiPreconditioner",
    "normal_mean_diagonal",
    "shot_mask",
    "projected_filtered_initial",
    "guided_initial",
    "projected_refinement",
    "SpectralPrior",
    "spectral_prior_term",
    "prior_brightness",
]
