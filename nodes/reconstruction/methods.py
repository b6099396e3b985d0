"""The reconstruction methods as data: production presets and comparison baselines.

:data:`RECONSTRUCTION_METHODS` holds the production methods, the values the set nodes'
``method`` takes; :data:`BASELINE_METHODS` the published methods this project compares
against (benchmarks and evaluation). Both map a name to a :class:`ReconstructionMethod`
record (its kind, function, working dtype and settings), as colour-science's
``XYZ_TO_SD_METHODS`` does; :func:`~spectralize.nodes.reconstruction.api.reconstruct`
dispatches on either.

A production preset is one of three solver implementations (:mod:`.solvers`) or the
estimator (:mod:`.estimators`) with one dict of *every* setting: for a solver the problem
set-up of :func:`~spectralize.nodes.reconstruction.operators.build_problem` (eq. 4 weights,
neighbours, filter placement) and the solver's own settings. The API and the nodes start
from that dict, so a preset's settings are read here and nowhere else; an option given by
the caller replaces its setting. The run-time inputs :data:`RUN_INPUTS` are no settings.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1 and 4.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
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
from .solvers import block_jacobi_pcg, paper_cg, prior_pcg

__all__ = [
    "ReconstructionMethod",
    "RECONSTRUCTION_METHODS",
    "BASELINE_METHODS",
    "DEFAULT_METHOD",
    "RUN_INPUTS",
    "SETUP_OPTIONS",
    "SET_MODEL_OPTIONS",
    "SET_MODELS",
    "get_method",
]

RUN_INPUTS = ("initial", "callback", "endmembers")
"""Keyword arguments that are inputs of one run, not settings of a method: a warm start,
an iteration callback, a set's endmember dictionary."""


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
``normalize_camera_matrix``, ``appearance``, ``scale_invariant``."""


SET_MODELS = ("independent", "shared-texel", "material-pooled")
"""The values of a solver's ``set_model`` setting: ``"independent"`` keeps the solver's
spectra; ``"shared-texel"`` refits a set of more than one image with per-texel spectral
shapes shared by its images (:func:`~.estimators.shared_texel.shared_texel_refine`);
``"material-pooled"`` refits it with one shape per material (texels clustered by their
shapes), fitted to the pooled band shots of the material's texels
(:func:`~.estimators.material_pooled.material_pooled_refine`). Both need the illuminant
(:func:`~spectralize.nodes.reconstruction.reconstruct`)."""

SET_MODEL_OPTIONS: Mapping[str, inspect.Parameter] = MappingProxyType(
    {"set_model": inspect.Parameter("set_model", inspect.Parameter.KEYWORD_ONLY, default="independent")}
)
"""The option every solver takes after its solve: ``set_model`` (:data:`SET_MODELS`)."""


@dataclass(frozen=True)
class ReconstructionMethod:
    """One method of :data:`RECONSTRUCTION_METHODS` or :data:`BASELINE_METHODS`.

    Attributes
    ----------
    name
        Its key in the table (``"mixture-prior-pcg"``).
    kind
        ``"solver"``: ``function(problem, **settings) -> SolverResult`` solves eq. 1 set up
        by :func:`~.operators.build_problem`; ``"estimator"`` (this project's own,
        :mod:`.estimators`) and ``"baseline"`` (a published method, for comparison):
        ``function(inputs, **settings) -> cube`` maps the checked inputs straight to a cube
        ``(wavelength, image, y, x)``.
    function
        The implementation.
    dtype
        Floating dtype the method works in (a solver's problem is set up in it, unless the
        ``dtype`` setting says otherwise).
    description
        One line for tables and messages.
    settings
        Every setting, by name: for a solver the set-up options of :data:`SETUP_OPTIONS`
        and the function's own keyword arguments, :data:`RUN_INPUTS` left out.
    """

    name: str
    kind: Literal["solver", "baseline", "estimator"]
    function: Callable[..., Any]
    dtype: np.dtype
    description: str
    settings: Mapping[str, Any]

    @property
    def options(self) -> dict[str, inspect.Parameter]:
        """Every option :func:`~spectralize.nodes.reconstruction.reconstruct` takes for this
        method, by name (set-up options first for a solver)."""
        own = _keyword_options(self.function)
        return {**SETUP_OPTIONS, **own, **SET_MODEL_OPTIONS} if self.kind == "solver" else own

    def defaults(self) -> dict[str, Any]:
        """Option name -> the value a run uses unless the caller gives one: the settings,
        and None for the run-time inputs."""
        return {name: self.settings.get(name) for name in self.options}


def _method(
    name: str,
    kind: Literal["solver", "baseline", "estimator"],
    function: Callable[..., Any],
    dtype: type,
    description: str,
    settings: Mapping[str, Any] | None = None,
) -> ReconstructionMethod:
    """A record; without ``settings``, the function's own keyword defaults are its settings."""
    if settings is None:
        settings = {
            name: parameter.default
            for name, parameter in _keyword_options(function, leave_out=RUN_INPUTS).items()
        }
    return ReconstructionMethod(
        name, kind, function, np.dtype(dtype), description, MappingProxyType(dict(settings))
    )


