"""The one table of reconstruction methods: every solver of eq. 1 and every baseline.

:data:`RECONSTRUCTION_METHODS` maps a method name to a :class:`ReconstructionMethod` record
(its kind, function, working dtype and options), as colour-science's ``XYZ_TO_SD_METHODS``
does; :func:`~spectralize.nodes.reconstruction.api.reconstruct` dispatches on it, and the
set-reconstruction nodes accept exactly its names.

A method's options are the keyword-only arguments of its function: for a solver, the
problem set-up of :func:`~spectralize.nodes.reconstruction.operators.build_problem` (eq. 4
weights, neighbours, filter placement) plus the solver's own; for a baseline, its own.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1 and 4.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from spectralize.schemas.errors import ReconstructionError

from .baselines import (
    filtered_bands,
    filtered_bands_projected,
    guided_filtered_projected,
    mallett2019_basis,
    pseudo_inverse,
    wiener_estimation,
)
from .estimators import endmember_mixture
from .operators import build_problem
from .solvers import (
    block_jacobi_pcg,
    guided_prior_pcg,
    material_prior_pcg,
    mixture_prior_pcg,
    paper_cg,
    spectral_prior_pcg,
)
from .solvers.material_prior_pcg import SETUP_DEFAULTS as MATERIAL_SETUP_DEFAULTS
from .solvers.spectral_prior_pcg import SETUP_DEFAULTS as SPECTRAL_SETUP_DEFAULTS

__all__ = [
    "ReconstructionMethod",
    "RECONSTRUCTION_METHODS",
    "DEFAULT_METHOD",
    "get_method",
    "SETUP_OPTIONS",
]


def _keyword_options(
    function: Callable[..., Any], leave_out: tuple[str, ...] = ()
) -> dict[str, inspect.Parameter]:
    return {
        name: parameter
        for name, parameter in inspect.signature(function).parameters.items()
        if parameter.kind is parameter.KEYWORD_ONLY and name not in leave_out
    }


SETUP_OPTIONS: Mapping[str, inspect.Parameter] = MappingProxyType(
    _keyword_options(build_problem, leave_out=("neighbours", "dtype"))
)
"""Options every solver takes for setting up eq. 1 (:func:`~.operators.build_problem`):
``alpha_hat``, ``beta_hat``, ``gamma_hat``, ``k``, ``centre_spacing``,
``normalize_camera_matrix``."""


@dataclass(frozen=True)
class ReconstructionMethod:
    """One reconstruction method of :data:`RECONSTRUCTION_METHODS`.

    Attributes
    ----------
    name
        Its key in the table (``"block-jacobi-pcg"``).
    kind
        ``"solver"``: ``function(problem, **options) -> SolverResult`` solves eq. 1 set up by
        :func:`~.operators.build_problem`; ``"baseline"`` (a published method, for
        comparison) and ``"estimator"`` (this project's own, :mod:`.estimators`):
        ``function(inputs, **options) -> cube`` maps the checked inputs straight to a cube
        ``(wavelength, image, y, x)``.
    function
        The implementation.
    dtype
        Floating dtype the method works in (a solver's problem is set up in it directly,
        unless the ``dtype`` option says otherwise).
    description
        One line for tables and messages.
    setup_defaults
        A solver's own defaults for set-up options of :data:`SETUP_OPTIONS` (e.g. its
        appearance space); empty for eq. 1 as the paper sets it up.
    """

    name: str
    kind: Literal["solver", "baseline", "estimator"]
    function: Callable[..., Any]
    dtype: np.dtype
    description: str
    setup_defaults: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))

    @property
    def options(self) -> dict[str, inspect.Parameter]:
        """Every option :func:`~spectralize.nodes.reconstruction.reconstruct` takes for this
        method, by name, with its default (set-up options first for a solver)."""
        own = _keyword_options(self.function)
        return {**SETUP_OPTIONS, **own} if self.kind == "solver" else own

    def defaults(self) -> dict[str, Any]:
        """Option name -> default value."""
        defaults = {name: parameter.default for name, parameter in self.options.items()}
        return {**defaults, **self.setup_defaults}


def _method(
    name: str,
    kind: Literal["solver", "baseline", "estimator"],
    function: Callable[..., Any],
    dtype: type,
    description: str,
    setup_defaults: Mapping[str, Any] | None = None,
) -> ReconstructionMethod:
    return ReconstructionMethod(
        name, kind, function, np.dtype(dtype), description, MappingProxyType(dict(setup_defaults or {}))
    )


RECONSTRUCTION_METHODS: dict[str, ReconstructionMethod] = {
    method.name: method
    for method in (
        _method(
            "block-jacobi-pcg",
            "solver",
            block_jacobi_pcg,
            np.float32,
            "eq. 1 alone: block-Jacobi preconditioned CG, float32, warm-started",
        ),
        _method(
            "guided-prior-pcg",
            "solver",
            guided_prior_pcg,
            np.float32,
            "eq. 1 plus a prior towards the RGB-guided filtered bands (weight: prior)",
        ),
        _method(
            "material-prior-pcg",
            "solver",
            material_prior_pcg,
            np.float32,
            "eq. 1, chromaticity+position neighbours, scale-invariant coupling, guided prior, S >= 0",
            MATERIAL_SETUP_DEFAULTS,
        ),
        _method(
            "spectral-prior-pcg",
            "solver",
            spectral_prior_pcg,
            np.float32,
            "material-prior-pcg plus a Gaussian spectral prior learnt from the guided estimate",
            SPECTRAL_SETUP_DEFAULTS,
        ),
        _method(
            "mixture-prior-pcg",
            "solver",
            mixture_prior_pcg,
            np.float32,
            "spectral-prior-pcg with its prior learnt from and centred on endmember-mixture",
            SPECTRAL_SETUP_DEFAULTS,
        ),
        _method(
            "endmember-mixture",
            "estimator",
            endmember_mixture,
            np.float64,
            "non-negative mixtures of endmembers learnt from all band shots, weights from RGB",
        ),
        _method(
            "paper-cg",
            "solver",
            paper_cg,
            np.float64,
            "the paper's CG on the normal equations (CGNR), float64, from zero",
        ),
        _method("pseudo-inverse", "baseline", pseudo_inverse, np.float64, "S = C^+ R (Imai and Berns)"),
        _method(
            "wiener",
            "baseline",
            wiener_estimation,
            np.float64,
            "Wiener estimation from RGB with a training-set prior",
        ),
        _method(
            "mallett2019",
            "baseline",
            mallett2019_basis,
            np.float64,
            "Mallett and Yuksel (2019) basis fitted to the camera RGB",
        ),
        _method(
            "filtered-bands",
            "baseline",
            filtered_bands,
            np.float64,
            "band images filtered by their Gaussian (sigma = s_i / 5) alone",
        ),
        _method(
            "filtered-projected",
            "baseline",
            filtered_bands_projected,
            np.float64,
            "filtered bands projected onto C S = R",
        ),
        _method(
            "guided-projected",
            "baseline",
            guided_filtered_projected,
            np.float64,
            "RGB-guided filtered bands projected onto C S = R",
        ),
    )
}
"""Every reconstruction method by name; see :class:`ReconstructionMethod`. A plugin adds a
method by adding a record."""

DEFAULT_METHOD = "mixture-prior-pcg"
"""Eq. 1 with neighbourhoods that separate materials, coupled scale-invariantly, the guided
prior, a spectral prior centred on the endmember-mixture estimate, and ``S >= 0``
(:mod:`~.solvers.mixture_prior_pcg`). Measured (``benchmarks/reconstruction.py``, README):
against the previous default ``"spectral-prior-pcg"`` a lower p95 on six and a lower median
on five of the eight hard scene x mode rows, and more accurate on the earlier scene; eq. 1
alone (``"block-jacobi-pcg"``, the paper's method) stays selectable."""


def get_method(name: str) -> ReconstructionMethod:
    """The record of method ``name``.

    Raises
    ------
    ReconstructionError
        For an unknown name, listing the known ones.
    """
    if name not in RECONSTRUCTION_METHODS:
        raise ReconstructionError(
            f"unknown method {name!r}; known methods: {', '.join(sorted(RECONSTRUCTION_METHODS))}"
        )
    return RECONSTRUCTION_METHODS[name]
