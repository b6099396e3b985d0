"""Spectral reconstruction (eq. 1) from HDR RGB and noisy, filtered band shots.

Public API::

    from spectralize.nodes.reconstruction import reconstruct, reconstruct_baseline
    spectra = reconstruct(rgb, bands, camera_matrix)              # fast default solver
    spectra = reconstruct(rgb, bands, camera_matrix, method="paper-cg")  # the paper's CG

Modules: :mod:`.operators` (filter, RGB and neighbour terms, the problem), :mod:`.neighbourhoods`
(k nearest neighbours in RGB space), :mod:`.weights` (eq. 4), :mod:`.solvers` (paper CG and the
fast default), :mod:`.baselines` (comparison methods), :mod:`.inputs` (checks), :mod:`.api`.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3.
"""

from .api import ReconstructionResult, reconstruct, reconstruct_baseline, reconstruct_spectra
from .baselines import BASELINE_METHODS
from .inputs import ReconstructionInputs, inputs_from_xarray
from .neighbourhoods import NeighbourGraph, appearance_neighbours
from .operators import (
    FilterConstraints,
    ReconstructionProblem,
    build_problem,
    filter_centres,
    gaussian_filter_matrix,
)
from .solvers import DEFAULT_METHOD, SOLVER_METHODS, SolverResult
from .weights import TermWeights, term_weights

__all__ = [
    "reconstruct",
    "reconstruct_spectra",
    "reconstruct_baseline",
    "ReconstructionResult",
    "SOLVER_METHODS",
    "BASELINE_METHODS",
    "DEFAULT_METHOD",
    "SolverResult",
    "ReconstructionInputs",
    "inputs_from_xarray",
    "ReconstructionProblem",
    "build_problem",
    "FilterConstraints",
    "filter_centres",
    "gaussian_filter_matrix",
    "NeighbourGraph",
    "appearance_neighbours",
    "TermWeights",
    "term_weights",
]
