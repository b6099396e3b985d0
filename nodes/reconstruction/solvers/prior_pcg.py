"""Solver ``"spectral-prior-pcg"``: ``material-prior-pcg`` plus a soft Gaussian spectral
prior (Wiener-like, per pixel).

Adds to the energy of :mod:`.material_prior_pcg` a per-pixel Gaussian prior

``sum_p w_p (S_p - m_p)^T Q (S_p - m_p)``

* ``Q = (Sigma / mean(diag Sigma) + delta I)^-1`` with ``Sigma`` the covariance of sample
  spectra, each normalised by its level: cheap along the samples' typical spectral
  variations, expensive along shapes none of them has;
* ``m_p = K C^T (C K C^T + s I)^-1 R_p``: the Wiener estimate from the pixel's RGB with the
  samples' second moment ``K`` (as baseline ``"wiener"``), linear in ``R`` so it scales
  with the pixel;
* ``w_p = spectral_prior * mean(diag A^T A) / max(b_p, b_min)^2`` with ``b_p`` the pixel's
  RGB brightness relative to its image's mean: the prior is one on the spectrum's *shape*,
  its covariance scales with the square of the spectrum's scale.

The samples (``prior_source``): ``"scene"`` (default), the pixels of the RGB-guided
filtered bands ``S_0`` of every image that has a shot of every band (the scene's own
materials under its own illuminant; none for a sparse set, which then gets no spectral
prior and is solved as ``material-prior-pcg``); ``"training"``, colour-science's 190
RAW-to-ACES reflectances lit by the illuminant estimated from the bands (measured: worse
on every set and on the woven-fabric image, see the README).

A soft term, not a hard subspace: the band shots and the neighbour term move a spectrum off
the samples' span where they say so. ``Q`` couples the wavelengths of a pixel; the
block-Jacobi preconditioner takes its diagonal. Then the same projected-gradient
refinement on ``S >= 0`` as :mod:`.material_prior_pcg`, on the whole energy.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 ("Hybrid Methods") and 3.
.. [2] Hardeberg, J. Y., Schmitt, F., Brettel, H. (1999). Multispectral image capture
   using a tunable filter (Wiener estimation).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from spectralize.schemas import ReconstructionError

from ..baselines.training import estimate_illuminant, training_reflectances
from ..baselines.wiener import WIENER_RELATIVE_NOISE
from ..estimators import endmember_mixture
from ..estimators.endmember_mixture import Endmembers
from ..operators import ReconstructionProblem
from .block_jacobi_pcg import (
    DEFAULT_RIDGE,
    BlockJacobiPreconditioner,
    _prior_mask,
    guided_initial,
    normal_mean_diagonal,
)
from .common import (
    COMPILED,
    DEFAULT_MAX_ITERATIONS,
    DEFAULT_TOLERANCE,
    Callback,
    SolverResult,
    needs_cube,
    preconditioned_cg,
    vdot,
)
from .guided_prior_pcg import DEFAULT_PRIOR
from .material_prior_pcg import DEFAULT_PROJECTED_ITERATIONS
from .material_prior_pcg import SETUP_DEFAULTS as MATERIAL_SETUP_DEFAULTS

__all__ = [
    "spectral_prior_pcg",
    "SpectralPrior",
    "spectral_prior_term",
    "SETUP_DEFAULTS",
    "DEFAULT_SPECTRAL_PRIOR",
    "DEFAULT_COVARIANCE_FLOOR",
    "DEFAULT_PRIOR_SOURCE",
    "MIN_BRIGHTNESS",
    "MAX_BRIGHTNESS",
    "PRIOR_WEIGHTINGS",
    "prior_brightness",
]

SETUP_DEFAULTS = dict(MATERIAL_SETUP_DEFAULTS)
"""Set-up options: those of ``material-prior-pcg``."""

DEFAULT_SPECTRAL_PRIOR = 0.003
"""Weight of the spectral prior, relative to the mean diagonal of ``A^T A``. Chosen by a
sweep over all four hard scenes (README, "Reconstruction on the hard scenes"): 0.003 and
0.01 lower the single-image medians of ``material-prior-pcg`` on 3-4 of 4 scenes by up to
0.009; 0.003 keeps p95 within 3 %."""

DEFAULT_PRIOR_SOURCE = "scene"
"""Where the prior is learnt by default (:func:`spectral_prior_term`): the scene's own
guided estimate. Learnt from the training reflectances it made every set and the
woven-fabric image worse (the estimated illuminant and the collection are biased there)."""

DEFAULT_COVARIANCE_FLOOR = 1e-2
"""``delta``: floor added to the normalised covariance before inverting it."""

MIN_BRIGHTNESS = 0.1
"""``b_min``: pixels darker than this fraction of their image's mean are weighted as this."""

