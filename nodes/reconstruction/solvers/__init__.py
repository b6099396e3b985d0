"""Solvers of the normal equations ``A^T A S = A^T b`` of eq. 1, one method per module.

All of them are listed in
:data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS` and run through
:func:`~spectralize.nodes.reconstruction.reconstruct`:

``"paper-cg"`` (:mod:`.paper_cg`)
    The paper's solver, kept as the reference mode: CGNR, float64, started from zero.
``"block-jacobi-pcg"`` (:mod:`.block_jacobi_pcg`)
    Eq. 1 alone, solved fast: block-Jacobi preconditioned CG on ``A^T A``, float32,
    started from the filtered bands projected onto ``C S = R``.
``"guided-prior-pcg"`` (:mod:`.guided_prior_pcg`)
    The same solver on eq. 1 plus a prior towards the RGB-guided filtered bands.

``"material-prior-pcg"`` (:mod:`.material_prior_pcg`)
    Eq. 1 with neighbourhoods in chromaticity and position, scale-invariant coupling, the
    guided prior and non-negativity.
``"spectral-prior-pcg"`` (:mod:`.spectral_prior_pcg`)
    ``material-prior-pcg`` plus a soft Gaussian spectral prior from colour-science's
    reflectances, centred on the Wiener estimate and scaled by each pixel's brightness.
``"mixture-prior-pcg"`` (:mod:`.mixture_prior_pcg`)
    The same with the prior learnt from, and centred on, the endmember-mixture estimate
    (:mod:`..estimators`). The default.

All stop when the relative residual of the normal equations ``||A^T b - A^T A S|| /
||A^T b||`` falls below ``tolerance``, or after ``max_iterations``
(:mod:`.common`).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM.
"""

from .block_jacobi_pcg import (
    DEFAULT_RIDGE,
    BlockJacobiPreconditioner,
    block_jacobi_pcg,
    guided_initial,
    projected_filtered_initial,
)
from .common import DEFAULT_MAX_ITERATIONS, DEFAULT_TOLERANCE, SolverResult
from .guided_prior_pcg import DEFAULT_PRIOR, guided_prior_pcg
from .material_prior_pcg import material_prior_pcg
from .mixture_prior_pcg import mixture_prior_pcg
from .paper_cg import paper_cg
from .spectral_prior_pcg import spectral_prior_pcg

__all__ = [
    "SolverResult",
    "DEFAULT_TOLERANCE",
    "DEFAULT_MAX_ITERATIONS",
    "DEFAULT_RIDGE",
    "DEFAULT_PRIOR",
    "paper_cg",
    "block_jacobi_pcg",
    "guided_prior_pcg",
    "material_prior_pcg",
    "spectral_prior_pcg",
    "mixture_prior_pcg",
    "BlockJacobiPreconditioner",
    "projected_filtered_initial",
    "guided_initial",
]
