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

:func:`resolve_method` is the one place a method is looked up, its default applied and the
caller's options checked: it returns a :class:`ResolvedMethod`, the preset's settings with
the caller's laid over them, which the API, the nodes and the tiled path pass on (as xarray's
``get_backend`` takes a name or the backend itself, every function that takes a method takes
a name, a record or a resolved record, and resolves it no more than once).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1 and 4.

Examples
--------
The tables' names, a preset's settings, and a preset resolved with an option that replaces
one of them:

>>> list(RECONSTRUCTION_METHODS)  # doctest: +NORMALIZE_WHITESPACE
['block-jacobi-pcg', 'guided-prior-pcg', 'spectral-prior-pcg', 'natural-prior-pcg',
 'mixture-prior-pcg', 'endmember-mixture', 'sparse-choice', 'paper-cg']
>>> list(BASELINE_METHODS)  # doctest: +NORMALIZE_WHITESPACE
['pseudo-inverse', 'wiener', 'mallett2019', 'filtered-bands', 'filtered-projected',
 'guided-projected', 'hysure', 'cnmf']
>>> preset = RECONSTRUCTION_METHODS["guided-prior-pcg"]
>>> preset.kind, preset.settings["prior"], preset.settings["k"]
('solver', 0.1, 3)
>>> resolved = resolve_method("guided-prior-pcg", prior=0.3)
>>> resolved.settings["prior"], resolved.settings["k"], dict(resolved.given)
(0.3, 3, {'prior': 0.3})
>>> resolve_method().name == DEFAULT_METHOD
True
"""

from __future__ import annotations

import difflib
import inspect
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, Literal

import numpy as np

from spectralize.schemas.errors import ReconstructionError

from .baselines import (
    cnmf,
    filtered_bands,
    filtered_bands_projected,
    guided_filtered_projected,
    hysure,
    mallett2019_basis,
    pseudo_inverse,
    wiener_estimation,
)
from .estimators import endmember_mixture, sparse_choice
from .operators import build_problem
from .solvers import block_jacobi_pcg, paper_cg, prior_pcg

__all__ = [
    "ReconstructionMethod",
    "ResolvedMethod",
    "MethodLike",
    "RECONSTRUCTION_METHODS",
    "BASELINE_METHODS",
    "DEFAULT_METHOD",
    "RUN_INPUTS",
    "SETUP_OPTIONS",
    "SET_MODEL_OPTIONS",
    "SET_MODELS",
    "get_method",
    "resolve_method",
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


SET_MODELS = ("independent", "shared-texel", "material-pooled", "evidence-blend")
"""The values of a solver's ``set_model`` setting: ``"independent"`` keeps the solver's
spectra; ``"shared-texel"`` refits a set of more than one image with per-texel spectral
shapes shared by its images (:func:`~.estimators.shared_texel.shared_texel_refine`);
``"material-pooled"`` refits it with one shape per material (texels clustered by their
shapes), fitted to the pooled band shots of the material's texels
(:func:`~.estimators.material_pooled.material_pooled_refine`); ``"evidence-blend"`` is
``"material-pooled"`` and then, given the run's endmember library (``endmembers``), each
texel's materials chosen over the set from it and the spectra moved towards the choice's by
the posterior of the texel's band shots
(:func:`~.estimators.evidence_blend.material_choice_blend`; without a library it is
``"material-pooled"``). All need the illuminant
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