_MIXTURE_PRIOR_SETTINGS: dict[str, Any] = {
    # the problem (eq. 4 and neighbourhoods that separate materials)
    "alpha_hat": 1.0,
    "beta_hat": 1.0,
    "gamma_hat": None,
    "k": 6,
    "centre_spacing": 2.5,
    "normalize_camera_matrix": True,
    "appearance": "chromaticity-spatial",
    "scale_invariant": True,
    # the priors
    "prior": 0.3,
    "prior_weighting": "brightness",
    "spectral_prior": 0.003,
    "prior_source": "mixture",
    "natural_prior": 0.0,
    "covariance_floor": 1e-2,
    "ridge": 1e-4,
    # the solve
    "tolerance": 3e-3,
    "max_iterations": 2000,
    "projected_iterations": 10,
    "precondition": True,
    "dtype": np.float32,
    "set_model": "independent",
}
"""The settings of ``"mixture-prior-pcg"``; ``"natural-prior-pcg"`` differs only in its prior's
centre (``prior_source``, ``natural_prior``) and its set model (``set_model``),
``"spectral-prior-pcg"`` in its priors' source and weighting and its stopping rule."""


RECONSTRUCTION_METHODS: dict[str, ReconstructionMethod] = {
    method.name: method
    for method in (
        _method(
            "block-jacobi-pcg",
            "solver",
            block_jacobi_pcg,
            np.float32,
            "eq. 1 alone, as the paper sets it up: block-Jacobi preconditioned CG, float32",
            {
                "alpha_hat": 1.0,
                "beta_hat": 1.0,
                "gamma_hat": None,
                "k": 3,
                "centre_spacing": 2.5,
                "normalize_camera_matrix": True,
                "appearance": "rgb",
                "scale_invariant": False,
                "prior": 0.0,
                "ridge": 1e-4,
                "tolerance": 1e-3,
                "max_iterations": 2000,
                "precondition": True,
                "dtype": np.float32,
                "set_model": "independent",
            },
        ),
        _method(
            "guided-prior-pcg",
            "solver",
            block_jacobi_pcg,
            np.float32,
            "eq. 1 as the paper sets it up plus a prior towards the RGB-guided filtered bands",
            {
                "alpha_hat": 1.0,
                "beta_hat": 1.0,
                "gamma_hat": None,
                "k": 3,
                "centre_spacing": 2.5,
                "normalize_camera_matrix": True,
                "appearance": "rgb",
                "scale_invariant": False,
                "prior": 0.1,
                "ridge": 1e-4,
                "tolerance": 1e-3,
                "max_iterations": 2000,
                "precondition": True,
                "dtype": np.float32,
                "set_model": "independent",
            },
        ),
        _method(
            "spectral-prior-pcg",
            "solver",
            prior_pcg,
            np.float32,
            "eq. 1 on material neighbourhoods, the guided prior and a spectral prior learnt "
            "from the scene's guided estimate, then S >= 0",
            {
                **_MIXTURE_PRIOR_SETTINGS,
                "prior": 0.1,
                "prior_weighting": "uniform",
                "prior_source": "scene",
                "tolerance": 1e-3,
                "projected_iterations": 40,
            },
        ),
        _method(
            "natural-prior-pcg",
            "solver",
            prior_pcg,
            np.float32,
            "eq. 1 on material neighbourhoods, a brightness-weighted guided prior and a "
            "spectral prior centred per pixel between the endmember mixture and the natural-"
            "spectra (Wiener) estimate by the band evidence, then S >= 0",
            {
                **_MIXTURE_PRIOR_SETTINGS,
                "prior_source": "natural",
                "natural_prior": 0.001,
                "set_model": "material-pooled",
            },
        ),
        _method(
            "mixture-prior-pcg",
            "solver",
            prior_pcg,
            np.float32,
            "eq. 1 on material neighbourhoods, a brightness-weighted guided prior and a "
            "spectral prior centred on the endmember mixture, then S >= 0",
            _MIXTURE_PRIOR_SETTINGS,
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
            "eq. 1 by the paper's CG on the normal equations (CGNR), float64, from zero",
            {
                "alpha_hat": 1.0,
                "beta_hat": 1.0,
                "gamma_hat": None,
                "k": 3,
                "centre_spacing": 2.5,
                "normalize_camera_matrix": True,
                "appearance": "rgb",
                "scale_invariant": False,
                "tolerance": 1e-3,
                "max_iterations": 2000,
                "set_model": "independent",
            },
        ),
    )
}
"""The production methods by name: what the set nodes' ``method`` takes. Each stays for a
reason:

``"natural-prior-pcg"``
    The default (:data:`DEFAULT_METHOD`): ``"mixture-prior-pcg"`` plus the natural-spectra
    prior, weighed per pixel by the band evidence; a lower median than it on 7 of the
    benchmark's 8 scene x mode rows, and than the RGB-only baselines on 7 of 8.
``"mixture-prior-pcg"``
    The previous default: the lowest median on woven sets (1 % below the default) and
    the lowest p95 on some single images (1-3 %).
``"spectral-prior-pcg"``
    The same solver with a spectral prior learnt from the scene's guided estimate: a lower
    median than the default on some of the hard scenes.
``"guided-prior-pcg"``
    Eq. 1 as the paper sets it up plus the guided prior: more accurate than the default on
    one of the real measured scenes, and the fastest of the priors.
``"block-jacobi-pcg"``
    Eq. 1 alone, the paper's model, solved fast: the reference for what the priors add.
``"paper-cg"``
    The paper's own solver, the reference for the fast solvers' accuracy and speed.
``"endmember-mixture"``
    The default's spectral prior on its own: non-iterative, several times faster, close
    to the default at the median.

The default's ``set_model`` is ``"material-pooled"``: a set of more than one image given
the illuminant is refitted with one spectral shape per material (:data:`SET_MODELS`; better
than ``"independent"`` at the median and p95 on every hard set, and at the fraction of
pixels under 0.03); without the illuminant it keeps its spectra (``"independent"``, recorded
in the result's attrs). Every other preset's is ``"independent"``; ``"shared-texel"`` and
``"material-pooled"`` are opt-in there.

Retired: ``"material-prior-pcg"``, the prior PCG without the spectral prior, never best on
the benchmark; it is ``method="spectral-prior-pcg", spectral_prior=0``. The figures are in
``benchmarks/results/reconstruction.json``."""