MAX_BRIGHTNESS = 10.0
"""``b_max``: with ``prior_weighting="brightness"``, pixels brighter than this multiple of
their image's mean weigh the guided prior as this (a highlight does not pin its pixel
harder than a bright material)."""

PRIOR_WEIGHTINGS = ("uniform", "brightness")
"""How the guided prior's weight ``epsilon_p`` is spread over the pixels (see
:func:`spectral_prior_pcg`)."""

_CHUNK = 1 << 15
"""Pixels per chunk of the spectral prior's ``w_p Q S_p`` (bounds its temporary)."""


@dataclass(frozen=True)
class SpectralPrior:
    """The quadratic term ``sum_p w_p (S_p - m_p)^T Q (S_p - m_p)`` on a cube ``(w, m, y, x)``.

    Attributes
    ----------
    precision
        ``Q``, ``(n_wavelength, n_wavelength)``, symmetric positive definite.
    weight
        ``w_p``, ``(n_image, height, width)`` (absolute).
    centre
        ``m``, the cube ``(n_wavelength, n_image, height, width)``.
    """

    precision: np.ndarray
    weight: np.ndarray
    centre: np.ndarray

    def apply(self, cube: np.ndarray) -> np.ndarray:
        """``w ⊙ Q cube`` (the term's Hessian / 2 applied), same shape as ``cube``."""
        n = cube.shape[0]
        out = self.precision @ cube.reshape(n, -1)
        out *= self.weight.reshape(1, -1)
        return out.reshape(cube.shape)

    def rhs(self) -> np.ndarray:
        """``w ⊙ Q m``."""
        return self.apply(self.centre)

    def energy(self, cube: np.ndarray) -> float:
        d = cube - self.centre
        return vdot(d, self.apply(d))

    def diagonal(self) -> np.ndarray:
        """Diagonal of the term's Hessian / 2, cube-shaped."""
        return np.diag(self.precision)[:, None, None, None] * self.weight[None]

    def astype(self, dtype: np.dtype | type) -> SpectralPrior:
        return SpectralPrior(
            self.precision.astype(dtype), self.weight.astype(dtype), self.centre.astype(dtype)
        )


