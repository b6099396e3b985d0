"""The one reconstruction entry point, :func:`reconstruct`: xarray in, xarray out.

A thin layer over the numpy numerics: it brings the input forms to one (a set of images
with band shots), checks them (:mod:`.inputs`), resolves the method with the caller's
options (:func:`~.methods.resolve_method`: the record of
:data:`~.methods.RECONSTRUCTION_METHODS` or :data:`~.methods.BASELINE_METHODS`, its settings
with the options laid over them, checked once) and dispatches.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 3 and 5.
"""

from __future__ import annotations

import numbers
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
import xarray as xr

from spectralize.schemas.errors import ReconstructionError
from spectralize.schemas.run import SPECTRA

from .confidence import CONFIDENCE_NEIGHBOURS, neighbourhood_spread
from .estimators.evidence_blend import material_choice_blend
from .estimators.material_pooled import material_pooled_refine
from .estimators.shared_texel import shared_texel_refine
from .inputs import ReconstructionInputs, inputs_from_xarray
from .methods import (
    RUN_INPUTS,
    SET_MODEL_OPTIONS,
    SETUP_OPTIONS,
    MethodLike,
    ResolvedMethod,
    resolve_method,
)
from .operators import ReconstructionProblem, build_problem
from .weights import default_gamma_hat

__all__ = ["reconstruct", "ReconstructionResult"]


@dataclass
class ReconstructionResult:
    """Spectra and solver record of one reconstruction (``reconstruct(..., full_output=True)``).

    Attributes
    ----------
    spectra
        What :func:`reconstruct` returns: ``(image, wavelength, y, x)`` float32 (or
        ``(wavelength, y, x)`` for a single ``(y, x, channel)`` image).
    iterations
        Solver iterations (0 for a baseline).
    residual_history
        Relative normal-equation residual before and after every iteration (empty for a
        baseline).
    converged
        Whether the tolerance was reached (``True`` for a baseline).
    wall_time
        Seconds for the whole call (checks, neighbour search, set-up and solve).
    setup_time
        Seconds of that for checks, neighbour search and operator set-up.
    method
        Method name.
    problem
        The :class:`~.operators.ReconstructionProblem` solved (operators, weights, neighbour
        graph); ``None`` for a baseline.
    confidence
        Per-pixel error estimate, dims like ``spectra`` without ``wavelength``
        (:func:`~.confidence.neighbourhood_spread`: higher means trust less); ``None`` when
        not asked for.
    """

    spectra: xr.DataArray
    iterations: int
    residual_history: np.ndarray
    converged: bool
    wall_time: float
    setup_time: float
    method: str
    problem: ReconstructionProblem | None = field(default=None, repr=False)
    confidence: xr.DataArray | None = field(default=None, repr=False)


# -- input forms ---------------------------------------------------------------------------
def _is_array(value: object, dims: set[str]) -> bool:
    return isinstance(value, xr.DataArray) and set(value.dims) == dims and len(value.dims) == 3