BASELINE_METHODS: dict[str, ReconstructionMethod] = {
    method.name: method
    for method in (
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
"""The comparison baselines by name (published methods, and the estimates the solvers start
from): :func:`~spectralize.nodes.reconstruction.reconstruct` runs them for benchmarks and
evaluation; the nodes do not take them."""

DEFAULT_METHOD = "natural-prior-pcg"
"""The default preset: eq. 1 with neighbourhoods that separate materials, coupled
scale-invariantly, a guided prior weighted by brightness and a spectral prior, both centred
per pixel between the endmember-mixture estimate and the natural-spectra (Wiener) estimate
by the band evidence (:mod:`.solvers.natural_prior`, :mod:`.solvers.band_evidence`), and
``S >= 0`` (:func:`~.solvers.prior_pcg.prior_pcg`); its settings are
``RECONSTRUCTION_METHODS[DEFAULT_METHOD].settings``."""


def get_method(name: str) -> ReconstructionMethod:
    """The record of method ``name``, production or baseline.

    Raises
    ------
    ReconstructionError
        For an unknown name, listing the known ones.
    """
    record = RECONSTRUCTION_METHODS.get(name) or BASELINE_METHODS.get(name)
    if record is None:
        raise ReconstructionError(
            f"unknown method {name!r}; methods: {', '.join(RECONSTRUCTION_METHODS)}; "
            f"baselines: {', '.join(BASELINE_METHODS)}"
        )
    return record
