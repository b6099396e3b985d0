"""The public, xarray-level reconstruction API (a thin layer over the numpy numerics).

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 3 and 5.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import xarray as xr

from spectralize.schemas.errors import ReconstructionError

from .baselines import BASELINE_METHODS
from .inputs import ReconstructionInputs, inputs_from_xarray
from .operators import ReconstructionProblem, build_problem
from .solvers import (
    DEFAULT_MAX_ITERATIONS,
    DEFAULT_METHOD,
    DEFAULT_TOLERANCE,
    SOLVER_DTYPES,
    SOLVER_METHODS,
    SolverResult,
)

__all__ = ["reconstruct", "reconstruct_spectra", "reconstruct_baseline", "ReconstructionResult"]


@dataclass
class ReconstructionResult:
    """Spectra and solver record of one reconstruction.

    Attributes
    ----------
    spectra
        ``(image, wavelength, y, x)`` float32 DataArray (what :func:`reconstruct` returns).
    iterations
        Solver iterations.
    residual_history
        Relative normal-equation residual before and after every iteration.
    converged
        Whether the tolerance was reached.
    wall_time
        Seconds for the whole call (checks, neighbour search, set-up and solve).
    setup_time
        Seconds of that for checks, neighbour search and operator set-up.
    method
        Solver name.
    problem
        The :class:`ReconstructionProblem` solved (operators, weights, neighbour graph).
    """

    spectra: xr.DataArray
    iterations: int
    residual_history: np.ndarray
    converged: bool
    wall_time: float
    setup_time: float
    method: str
    problem: ReconstructionProblem = field(repr=False)


def _method_error(method: str, table: dict) -> ReconstructionError:
    return ReconstructionError(f"unknown method {method!r}; known methods: "
                               f"{', '.join(sorted(table))}")


def _spectra_array(cube: np.ndarray, rgb: xr.DataArray, inputs: ReconstructionInputs,
                   attrs: dict) -> xr.DataArray:
    """``(n_wavelength, n_image, y, x)`` -> DataArray ``(image, wavelength, y, x)``."""
    values = np.ascontiguousarray(np.moveaxis(np.asarray(cube), 0, 1), dtype=np.float32)
    coords = {name: coord for name, coord in rgb.coords.items()
              if set(coord.dims) <= {"image"}}
    coords["wavelength"] = xr.DataArray(inputs.wavelength, dims="wavelength",
                                        attrs={"units": "nm", "long_name": "wavelength"})
    return xr.DataArray(values, dims=("image", "wavelength", "y", "x"), coords=coords,
                        attrs={"units": "1", "long_name": "relative spectral radiance",
                               **attrs})


def _initial_cube(initial: xr.DataArray | None, rgb: xr.DataArray,
                  inputs: ReconstructionInputs) -> np.ndarray | None:
    if initial is None:
        return None
    wanted = ("image", "wavelength", "y", "x")
    if not isinstance(initial, xr.DataArray) or set(initial.dims) != set(wanted):
        found = (dict(initial.sizes) if isinstance(initial, xr.DataArray)
                 else type(initial).__name__)
        raise ReconstructionError(f"initial: expected a DataArray with dims {wanted}, "
                                  f"found {found}")
    initial = initial.transpose(*wanted)
    expected = (inputs.n_image, inputs.n_wavelength, inputs.height, inputs.width)
    if initial.shape != expected:
        raise ReconstructionError(f"initial: expected shape {expected} (image, wavelength, y, "
                                  f"x), found {initial.shape}")
    if "wavelength" in initial.coords and not np.allclose(initial["wavelength"].values,
                                                          inputs.wavelength, atol=0.01):
        raise ReconstructionError(f"initial: wavelengths {initial['wavelength'].values.tolist()}"
                                  f" differ from camera_matrix's {inputs.wavelength.tolist()}")
    values = np.asarray(initial.values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise ReconstructionError("initial: expected finite values, found NaN or inf")
    return np.moveaxis(values, 1, 0)


def reconstruct_spectra(rgb: xr.DataArray, bands: xr.DataArray, camera_matrix: xr.DataArray,
                        *, method: str = DEFAULT_METHOD, alpha_hat: float = 1.0,
                        beta_hat: float = 1.0, gamma_hat: float | None = None, k: int = 3,
                        centre_spacing: float = 2.5, tolerance: float = DEFAULT_TOLERANCE,
                        max_iterations: int = DEFAULT_MAX_ITERATIONS,
                        initial: xr.DataArray | None = None,
                        normalize_camera_matrix: bool = True,
                        callback=None) -> ReconstructionResult:
    """Reconstruct spectral images (eq. 1) and return them with the solver's record.

    Same parameters as :func:`reconstruct`, plus ``callback(iteration, cube)`` called after
    every solver iteration with the current cube ``(wavelength, image, y, x)``.

    Returns
    -------
    ReconstructionResult
    """
    started = time.perf_counter()
    if method not in SOLVER_METHODS:
        raise _method_error(method, SOLVER_METHODS)
    for name, value in {"alpha_hat": alpha_hat, "beta_hat": beta_hat,
                        "centre_spacing": centre_spacing, "tolerance": tolerance}.items():
        if not (np.isfinite(value) and value > 0):
            raise ReconstructionError(f"{name}: expected a finite number > 0, found {value!r}")
    if gamma_hat is not None and not (np.isfinite(gamma_hat) and gamma_hat >= 0):
        raise ReconstructionError(f"gamma_hat: expected a finite number >= 0, found "
                                  f"{gamma_hat!r}")
    if int(k) != k or k < 1:
        raise ReconstructionError(f"k: expected an integer >= 1, found {k!r}")
    if int(max_iterations) != max_iterations or max_iterations < 0:
        raise ReconstructionError(f"max_iterations: expected an integer >= 0, found "
                                  f"{max_iterations!r}")
    inputs = inputs_from_xarray(rgb, bands, camera_matrix)
    start_cube = _initial_cube(initial, rgb, inputs)
    problem = build_problem(inputs, alpha_hat=alpha_hat, beta_hat=beta_hat,
                            gamma_hat=gamma_hat, k=int(k), centre_spacing=centre_spacing,
                            normalize_camera_matrix=normalize_camera_matrix,
                            dtype=SOLVER_DTYPES.get(method, np.float64))
    setup_time = time.perf_counter() - started
    solved: SolverResult = SOLVER_METHODS[method](
        problem, initial=start_cube, tolerance=tolerance, max_iterations=int(max_iterations),
        callback=callback)
    wall_time = time.perf_counter() - started
    w = problem.weights
    attrs = {
        "method": method,
        "iterations": int(solved.iterations),
        "residual_history_length": int(len(solved.residual_history)),
        "final_relative_residual": float(solved.residual_history[-1]),
        "converged": int(solved.converged),
        "tolerance": float(tolerance),
        "wall_time_s": float(wall_time),
        "alpha": float(w.alpha), "beta": float(w.beta), "gamma": float(w.gamma),
        "alpha_hat": float(alpha_hat), "beta_hat": float(beta_hat),
        "gamma_hat": float(gamma_hat if gamma_hat is not None
                           else (1.0 if inputs.n_image == 1 else 20.0)),
        "k": int(k), "centre_spacing": float(centre_spacing),
        "filter_constraints": int(w.n_filters),
    }
    spectra = _spectra_array(solved.cube, rgb.transpose("image", "y", "x", "channel"),
                             inputs, attrs)
    return ReconstructionResult(spectra, solved.iterations, solved.residual_history,
                                solved.converged, wall_time, setup_time, method, problem)


def reconstruct(rgb: xr.DataArray, bands: xr.DataArray, camera_matrix: xr.DataArray, *,
                method: str = DEFAULT_METHOD, alpha_hat: float = 1.0, beta_hat: float = 1.0,
                gamma_hat: float | None = None, k: int = 3, centre_spacing: float = 2.5,
                tolerance: float = DEFAULT_TOLERANCE,
                max_iterations: int = DEFAULT_MAX_ITERATIONS,
                initial: xr.DataArray | None = None,
                normalize_camera_matrix: bool = True) -> xr.DataArray:
    """Reconstruct spectral images from HDR RGB and noisy band shots (eq. 1).

    Minimises ``E(S) = alpha sum_i ||sum_p F_i(p) (S_bi(p) - D_bi(p))||^2 + beta sum_p
    ||C S(p) - R(p)||^2 + gamma sum_p sum_{n in N_p} ||S(p) - S(n)||^2`` over all pixels of
    all images of the set in one linear system, with the weights of eq. 4.

    Parameters
    ----------
    rgb
        ``R``: HDR RGB radiance, dims ``(image, y, x, channel)``, 3 channels.
    bands
        ``D``: calibrated noisy band radiance, dims ``(shot, y, x)``, with coords along
        ``shot``: ``wavelength`` [nm], ``image`` (which rgb image it pairs with; images may
        have no, some or all bands) and ``filter_size`` ``s_i`` [px] (eq. 3).
    camera_matrix
        ``C``, dims ``(channel, wavelength)``: maps a spectrum to RGB. Its wavelengths must be
        exactly the bands' wavelengths; the spectra are reconstructed on them.
    method
        A solver of :data:`~spectralize.nodes.reconstruction.solvers.SOLVER_METHODS`:
        ``"block-jacobi-pcg"`` (default: eq. 1, fast), ``"guided-prior-pcg"`` (eq. 1 plus a
        prior towards the RGB-guided filtered bands) or ``"paper-cg"`` (the paper's CG).
    alpha_hat, beta_hat, gamma_hat
        Relative weights of the filter, RGB and neighbour terms (eq. 4); ``gamma_hat=None``
        is 1 for one image and 20 for a set of images, as in the paper.
    k
        Appearance neighbours per pixel in RGB space (paper: 3).
    centre_spacing
        ``d``: filter centres are at most this many pixels apart (paper: 2.5).
    tolerance
        Stop when ``||A^T b - A^T A S|| / ||A^T b||`` is below this.
    max_iterations
        Iteration limit of the solver.
    initial
        Optional warm start, dims ``(image, wavelength, y, x)`` (e.g. spectra transported
        from a previous image set, paper section 4).
    normalize_camera_matrix
        Measure the RGB term in band units (divide ``C`` and ``R`` by the mean row sum of
        ``|C|``), so the result does not depend on the gain of ``C``.

    Returns
    -------
    xarray.DataArray
        ``S``, dims ``(image, wavelength, y, x)``, float32, ``units="1"``; the per-image
        coords of ``rgb``; attrs record the method, iterations, residual history length,
        final residual, weights and wall time.

    Raises
    ------
    ReconstructionError
        (a ``ValueError``) for inputs that do not fit together: dims, shapes, wavelengths,
        NaN/inf, filter sizes larger than the image, an empty set, unknown methods.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1-4.

    Examples
    --------
    >>> spectra = reconstruct(hdr.radiance, bands.radiance, camera_matrix)  # doctest: +SKIP
    """
    return reconstruct_spectra(
        rgb, bands, camera_matrix, method=method, alpha_hat=alpha_hat, beta_hat=beta_hat,
        gamma_hat=gamma_hat, k=k, centre_spacing=centre_spacing, tolerance=tolerance,
        max_iterations=max_iterations, initial=initial,
        normalize_camera_matrix=normalize_camera_matrix).spectra


def reconstruct_baseline(rgb: xr.DataArray, bands: xr.DataArray, camera_matrix: xr.DataArray,
                         *, method: str = "filtered-projected") -> xr.DataArray:
    """Reconstruct spectra with a baseline method, for comparison with :func:`reconstruct`.

    Parameters
    ----------
    rgb, bands, camera_matrix
        As for :func:`reconstruct`.
    method
        A name in :data:`~spectralize.nodes.reconstruction.baselines.BASELINE_METHODS`:
        ``"pseudo-inverse"``, ``"wiener"``, ``"mallett2019"``, ``"filtered-bands"``,
        ``"filtered-projected"``.

    Returns
    -------
    xarray.DataArray
        Dims ``(image, wavelength, y, x)``, float32, attrs ``method`` and ``wall_time_s``.
    """
    started = time.perf_counter()
    if method not in BASELINE_METHODS:
        raise _method_error(method, BASELINE_METHODS)
    inputs = inputs_from_xarray(rgb, bands, camera_matrix)
    cube = BASELINE_METHODS[method](inputs)
    return _spectra_array(cube, rgb.transpose("image", "y", "x", "channel"), inputs,
                          {"method": method, "wall_time_s": time.perf_counter() - started})