def _band_cube_as_shots(
    cube: xr.DataArray, rgb: xr.DataArray, filter_size: float | Sequence[float] | None
) -> xr.DataArray:
    """A ``(y, x, wavelength)`` band cube of one image as ``(shot, y, x)`` shots of it."""
    if rgb.sizes.get("image", 1) != 1:
        raise ReconstructionError(
            f"bands: a (y, x, wavelength) band cube is one image's bands, but rgb has "
            f"{rgb.sizes['image']} images; give bands as (shot, y, x) with the coordinates "
            "wavelength, image and filter_size along shot"
        )
    if "wavelength" not in cube.coords:
        raise ReconstructionError(
            "bands: expected a 'wavelength' coordinate [nm] on the "
            "(y, x, wavelength) band cube, found none"
        )
    cube = cube.transpose("wavelength", "y", "x")
    n_band = cube.sizes["wavelength"]
    coord = cube.coords.get("filter_size")
    if coord is not None and filter_size is not None:
        raise ReconstructionError(
            "filter_size: given both as an option and as a coordinate of bands; give one"
        )
    if coord is None and filter_size is None:
        raise ReconstructionError(
            "bands: a (y, x, wavelength) band cube needs the filter size s_i [px] of every "
            "band (eq. 3): a 'filter_size' coordinate along wavelength or "
            "reconstruct(..., filter_size=s)"
        )
    sizes = np.asarray(coord.values if coord is not None else filter_size, dtype=np.float64)
    if sizes.ndim == 0:
        sizes = np.full(n_band, float(sizes))
    if sizes.shape != (n_band,):
        raise ReconstructionError(
            f"filter_size: expected one number or {n_band} (one per "
            f"wavelength), found shape {sizes.shape}"
        )
    label = rgb["image"].values[0] if "image" in rgb.coords else 0
    return xr.DataArray(
        cube.data,
        dims=("shot", "y", "x"),
        coords={
            "wavelength": ("shot", np.asarray(cube["wavelength"].values, np.float64)),
            "image": ("shot", np.full(n_band, label)),
            "filter_size": ("shot", sizes),
        },
        attrs=cube.attrs,
    )


def _one_form(
    rgb: Any, bands: Any, filter_size: float | Sequence[float] | None
) -> tuple[Any, Any, bool]:
    """``(rgb, bands, single)``: the set form ``(image, y, x, channel)`` / ``(shot, y, x)``;
    ``single`` when ``rgb`` came as one ``(y, x, channel)`` image."""
    single = _is_array(rgb, {"y", "x", "channel"})
    if single:
        if "image" in rgb.coords and rgb["image"].ndim == 0:
            label = rgb["image"].values.item()
        elif (
            isinstance(bands, xr.DataArray)
            and "shot" in bands.dims
            and "image" in bands.coords
            and np.unique(bands["image"].values).size == 1
        ):
            label = np.unique(bands["image"].values)[0].item()
        else:
            label = 0
        rgb = rgb.drop_vars("image", errors="ignore").expand_dims(image=[label])
    if _is_array(bands, {"y", "x", "wavelength"}):
        if isinstance(rgb, xr.DataArray):
            bands = _band_cube_as_shots(bands, rgb, filter_size)
    elif filter_size is not None:
        raise ReconstructionError(
            "filter_size: only for bands given as a (y, x, wavelength) band cube; bands "
            "(shot, y, x) carry their filter sizes as the coordinate 'filter_size'"
        )
    return rgb, bands, single


# -- options -------------------------------------------------------------------------------
def _recorded(options: dict[str, Any]) -> dict[str, Any]:
    """The scalar options as attrs (JSON-safe: bools as 0/1, dtypes by name)."""
    attrs: dict[str, Any] = {}
    for name, value in options.items():
        if name == "dtype" and value is not None:
            attrs[name] = np.dtype(value).name
        elif isinstance(value, bool | np.bool_):
            attrs[name] = int(value)
        elif isinstance(value, numbers.Integral):
            attrs[name] = int(value)
        elif isinstance(value, numbers.Real):
            attrs[name] = float(value)
        elif isinstance(value, str):
            attrs[name] = value
    return attrs


# -- output --------------------------------------------------------------------------------
def _spectra_array(
    cube: np.ndarray, rgb: xr.DataArray, inputs: ReconstructionInputs, attrs: dict
) -> xr.DataArray:
    """``(n_wavelength, n_image, y, x)`` -> DataArray ``(image, wavelength, y, x)``."""
    values = np.ascontiguousarray(np.moveaxis(np.asarray(cube), 0, 1), dtype=np.float32)
    coords = {name: coord for name, coord in rgb.coords.items() if set(coord.dims) <= {"image"}}
    coords["wavelength"] = xr.DataArray(
        inputs.wavelength, dims="wavelength", attrs=SPECTRA.spec("wavelength").attrs
    )
    return xr.DataArray(
        values,
        dims=("image", "wavelength", "y", "x"),
        coords=coords,
        attrs={**SPECTRA.spec("radiance").attrs, **attrs},
    )