def _level_normalised(spectra: np.ndarray) -> np.ndarray:
    """Sample spectra ``(n_wavelength, n)``, clipped at 0, each divided by its mean; those
    darker than a quarter of the median left out; at most about 20000, strided."""
    step = max(1, spectra.shape[1] // 20000)
    spectra = np.maximum(spectra[:, ::step], 0)  # the sample first: no cube-sized copies
    level = spectra.mean(axis=0)
    keep = level > 0.25 * max(float(np.median(level)), 1e-300)
    return spectra[:, keep] / level[keep]


def _scene_spectra(problem: ReconstructionProblem) -> np.ndarray | None:
    """Pixel spectra of the guided estimate ``S_0`` on the images that have a shot of every
    band, each divided by its mean: ``(n_wavelength, n_samples)``; None if no image has."""
    full = _prior_mask(problem)[:, :, 0, 0].all(axis=0)
    if not full.any():
        return None
    centre = np.asarray(guided_initial(problem), dtype=np.float64).reshape(problem.shape)
    return _level_normalised(centre[:, full].reshape(problem.shape[0], -1))


def spectral_prior_term(
    problem: ReconstructionProblem,
    weight: float,
    mean_diagonal: float,
    *,
    covariance_floor: float = DEFAULT_COVARIANCE_FLOOR,
    source: str = DEFAULT_PRIOR_SOURCE,
    endmembers: Endmembers | None = None,
) -> SpectralPrior | None:
    """The spectral prior of a problem built with its inputs (see the module docstring).

    ``weight`` is relative to ``mean_diagonal`` (the mean diagonal of ``A^T A``).
    ``source``: ``"training"`` learns the mean and covariance from colour-science's
    training reflectances lit by the estimated illuminant; ``"scene"`` from the scene's own
    guided estimate ``S_0`` (pixels of the images with every band, normalised by their
    level; no illuminant estimate needed); None (no prior) without such an image (a sparse
    set, where its covariance cannot be learnt). ``"mixture"``: the covariance of the
    :func:`~..estimators.endmember_mixture` estimate of every pixel (level-normalised), and
    that estimate itself as the centre ``m`` instead of the Wiener estimate (any set has
    one); ``endmembers``: its dictionary, learnt before (e.g. once per set for all its
    tiles), with ``"mixture"`` only.
    """
    inputs = problem.extras.get("inputs")
    if inputs is None:
        raise ValueError("the spectral prior needs a problem built from inputs")
    mixture = None
    if endmembers is not None and source != "mixture":
        raise ReconstructionError(
            f"endmembers: only the 'mixture' prior source takes a dictionary, found source {source!r}"
        )
    if source == "scene":
        samples = _scene_spectra(problem)
        if samples is None:
            return None
    elif source == "mixture":
        mixture = endmember_mixture(inputs, endmembers=endmembers).reshape(problem.shape)
        samples = _level_normalised(mixture.reshape(problem.shape[0], -1))
    elif source == "training":
        reflectances = training_reflectances(inputs.wavelength)
        samples = estimate_illuminant(inputs, reflectances)[:, None] * reflectances
    else:
        raise ValueError(f"unknown prior source {source!r}; use 'scene', 'mixture' or 'training'")
    n = samples.shape[0]
    covariance = np.cov(samples)
    covariance = covariance / max(float(np.mean(np.diag(covariance))), 1e-300)
    precision = np.linalg.inv(covariance + covariance_floor * np.eye(n))
    precision = 0.5 * (precision + precision.T)
    rgb = np.asarray(inputs.rgb, dtype=np.float64)  # (image, y, x, channel)
    brightness = np.abs(rgb.sum(axis=-1))
    brightness = brightness / np.maximum(brightness.mean(axis=(1, 2), keepdims=True), 1e-300)
    w = weight * mean_diagonal / np.maximum(brightness, MIN_BRIGHTNESS) ** 2
    if mixture is not None:
        return SpectralPrior(precision, w, mixture)
    # Wiener estimate from RGB with the samples' second moment
    second_moment = samples @ samples.T / samples.shape[1]
    c = inputs.camera_matrix
    projected = c @ second_moment @ c.T
    noise = WIENER_RELATIVE_NOISE * np.trace(projected) / 3
    operator = second_moment @ c.T @ np.linalg.inv(projected + noise * np.eye(3))
    centre = (operator @ inputs.rgb_pixels()).reshape(problem.shape)
    return SpectralPrior(precision, w, centre)


def prior_brightness(rgb: np.ndarray) -> np.ndarray:
    """Per pixel ``f_p = clip(b_p, b_min, b_max) / mean(...)``, ``(n_image, height, width)``:
    the RGB brightness relative to its image's mean, clipped to
    [:data:`MIN_BRIGHTNESS`, :data:`MAX_BRIGHTNESS`] and normalised to mean 1 over all
    pixels (so ``prior`` keeps its meaning as the mean weight)."""
    brightness = np.abs(np.asarray(rgb, dtype=np.float64).sum(axis=-1))
    brightness /= np.maximum(brightness.mean(axis=(1, 2), keepdims=True), 1e-300)
    np.clip(brightness, MIN_BRIGHTNESS, MAX_BRIGHTNESS, out=brightness)
    return brightness / max(float(brightness.mean()), 1e-300)


def _projected_refinement(
    operator, rhs: np.ndarray, scale: np.ndarray, x: np.ndarray, iterations: int
) -> np.ndarray:
    """Minimise ``x^T H x / 2 - rhs^T x`` over ``x >= 0`` by Jacobi-scaled projected
    gradient with Barzilai-Borwein steps (as :mod:`.material_prior_pcg`).

    Three buffers besides ``x`` (the gradient, the step and its gradient), allocated once
    and passed to ``operator(cube, out=...)`` as its output;
    the step and the Barzilai-Borwein dot products are compiled passes
    (:func:`~..kernels.projected_step`, :func:`~..kernels.step_dots`) that never form the
    differences (measured on a 20-image tile of 308^2 px, 10 iterations: 11.1 -> 9.1 s,
    and two cube-sized buffers fewer than with numpy); ``x`` is overwritten.
    """
    from ..kernels import projected_step, step_dots

    np.maximum(x, 0, out=x)
    g, new, new_g = np.empty_like(x), np.empty_like(x), np.empty_like(x)
    g = np.subtract(operator(x, out=g), rhs, out=g)
    step = 1.0
    for _ in range(iterations):
        projected_step(x, g, scale, step, new)
        np.subtract(operator(new, out=new_g), rhs, out=new_g)
        sy, ss = step_dots(new, x, new_g, g, scale)
        step = float(ss / sy) if sy > 0 else step
        step = min(max(step, 1e-3), 10.0)
        x, new = new, x
        g, new_g = new_g, g
    return x


def spectral_prior_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = DEFAULT_RIDGE,
    prior: float = DEFAULT_PRIOR,
    spectral_prior: float = DEFAULT_SPECTRAL_PRIOR,
    covariance_floor: float = DEFAULT_COVARIANCE_FLOOR,
    prior_source: str = DEFAULT_PRIOR_SOURCE,
    precondition: bool | str = True,
    projected_iterations: int = DEFAULT_PROJECTED_ITERATIONS,
    endmembers: Endmembers | None = None,
    prior_weighting: str = "uniform",
) -> SolverResult:
    """Eq. 1 (set up as ``material-prior-pcg``) + guided prior + spectral prior, then S >= 0.

    Minimises eq. 1 ``+ epsilon_r ||S - S_start||^2 + epsilon_p sum_p f_p M ||S_p -
    S_0,p||^2 + sum_p w_p (S_p - m_p)^T Q (S_p - m_p)`` by block-Jacobi PCG (the priors'
    diagonals in the preconditioner), then refines on ``S >= 0``; ``f_p`` is 1
    (``prior_weighting="uniform"``) or the pixel's relative brightness
    (:func:`prior_brightness`, ``"brightness"``).

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`
        with its inputs.
    initial, tolerance, max_iterations, callback, dtype, ridge, prior, precondition
        As for :func:`~.material_prior_pcg.material_prior_pcg`.
    spectral_prior
        Weight of the spectral prior relative to the mean diagonal of ``A^T A`` (0: the
        energy of ``material-prior-pcg``).
    covariance_floor
        ``delta`` of ``Q`` (see the module docstring).
    prior_source
        ``"scene"``, ``"mixture"`` or ``"training"``: where the prior's mean and covariance
        are learnt (:func:`spectral_prior_term`). With ``"mixture"`` the guided prior
        (``prior``) and the start are centred on the mixture estimate too.
    projected_iterations
        Projected-gradient iterations on ``S >= 0`` (0: none).
    endmembers
        With ``prior_source="mixture"``: the mixture's dictionary, learnt before
        (:func:`~..estimators.endmember_mixture.set_endmembers`); None: learnt from the
        problem's inputs.
    prior_weighting
        One of :data:`PRIOR_WEIGHTINGS`: ``"brightness"`` weighs the guided prior of each
        pixel by its relative brightness ``f_p`` (mean 1), so that it pins the bright
        pixels, whose estimate ``S_0`` is accurate relative to their level, harder than
        the dark ones, where eq. 1's neighbour term averages out more band noise than it
        adds errors.

    Returns
    -------
    SolverResult
        ``method="spectral-prior-pcg"``; iterations count both stages.

    Raises
    ------
    ValueError
        For an unknown ``prior_weighting``.
    """
    started = time.perf_counter()
    if prior_weighting not in PRIOR_WEIGHTINGS:
        raise ValueError(
            f"prior_weighting: expected one of {PRIOR_WEIGHTINGS}, found {prior_weighting!r}"
        )
    dtype = np.dtype(dtype)
    work = problem.astype(dtype)
    guided = prior * _prior_mask(problem)  # epsilon_p M / mean(diag A^T A), (w, m, 1, 1)
    brightness = None
    if prior_weighting == "brightness" and prior > 0:
        inputs = problem.extras.get("inputs")
        if inputs is None:
            raise ValueError("prior_weighting='brightness' needs a problem built from inputs")
        brightness = prior_brightness(inputs.rgb).astype(dtype)
        guided = guided.astype(dtype) * brightness[None]  # per pixel: one float32 cube
    relative: float | np.ndarray = ridge + guided
    mean_diagonal = normal_mean_diagonal(work)
    term = None
    if spectral_prior > 0:
        term = spectral_prior_term(
            problem,
            spectral_prior,
            mean_diagonal,
            covariance_floor=covariance_floor,
            source=prior_source,
            endmembers=endmembers,
        )
    if term is not None:  # the prior's diagonal joins the ridges, one float32 cube
        term = term.astype(dtype)
        diagonal = term.diagonal()
        diagonal *= dtype.type(1.0 / mean_diagonal)
        diagonal += np.asarray(relative, dtype=dtype)
        relative = diagonal
        del diagonal
    if term is not None and prior_source == "mixture":
        centre = term.centre  # the guided prior pulls towards the same estimate (read only)
    else:
        centre = np.asarray(guided_initial(problem), dtype=dtype).reshape(work.shape)
    # pixel-major vectors in appearance order and compiled passes, as block-jacobi-pcg
    order = work.pixel_order("appearance")
    preconditioner = BlockJacobiPreconditioner(work, dtype, ridge=relative, order=order)
    del relative
    # the ridges alone (without the spectral prior's diagonal), absolute
    towards = dtype.type(ridge * mean_diagonal)
    start = centre if initial is None else np.asarray(initial, dtype=dtype).reshape(work.shape)
    rhs = work.normal_rhs() + towards * start
    mask = _prior_mask(problem)  # (w, m, 1, 1)
    pixel_prior = None
    if brightness is None:  # uniform per (band, image): a ridge of the compiled operator
        epsilon = ((ridge + prior * mask) * mean_diagonal).astype(dtype)
        rhs += (guided * mean_diagonal).astype(dtype) * centre  # + epsilon_p M S_0
    else:  # per pixel: epsilon_p f_p M, applied chunk by chunk beside ``w_p Q``
        epsilon = np.asarray(ridge * mean_diagonal, dtype=dtype)
        guided *= dtype.type(mean_diagonal)  # + epsilon_p f_p M S_0, in the weights' cube
        guided *= centre
        rhs += guided
        pixel_image = order.order // (problem.shape[2] * problem.shape[3])
        pixel_prior = (
            brightness.reshape(-1)[order.order],
            (mask[:, :, 0, 0].T * (prior * mean_diagonal)).astype(dtype),  # (m, w)
            pixel_image,
        )
        del brightness
    del guided
    if term is not None:
        rhs += term.rhs()
    del centre
    x = order.to_pixels(start)
    del start, initial
    rhs = order.to_pixels(rhs)
    q = np.empty_like(x)  # CG consumes H p before asking for the next one
    precision = weight = None
    if term is not None:  # Q and w_p, pixel-major
        precision = np.ascontiguousarray(term.precision)
        weight = term.weight.reshape(-1)[order.order]
        del term

    def operator(cube: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = q if out is None else out
        work.normal_pixels(cube, order=order, epsilon=epsilon, out=out)
        if weight is not None or pixel_prior is not None:
            for first in range(0, cube.shape[0], _CHUNK):  # + w_p Q S_p, chunk by chunk
                here = slice(first, first + _CHUNK)
                if weight is not None:
                    out[here] += (cube[here] @ precision) * weight[here, None]
                if pixel_prior is not None:  # + epsilon_p f_p M S_p
                    f, mask, image = pixel_prior
                    out[here] += cube[here] * (f[here, None] * mask[image[here]])
        return out

    rhs_norm = np.sqrt(COMPILED.dot(rhs, rhs)) or 1.0
    r = rhs - operator(x)
    if precondition == "jacobi":
        scalar = preconditioner.inverse_scalar_diagonal_pixels()

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return residual * scalar

    elif precondition:

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            # into the operator's buffer: CG uses up ``H p`` before it asks for ``z`` and
            # ``z`` before the next ``H p`` (one cube vector fewer)
            return preconditioner.apply_pixels(residual, out=q)

    else:

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return residual.copy()

    cube_wanted = needs_cube(callback)

    def band_major_callback(iteration: int, cube: np.ndarray) -> None:
        callback(iteration, order.to_cube(cube) if cube_wanted else None)

    x, history, iterations = preconditioned_cg(
        operator,
        x,
        r,
        rhs_norm,
        apply_preconditioner,
        tolerance=tolerance,
        max_iterations=max_iterations,
        dtype=dtype,
        callback=None if callback is None else band_major_callback,
        vectors=COMPILED,
    )
    del r
    converged = history[-1] <= tolerance
    if projected_iterations > 0:
        scale = preconditioner.inverse_scalar_diagonal_pixels()
        # the preconditioner and its buffer are done with: the refinement's buffers take
        # their place (the peak is the larger of the two stages, not their sum)
        del preconditioner, apply_preconditioner
        q = None  # and CG's operator buffer: the refinement passes its own
        x = _projected_refinement(operator, rhs, scale, x, int(projected_iterations))
    x = order.to_cube(x)
    return SolverResult(
        x,
        iterations + int(projected_iterations),
        np.asarray(history),
        converged,
        time.perf_counter() - started,
        "spectral-prior-pcg",
        {
            "ridge": float(ridge),
            "prior": float(prior),
            "spectral_prior": float(spectral_prior) if weight is not None else 0.0,
            "prior_weighting": prior_weighting,
            "projected_iterations": int(projected_iterations),
        },
    )