@dataclass(frozen=True)
class ResolvedMethod:
    """A method resolved with the caller's options: what a run solves with.

    Made by :func:`resolve_method` only, which checks the options once; the API, the nodes
    and the tiled path pass it on instead of a name and loose options, so a method is looked
    up and its options checked once per run, not once per function or tile.

    Attributes
    ----------
    method
        The record of :data:`RECONSTRUCTION_METHODS` or :data:`BASELINE_METHODS` (or the
        caller's own :class:`ReconstructionMethod`).
    given
        The options the caller gave, checked (a given ``set_model`` is applied or refused,
        a preset's own is applied where it can be: :func:`~.api.reconstruct`).
    settings
        The record's settings with ``given`` laid over them: every setting the run uses.

    Examples
    --------
    >>> resolved = resolve_method("block-jacobi-pcg", k=4)
    >>> resolved.name, resolved.settings["k"], resolved.settings["prior"], dict(resolved.given)
    ('block-jacobi-pcg', 4, 0.0, {'k': 4})
    >>> resolve_method(resolved) is resolved  # resolved once, passed on
    True
    """

    method: ReconstructionMethod
    given: Mapping[str, Any]
    settings: Mapping[str, Any]

    @property
    def name(self) -> str:
        """The method's name (its key in the tables)."""
        return self.method.name

    @property
    def kind(self) -> Literal["solver", "baseline", "estimator"]:
        """The method's kind (:attr:`ReconstructionMethod.kind`)."""
        return self.method.kind

    @property
    def options(self) -> dict[str, inspect.Parameter]:
        """Every option the method takes (:attr:`ReconstructionMethod.options`)."""
        return self.method.options

    def used(self) -> dict[str, Any]:
        """Option name -> the value a run uses: the settings, and None for the run-time
        inputs (:data:`RUN_INPUTS`), in the order of :attr:`options`."""
        return {name: self.settings.get(name) for name in self.options}

    def run_inputs(self, **inputs: Any) -> dict[str, Any]:
        """``inputs`` (:data:`RUN_INPUTS`: a warm start, a callback, an endmember dictionary),
        checked against the method's options like any option.

        Raises
        ------
        ReconstructionError
            For an input the method does not take, listing its options.
        """
        _check_names(self.method, inputs, run_inputs=True)
        return inputs

    def __reduce__(self) -> tuple[Any, ...]:
        # plain pickle (a dask.distributed task) takes no MappingProxyType
        method = self.method
        record = (method.name, method.kind, method.function, method.dtype, method.description)
        return (_resolved, (record, dict(method.settings), dict(self.given), dict(self.settings)))

    def __dask_tokenize__(self) -> tuple[Any, ...]:
        function = self.method.function
        return (
            type(self).__name__,
            self.name,
            f"{function.__module__}.{function.__qualname__}",
            str(self.method.dtype),
            tuple((name, repr(value)) for name, value in self.settings.items()),
            tuple(self.given),
        )


def _resolved(
    record: tuple[Any, ...], settings: dict[str, Any], given: dict[str, Any], used: dict[str, Any]
) -> ResolvedMethod:
    """A :class:`ResolvedMethod` again from its pickled parts (no look-up, no checks)."""
    name, kind, function, dtype, description = record
    method = ReconstructionMethod(name, kind, function, dtype, description, MappingProxyType(settings))
    return ResolvedMethod(method, MappingProxyType(given), MappingProxyType(used))


MethodLike = str | ReconstructionMethod | ResolvedMethod
"""What every function that takes a method takes: a name of :data:`RECONSTRUCTION_METHODS`
or :data:`BASELINE_METHODS`, a record, or a record resolved with its options."""


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


# -- the presets, composed from the blocks they share --------------------------------------------
_PAPER_SETUP: dict[str, Any] = {
    "alpha_hat": 1.0,
    "beta_hat": 1.0,
    "gamma_hat": None,
    "k": 3,
    "centre_spacing": 2.5,
    "normalize_camera_matrix": True,
    "appearance": "rgb",
    "scale_invariant": False,
}
"""Eq. 1 as the paper sets it up (:data:`SETUP_OPTIONS`): eq. 4's weights, 3 neighbours in
RGB, filter centres at most 2.5 px apart."""

_MATERIAL_SETUP: dict[str, Any] = {
    **_PAPER_SETUP,
    "k": 6,
    "appearance": "chromaticity-spatial",
    "scale_invariant": True,
}
"""Eq. 1 on neighbourhoods that separate materials: 6 neighbours by chromaticity and
position, coupled scale-invariantly (``S(p) - (b_p / b_n) S(n)``)."""

_CG_STOP: dict[str, Any] = {"tolerance": 1e-3, "max_iterations": 2000}
"""When a CG stops: the relative normal-equation residual, and an iteration limit."""

_PCG_SOLVE: dict[str, Any] = {
    "ridge": 1e-4,
    **_CG_STOP,
    "precondition": True,
    "dtype": np.float32,
}
"""The block-Jacobi preconditioned CG in float32 (:mod:`.solvers.block_jacobi_pcg`)."""

_MIXTURE_PRIORS: dict[str, Any] = {
    "prior": 0.3,
    "prior_weighting": "brightness",
    "spectral_prior": 0.003,
    "prior_source": "mixture",
    "natural_prior": 0.0,
    "covariance_floor": 1e-2,
}
"""A brightness-weighted guided prior and a spectral prior centred on the endmember mixture
(:func:`~.solvers.prior_pcg.prior_pcg`)."""

_PRIOR_SOLVE: dict[str, Any] = {
    "ridge": 1e-4,
    **_CG_STOP,
    "tolerance": 3e-3,
    "projected_iterations": 10,
    "precondition": True,
    "dtype": np.float32,
}
"""The prior PCG's solve: as :data:`_PCG_SOLVE`, stopped earlier, then ``S >= 0`` refined."""