def _initial_cube(initial: xr.DataArray | None, inputs: ReconstructionInputs) -> np.ndarray | None:
    if initial is None:
        return None
    wanted = ("image", "wavelength", "y", "x")
    if not isinstance(initial, xr.DataArray) or set(initial.dims) != set(wanted):
        found = dict(initial.sizes) if isinstance(initial, xr.DataArray) else type(initial).__name__
        raise ReconstructionError(f"initial: expected a DataArray with dims {wanted}, found {found}")
    initial = initial.transpose(*wanted)
    expected = (inputs.n_image, inputs.n_wavelength, inputs.height, inputs.width)
    if initial.shape != expected:
        raise ReconstructionError(
            f"initial: expected shape {expected} (image, wavelength, y, x), found {initial.shape}"
        )
    if "wavelength" in initial.coords and not np.allclose(
        initial["wavelength"].values, inputs.wavelength, atol=0.01
    ):
        raise ReconstructionError(
            f"initial: wavelengths {initial['wavelength'].values.tolist()}"
            f" differ from the bands' {inputs.wavelength.tolist()}"
        )
    values = np.asarray(initial.values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise ReconstructionError("initial: expected finite values, found NaN or inf")
    return np.moveaxis(values, 1, 0)


def _set_model_applies(
    set_model: str, inputs: ReconstructionInputs, method: str, *, given: bool = True
) -> bool:
    """Whether ``set_model`` refits the solver's spectra (a set of more than one image);
    raises for a ``set_model`` the caller gave (``"shared-texel"`` or ``"material-pooled"``)
    on a set without the illuminant, before any solve. A preset's own set model
    (``given=False``) does not apply without the illuminant."""
    if set_model == "independent" or inputs.n_image < 2:
        return False  # one image: nothing to share
    if inputs.illuminant is None and not given:
        return False  # the preset's set model needs L: the solver's spectra are kept
    if inputs.illuminant is None:
        raise ReconstructionError(
            f"set_model: {set_model!r} (method {method!r}) needs the illuminant L, the "
            f"spectrum of the set's highlights, on the {inputs.n_wavelength} band wavelengths; "
            "found none: pass reconstruct(..., illuminant=L) (e.g. a calibration's "
            "'illuminant', dims (wavelength,)) or use set_model='independent'"
        )
    return True


def _material_choice_step(
    inputs: ReconstructionInputs, cube: np.ndarray, used: dict[str, Any]
) -> np.ndarray:
    """``set_model="evidence-blend"`` after the pooled refit: the material choice from the
    run's library (``endmembers``) weighed in per texel by the band evidence
    (:func:`~.estimators.evidence_blend.material_choice_blend`). Without a library, or
    without band shots, the pooled refit is kept and recorded as ``"material-pooled"``."""
    endmembers = used.get("endmembers")
    if endmembers is None or len(inputs.band) == 0:
        used["set_model"] = "material-pooled"
        return cube
    return material_choice_blend(inputs, cube, endmembers)


class _Solved(NamedTuple):
    """What one reconstruction gave, before it is dressed as xarray."""

    cube: np.ndarray
    iterations: int
    history: np.ndarray
    converged: bool
    wall_time: float
    setup_time: float
    attrs: dict[str, Any]
    problem: ReconstructionProblem | None


def _solve(
    resolved: ResolvedMethod, used: dict[str, Any], inputs: ReconstructionInputs, started: float
) -> _Solved:
    """Eq. 1 set up (:func:`~.operators.build_problem`) and solved by a solver, then its set
    model; ``used`` (the options the run uses) is updated to what was applied (the set model,
    ``gamma_hat``).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1 and 4.
    """
    refit = _set_model_applies(
        used["set_model"], inputs, resolved.name, given="set_model" in resolved.given
    )  # fail before the solve
    if not refit and inputs.n_image > 1:
        used["set_model"] = "independent"  # a set's spectra kept: recorded as applied
    setup = {name: used[name] for name in SETUP_OPTIONS}
    setup["k"] = int(setup["k"])
    own = {
        name: used[name]
        for name in resolved.options
        if name not in SETUP_OPTIONS and name not in SET_MODEL_OPTIONS
    }
    own["max_iterations"] = int(own["max_iterations"])
    own["initial"] = _initial_cube(own["initial"], inputs)
    problem = build_problem(inputs, **setup, dtype=used.get("dtype", resolved.method.dtype))
    setup_time = time.perf_counter() - started
    solved = resolved.method.function(problem, **own)
    problem.release_pixel_orders()  # the solve's: the set model and the confidence do not hold them
    cube, iterations, history, converged = (
        solved.cube,
        int(solved.iterations),
        solved.residual_history,
        solved.converged,
    )
    set_model_time = 0.0
    if refit and inputs.illuminant is not None:  # the set model: shapes shared by the set
        refit_started = time.perf_counter()
        refine = shared_texel_refine if used["set_model"] == "shared-texel" else material_pooled_refine
        cube = refine(inputs, cube, inputs.illuminant)
        if used["set_model"] == "evidence-blend":
            cube = _material_choice_step(inputs, cube, used)
        set_model_time = time.perf_counter() - refit_started
    wall_time = time.perf_counter() - started
    weights = problem.weights
    if used["gamma_hat"] is None:
        used["gamma_hat"] = default_gamma_hat(inputs.n_image)
    attrs = {
        "method": resolved.name,
        "iterations": iterations,
        "residual_history_length": int(len(history)),
        "final_relative_residual": float(history[-1]),
        "converged": int(converged),
        "wall_time_s": float(wall_time),
        **({"set_model_time_s": float(set_model_time)} if refit else {}),
        "alpha": float(weights.alpha),
        "beta": float(weights.beta),
        "gamma": float(weights.gamma),
        "filter_constraints": int(weights.n_filters),
        **_recorded(used),
    }
    return _Solved(cube, iterations, history, converged, wall_time, setup_time, attrs, problem)


def _confidence(
    solved: _Solved,
    inputs: ReconstructionInputs,
    used: dict[str, Any],
    spectra: xr.DataArray,
    region: tuple[slice, slice] | None = None,
) -> xr.DataArray:
    """The per-pixel confidence (image, y, x) of a result
    (:func:`~.confidence.neighbourhood_spread`), from the solver's own neighbours where they
    are the confidence's (same space and k); inside ``region`` only where given."""
    graph = None
    if solved.problem is not None and used.get("appearance") == "chromaticity-spatial":
        graph = solved.problem.neighbours.neighbours
        graph = graph if graph.shape[1] == CONFIDENCE_NEIGHBOURS else None
    return xr.DataArray(
        neighbourhood_spread(np.asarray(solved.cube), inputs.rgb, neighbours=graph, region=region),
        dims=("image", "y", "x"),
        coords={name: c for name, c in spectra.coords.items() if set(c.dims) <= {"image"}},
        attrs={"units": "1", "long_name": "estimated per-pixel nRMSE (higher: trust less)"},
    )


# -- the entry point -------------------------------------------------------------------------
def reconstruct(
    rgb: xr.DataArray,
    bands: xr.DataArray,
    camera_matrix: xr.DataArray,
    *,
    method: MethodLike | None = None,
    filter_size: float | Sequence[float] | None = None,
    illuminant: xr.DataArray | np.ndarray | None = None,
    full_output: bool = False,
    confidence: bool | tuple[slice, slice] = True,
    **method_options: Any,
) -> xr.DataArray | ReconstructionResult:
    """Reconstruct spectral images from HDR RGB and noisy band shots (eq. 1), or a baseline.

    The solvers minimise ``E(S) = alpha sum_i ||sum_p F_i(p) (S_bi(p) - D_bi(p))||^2 + beta
    sum_p ||C S(p) - R(p)||^2 + gamma sum_p sum_{n in N_p} ||S(p) - S(n)||^2`` over all
    pixels of all images of the set in one linear system, with the weights of eq. 4; the
    baselines map the same inputs to spectra directly, for comparison.

    Parameters
    ----------
    rgb
        ``R``: HDR RGB radiance, dims ``(image, y, x, channel)`` (a set of images) or
        ``(y, x, channel)`` (one image), 3 channels, any dim order.
    bands
        ``D``: calibrated noisy band radiance, either shots ``(shot, y, x)`` with coords along
        ``shot``: ``wavelength`` [nm], ``image`` (which rgb image it pairs with; images may
        have no, some or all bands) and ``filter_size`` ``s_i`` [px] (eq. 3); or, for one
        image, a band cube ``(y, x, wavelength)`` with a ``wavelength`` coordinate, every
        band a shot of that image, and its filter sizes as a coordinate ``filter_size``
        along ``wavelength`` or the ``filter_size`` argument.
    camera_matrix
        ``C``, dims ``(channel, wavelength)``: maps a spectrum to RGB. Its grid must contain
        every band's wavelength (within 0.01 nm); a wider grid is restricted to the bands'
        wavelengths, on which the spectra are reconstructed. Images of several RGB cameras:
        one ``C_m`` per image, dims ``(image, channel, wavelength)`` (matched by the
        ``image`` coordinate), or ``(camera, channel, wavelength)`` picked per image by
        ``rgb``'s ``camera`` coordinate; the RGB term is then ``||C_m S(p) - R(p)||^2``
        (:func:`~.inputs.inputs_from_xarray`).
    method
        A name, a record or a resolved record (:func:`~.methods.resolve_method`; None: the
        default, :data:`~.methods.DEFAULT_METHOD`, ``"natural-prior-pcg"``). The production
        methods of :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`:
        the solvers ``"natural-prior-pcg"``, ``"mixture-prior-pcg"``,
        ``"spectral-prior-pcg"``, ``"guided-prior-pcg"``, ``"block-jacobi-pcg"`` (eq. 1
        alone, the paper's model, fast) and ``"paper-cg"`` (the paper's CG), the estimator
        ``"endmember-mixture"`` (non-iterative); or a comparison baseline of
        :data:`~spectralize.nodes.reconstruction.methods.BASELINE_METHODS`
        (``"pseudo-inverse"``, ``"wiener"``, ``"mallett2019"``, ``"filtered-bands"``,
        ``"filtered-projected"``, ``"guided-projected"``). A resolved record carries its
        options; ``method_options`` given too are laid over them.
    filter_size
        ``s_i`` [px] of the bands of a ``(y, x, wavelength)`` band cube: one number, or one
        per wavelength.
    illuminant
        ``L``, the light's relative spectral radiance (any scale, ``>= 0``): dims
        ``(wavelength,)`` with a ``wavelength`` coordinate [nm] (a calibration's
        ``illuminant``; interpolated onto the bands' wavelengths) or one value per band
        wavelength (:func:`~.inputs.inputs_from_xarray`). Needed by
        ``set_model="shared-texel"``, ``"material-pooled"`` or ``"evidence-blend"`` on a set,
        unused otherwise.
    full_output
        Return a :class:`ReconstructionResult` (spectra, iterations, residual history,
        timings, the problem, the confidence) instead of the spectra alone.
    confidence
        With ``full_output``: compute the per-pixel confidence (False: leave it ``None``;
        it costs a neighbour search and a pass over the spectra). A ``(y, x)`` pair of
        slices: only for the pixels inside them (a tile's core), NaN elsewhere
        (:func:`~.confidence.neighbourhood_spread`, ``region``).
    **method_options
        Options that replace the method's settings
        (``RECONSTRUCTION_METHODS[method].settings``, which hold every one). Every solver
        takes the set-up of eq. 1:

        ``alpha_hat, beta_hat, gamma_hat``
            relative weights of the filter, RGB and neighbour terms (eq. 4);
            ``gamma_hat=None`` is 1 for one image and 20 for a set, as in the paper;
        ``k``
            appearance neighbours per pixel;
        ``centre_spacing``
            ``d``: filter centres are at most this many pixels apart;
        ``normalize_camera_matrix``
            measure the RGB term in band units (divide ``C`` and ``R`` by the mean row sum
            of ``|C|``), so the result does not depend on the gain of ``C``;
        ``appearance``
            the neighbour search's space, ``"rgb"`` (paper) or ``"chromaticity-spatial"``;
        ``scale_invariant``
            couple neighbours as ``S(p) - (b_p / b_n) S(n)`` (``b``: RGB brightness);

        and its own: ``tolerance`` (stop when ``||A^T b - A^T A S|| / ||A^T b||`` is below
        it), ``max_iterations``, ``initial`` (a warm start, dims ``(image, wavelength, y,
        x)``, e.g. spectra transported from a previous image set, paper section 4),
        ``callback(iteration, cube)``, ``set_model`` (``"independent"``, or
        ``"shared-texel"``: on a set of more than one image, refit the solver's spectra
        with per-texel spectral shapes shared by the set's images, a per-image shading and
        a highlight in the illuminant's spectrum,
        :func:`~.estimators.shared_texel.shared_texel_refine` with its defaults; or
        ``"material-pooled"``: one shape per material, the texels clustered by their shapes
        and each material's shape fitted to its texels' pooled band shots,
        :func:`~.estimators.material_pooled.material_pooled_refine` with its defaults;
        or ``"evidence-blend"``: ``"material-pooled"``, then, given the run's library
        (``endmembers``), each texel's materials chosen over the set from it and the
        spectra moved towards the choice's by the posterior of its band shots,
        :func:`~.estimators.evidence_blend.material_choice_blend`; the last three
        need ``illuminant``; a single image is left as solved; the default preset's is
        ``"evidence-blend"``, every other preset's ``"independent"``; a preset's own set
        model without ``illuminant`` keeps the solver's spectra, a given one raises); the
        PCG solvers also ``dtype``,
        ``ridge``, ``prior`` (the guided prior's weight) and ``precondition``, the prior
        PCG the spectral prior's settings (:func:`~.solvers.prior_pcg.prior_pcg`).
        Baselines: ``"wiener"`` takes ``relative_noise``, ``"guided-projected"``
        ``window_scale`` and ``epsilon``.

    Returns
    -------
    xarray.DataArray or ReconstructionResult
        ``S``, dims ``(image, wavelength, y, x)`` (``(wavelength, y, x)`` when ``rgb`` is one
        ``(y, x, channel)`` image), float32, ``units="1"``; the per-image coords of ``rgb``;
        attrs record the method and its options, and for a solver the iterations, residual
        history length, final residual, eq. 4 weights and wall time.

    Raises
    ------
    ReconstructionError
        (a ``ValueError``) for inputs that do not fit together (dims, shapes, wavelengths,
        NaN/inf, filter sizes larger than the image, an empty set), unknown methods, and
        unknown or invalid options (the message lists the method's options).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1-4.

    Examples
    --------
    One image of two materials, its RGB through a camera of three broad channels and a
    noisy shot of every band (a band cube, all filtered with ``s_i = 3`` px):

    >>> import numpy as np
    >>> import xarray as xr
    >>> wavelength = np.array([450.0, 500.0, 550.0, 600.0])
    >>> peaks = np.array([[600.0], [540.0], [460.0]])
    >>> camera_matrix = xr.DataArray(
    ...     np.exp(-0.5 * ((wavelength - peaks) / 40.0) ** 2),
    ...     dims=("channel", "wavelength"),
    ...     coords={"channel": ["R", "G", "B"], "wavelength": wavelength},
    ... )
    >>> materials = np.array([[0.2, 0.4, 0.6, 0.8], [0.7, 0.5, 0.4, 0.3]])
    >>> truth = materials[np.repeat([[0] * 8 + [1] * 8], 16, axis=0)]  # (y, x, wavelength)
    >>> rgb = xr.DataArray(
    ...     truth @ camera_matrix.values.T,
    ...     dims=("y", "x", "channel"),
    ...     coords={"channel": ["R", "G", "B"]},
    ... )
    >>> noise = np.random.default_rng(0).normal(0.0, 0.01, truth.shape)
    >>> band_cube = xr.DataArray(
    ...     truth + noise, dims=("y", "x", "wavelength"), coords={"wavelength": wavelength}
    ... )

    The default method, then another preset with an option of its own, then a baseline:

    >>> spectra = reconstruct(rgb, band_cube, camera_matrix, filter_size=3.0)
    >>> spectra.dims, spectra.dtype, spectra.attrs["method"]
    (('wavelength', 'y', 'x'), dtype('float32'), 'natural-prior-pcg')
    >>> error = np.abs(spectra.transpose("y", "x", "wavelength").values - truth)
    >>> bool(error.mean() < 0.05)
    True
    >>> result = reconstruct(
    ...     rgb, band_cube, camera_matrix, filter_size=3.0,
    ...     method="block-jacobi-pcg", k=4, full_output=True,
    ... )
    >>> result.method, result.spectra.attrs["k"], result.iterations > 0
    ('block-jacobi-pcg', 4, True)
    >>> reconstruct(rgb, band_cube, camera_matrix, filter_size=3.0, method="wiener").attrs["method"]
    'wiener'

    A method resolved once with its options (:func:`~.methods.resolve_method`, also
    ``spectralize.nodes.reconstruction.resolve_method``) is passed on as it is:

    >>> paper = resolve_method("paper-cg", max_iterations=5)
    >>> reconstruct(rgb, band_cube, camera_matrix, filter_size=3.0, method=paper).attrs["iterations"]
    5
    """
    started = time.perf_counter()
    settings = {name: value for name, value in method_options.items() if name not in RUN_INPUTS}
    resolved = resolve_method(method, **settings)
    run = resolved.run_inputs(**{n: v for n, v in method_options.items() if n in RUN_INPUTS})
    used = {**resolved.used(), **run}
    rgb, bands, single = _one_form(rgb, bands, filter_size)
    inputs = inputs_from_xarray(rgb, bands, camera_matrix, illuminant)
    rgb = rgb.transpose("image", "y", "x", "channel")
    if resolved.kind == "solver":
        solved = _solve(resolved, used, inputs, started)
    else:
        cube = resolved.method.function(inputs, **used)
        wall_time = time.perf_counter() - started
        attrs = {"method": resolved.name, "wall_time_s": float(wall_time), **_recorded(used)}
        solved = _Solved(cube, 0, np.zeros(0), True, wall_time, wall_time, attrs, None)
    spectra = _spectra_array(solved.cube, rgb, inputs, solved.attrs)
    if single:
        spectra = spectra.isel(image=0)
    if not full_output:
        return spectra
    spread = None
    if confidence:
        region = confidence if isinstance(confidence, tuple) else None
        spread = _confidence(solved, inputs, used, spectra, region)
        if single:
            spread = spread.isel(image=0)
    return ReconstructionResult(
        spectra,
        solved.iterations,
        np.asarray(solved.history),
        bool(solved.converged),
        solved.wall_time,
        solved.setup_time,
        resolved.name,
        solved.problem,
        spread,
    )
