"""Spectral reconstruction (eq. 1) from HDR RGB and noisy, filtered band shots.

Public API::

    from spectralize.nodes.reconstruction import reconstruct, resolve_method, RECONSTRUCTION_METHODS
    spectra = reconstruct(rgb, bands, camera_matrix)                      # the default solver
    spectra = reconstruct(rgb, bands, camera_matrix, method="paper-cg")   # the paper's CG
    spectra = reconstruct(rgb, bands, camera_matrix, method="guided-prior-pcg", prior=0.3)
    spectra = reconstruct(rgb, bands, camera_matrix, method="wiener")     # a baseline
    RECONSTRUCTION_METHODS["natural-prior-pcg"].settings                 # every setting
    method = resolve_method("guided-prior-pcg", prior=0.3)                # checked once
    spectra = reconstruct(rgb, bands, camera_matrix, method=method)       # passed on

Modules: :mod:`.api` (:func:`reconstruct`, the one entry point), :mod:`.methods` (the
production presets and the comparison baselines, as data), :mod:`.solvers`,
:mod:`.estimators` and :mod:`.baselines` (one method per module), :mod:`.operators`
(filter, RGB and neighbour terms, the problem), :mod:`.neighbourhoods` (k nearest
neighbours in appearance space), :mod:`.weights` (eq. 4), :mod:`.inputs` (checks),
:mod:`.image_sets`, :mod:`.warm_start` and :mod:`.set_reconstruction` (a run, set by set),
:mod:`.tiling` (a set, tile by tile), :mod:`.declarations` (the nodes).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3.
"""

from .api import ReconstructionResult, reconstruct
from .inputs import ReconstructionInputs, inputs_from_xarray
from .methods import (
    BASELINE_METHODS,
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
    ReconstructionMethod,
    ResolvedMethod,
    resolve_method,
)
from .neighbourhoods import NeighbourGraph, appearance_neighbours
from .operators import (
    FilterConstraints,
    ReconstructionProblem,
    build_problem,
    filter_centres,
    gaussian_filter_matrix,
)
from .solvers import SolverResult
from .weights import TermWeights, term_weights

__all__ = [
    "reconstruct",
    "ReconstructionResult",
    "RECONSTRUCTION_METHODS",
    "BASELINE_METHODS",
    "ReconstructionMethod",
    "ResolvedMethod",
    "resolve_method",
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