_INDEPENDENT: dict[str, Any] = {"set_model": "independent"}
"""Every image of a set keeps its solver's spectra (:data:`SET_MODELS`)."""

_MIXTURE_PRIOR_SETTINGS: dict[str, Any] = {
    **_MATERIAL_SETUP,
    **_MIXTURE_PRIORS,
    **_PRIOR_SOLVE,
    **_INDEPENDENT,
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
            {**_PAPER_SETUP, "prior": 0.0, **_PCG_SOLVE, **_INDEPENDENT},
        ),
        _method(
            "guided-prior-pcg",
            "solver",
            block_jacobi_pcg,
            np.float32,
            "eq. 1 as the paper sets it up plus a prior towards the RGB-guided filtered bands",
            {**_PAPER_SETUP, "prior": 0.1, **_PCG_SOLVE, **_INDEPENDENT},
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
                "set_model": "evidence-blend",
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
            "sparse-choice",
            "estimator",
            sparse_choice,
            np.float64,
            "each texel's few endmembers chosen once over all images of its set (dichromatic "
            "candidates, RGB and band chi^2, a size penalty), weights from each image's RGB",
        ),
        _method(
            "paper-cg",
            "solver",
            paper_cg,
            np.float64,
            "eq. 1 by the paper's CG on the normal equations (CGNR), float64, from zero",
            {**_PAPER_SETUP, **_CG_STOP, **_INDEPENDENT},
        ),
    )
}
"""The production methods by name: what the set nodes' ``method`` takes. Each stays for a
reason (the measurements: ``benchmarks/results/reconstruction.json``):

``"natural-prior-pcg"``
    The default (:data:`DEFAULT_METHOD`): ``"mixture-prior-pcg"`` plus the natural-spectra
    prior, weighed per pixel by the band evidence; the lowest median error on most of the
    benchmark's scenes and capture modes, ahead of the RGB-only baselines.
``"mixture-prior-pcg"``
    The previous default: still the lowest median error on woven sets and the lowest p95
    on some single images.
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
    The default's spectral prior on its own: non-iterative, much faster, close to the
    default at the median.
``"sparse-choice"``
    Each texel's materials chosen over all images of its set: with a run's library pooled
    from several sets (``endmembers``) a lower median than the default on the woven,
    halftone and glossy sets, but a higher p95 on most; not the default for that, and for
    needing a library better than one set gives; the default's set model weighs it in per
    texel where the band evidence favours it (``"evidence-blend"``). Its ``context`` options
    (off by default) let each texel's RGB-similar neighbours add their evidence and their
    chosen endmembers to its choice.

The default's ``set_model`` is ``"evidence-blend"``: a set of more than one image given
the illuminant is refitted with one spectral shape per material (``"material-pooled"``,
better than ``"independent"`` on the hard sets) and, given the run's library, weighed per
texel against the material choice by the band evidence (:data:`SET_MODELS`; lower error than
``"material-pooled"`` on the hard sets with the run's library); without the illuminant it
keeps its spectra (``"independent"``), without a library it stops after the pooled refit
(``"material-pooled"``), as recorded in the result's attrs. Every other preset's is
``"independent"``; the other set models are opt-in there.

Retired: ``"material-prior-pcg"``, the prior PCG without the spectral prior, never best on
the benchmark; it is ``method="spectral-prior-pcg", spectral_prior=0``.
"""

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
        _method(
            "hysure",
            "baseline",
            hysure,
            np.float64,
            "HySure (Simoes et al. 2015): filtered bands fused with the RGB in a subspace, vector TV",
        ),
        _method(
            "cnmf",
            "baseline",
            cnmf,
            np.float64,
            "CNMF (Yokoya et al. 2012): filtered bands and RGB unmixed by coupled NMF",
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
        close = difflib.get_close_matches(str(name), [*RECONSTRUCTION_METHODS, *BASELINE_METHODS], n=1)
        raise ReconstructionError(
            f"unknown method {name!r}"
            + (f" (did you mean {close[0]!r}?)" if close else "")
            + f"; methods: {', '.join(RECONSTRUCTION_METHODS)}; "
            f"baselines: {', '.join(BASELINE_METHODS)}"
        )
    return record


def resolve_method(method: MethodLike | None = None, /, **options: Any) -> ResolvedMethod:
    """``method`` with ``options`` laid over its settings, checked: the one place a method is
    looked up and its default applied.

    Parameters
    ----------
    method
        A name of :data:`RECONSTRUCTION_METHODS` or :data:`BASELINE_METHODS`, a
        :class:`ReconstructionMethod`, or a :class:`ResolvedMethod` (returned as it is
        without ``options``; with them, its options and these resolved together). None:
        :data:`DEFAULT_METHOD`.
    **options
        Settings that replace the method's (names of its :attr:`~ReconstructionMethod.options`
        other than the run-time inputs :data:`RUN_INPUTS`).

    Returns
    -------
    ResolvedMethod

    Raises
    ------
    ReconstructionError
        For an unknown method (listing the known ones), an option the method does not take
        (listing its options, the closest name and the methods that take it), a run-time
        input given as a setting, or a value out of range (a weight, a count, a set model).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1 and 4.

    Examples
    --------
    >>> resolve_method().name  # the default
    'natural-prior-pcg'
    >>> resolve_method("paper-cg", tolerance=1e-6).settings["tolerance"]
    1e-06
    >>> try:
    ...     resolve_method("paper-cg", tolerence=1e-6)
    ... except ReconstructionError as error:
    ...     print(error)  # doctest: +ELLIPSIS
    method 'paper-cg': unknown option(s) ['tolerence'] (did you mean 'tolerance'?); its ...
    """
    if isinstance(method, ResolvedMethod):
        if not options:
            return method
        options = {**method.given, **options}
        method = method.method
    if method is None:
        method = DEFAULT_METHOD
    if isinstance(method, str):
        method = get_method(method)
    if not isinstance(method, ReconstructionMethod):
        raise ReconstructionError(
            "method: expected a method name, a ReconstructionMethod or a ResolvedMethod, "
            f"found {type(method).__name__}"
        )
    _check_names(method, options)
    _check_values(options)
    given = MappingProxyType(dict(options))
    return ResolvedMethod(method, given, MappingProxyType({**method.settings, **options}))


def _check_names(
    method: ReconstructionMethod, options: Mapping[str, Any], *, run_inputs: bool = False
) -> None:
    """Refuse options the method does not take, and run-time inputs given as settings
    (unless ``run_inputs``: they are what is checked)."""
    known = method.options
    unknown = sorted(set(options) - set(known))
    if unknown:
        every = {**RECONSTRUCTION_METHODS, **BASELINE_METHODS}
        takers = {name: [m for m, r in every.items() if name in r.options] for name in unknown}
        hints = "; ".join(f"{name!r} is an option of {', '.join(t)}" for name, t in takers.items() if t)
        close = {name: difflib.get_close_matches(name, list(known), n=1) for name in unknown}
        means = ", ".join(f"{c[0]!r}" for c in close.values() if c)
        raise ReconstructionError(
            f"method {method.name!r}: unknown option(s) {unknown}"
            + (f" (did you mean {means}?)" if means else "")
            + f"; its options are: {', '.join(known) or 'none'}"
            + (f" ({hints})" if hints else "")
        )
    inputs = [name for name in options if (name in RUN_INPUTS) != run_inputs]
    if inputs and run_inputs:
        raise ReconstructionError(
            f"method {method.name!r}: {inputs} are settings, not inputs of one run; resolve "
            "them with the method (resolve_method)"
        )
    if inputs:
        raise ReconstructionError(
            f"method {method.name!r}: {inputs} are inputs of one run, not settings; pass them "
            "to reconstruct(...) (or solve_set) with the method"
        )


_POSITIVE = ("alpha_hat", "beta_hat", "centre_spacing", "tolerance", "window_scale", "covariance_floor")
_NON_NEGATIVE = ("gamma_hat", "prior", "spectral_prior", "ridge", "relative_noise", "epsilon")
_INTEGER = {"k": 1, "max_iterations": 0, "projected_iterations": 0}


def _check_values(options: Mapping[str, Any]) -> None:
    """Refuse weights, counts and set models out of range, naming the option."""
    for name, value in options.items():
        if name in _POSITIVE and not (_is_real(value) and np.isfinite(value) and value > 0):
            raise ReconstructionError(f"{name}: expected a finite number > 0, found {value!r}")
        if (
            name in _NON_NEGATIVE
            and value is not None
            and not (_is_real(value) and np.isfinite(value) and value >= 0)
        ):
            raise ReconstructionError(f"{name}: expected a finite number >= 0, found {value!r}")
        if name == "set_model" and value not in SET_MODELS:
            raise ReconstructionError(
                f"set_model: expected one of {', '.join(map(repr, SET_MODELS))}, found {value!r}"
            )
        if name in _INTEGER and not (
            _is_real(value) and int(value) == value and value >= _INTEGER[name]
        ):
            raise ReconstructionError(
                f"{name}: expected an integer >= {_INTEGER[name]}, found {value!r}"
            )


def _is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)
