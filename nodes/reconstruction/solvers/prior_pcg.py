"""Eq. 1 with priors, by the block-Jacobi PCG, then ``S >= 0``: the prior PCG.

The energy is eq. 1 set up with neighbourhoods that separate materials, plus up to two
priors, then refined on ``S >= 0``:

* the problem's set-up (the presets' ``appearance="chromaticity-spatial"``,
  ``scale_invariant=True``, ``k=6``; :func:`~..operators.build_problem`): neighbours in
  chromaticity, log brightness and pixel position instead of absolute RGB, since noisy
  absolute RGB joins pixels of different materials (the paper itself proposes spatial
  proximity against metamers, section 6), and scale-invariant coupling
  ``S(p) - (b_p / b_n) S(n)``, since shading changes a spectrum's scale, not its shape;
* the guided prior ``epsilon_p sum_p f_p M ||S_p - c_p||^2`` of
  :mod:`.block_jacobi_pcg`, its centre ``c`` the guided estimate ``S_0`` (or the
  endmember-mixture estimate with that spectral prior), its per-pixel weight ``f_p``
  uniform or the pixel's relative brightness (:func:`~.spectral_prior.prior_brightness`:
  the bright pixels, whose estimate is accurate relative to their level, are held harder
  than the dark ones, where eq. 1's neighbour term averages out more band noise than it
  adds);
* the spectral prior ``sum_p w_p (S_p - m_p)^T Q (S_p - m_p)``
  (:mod:`.spectral_prior`), learnt from the scene, the endmember mixture or training
  reflectances; ``Q`` couples a pixel's wavelengths, the preconditioner takes its diagonal;
  with ``prior_source="natural"`` the natural-spectra prior (:mod:`.natural_prior`, a
  Gaussian learnt from natural reflectances under the run's illuminant, given the pixel's
  RGB: the Wiener estimate) joins it, weighed per pixel by the band evidence for it over
  the mixture (:mod:`.band_evidence`);
* radiance is never negative: the projected refinement of the same energy
  (:mod:`.projected_refinement`).

With ``spectral_prior=0`` it is eq. 1 with the guided prior on this set-up, refined on
``S >= 0``. The presets ``"spectral-prior-pcg"``, ``"mixture-prior-pcg"`` and
``"natural-prior-pcg"`` (the default)
of :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS` run it; why the
mixture preset stops earlier and refines fewer steps: it starts at its prior's centre, and
the iterations past that drift towards eq. 1's answer, which on sets carries the highlight
and neighbour errors of other images.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 ("Hybrid Methods"), 3 and 6.
.. [2] He, K., Sun, J., Tang, X. (2013). Guided Image Filtering. IEEE TPAMI 35(6).
.. [3] Barzilai, J., Borwein, J. M. (1988). Two-point step size gradient methods. IMA J.
   Numer. Anal. 8.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from spectralize.schemas.errors import ParameterError, ReconstructionError

from ..estimators.endmember_mixture import Endmembers
from ..operators import PixelOrder, ReconstructionProblem
from .common import Callback, SolverResult, pixel_pcg
from .guided_estimate import guided_initial, shot_mask
from .preconditioner import BlockJacobiPreconditioner, normal_mean_diagonal
from .projected_refinement import projected_refinement
from .spectral_prior import (
    PRIOR_WEIGHTINGS,
    SpectralPrior,
    prior_brightness,
    spectral_prior_term,
)

__all__ = ["prior_pcg"]


def prior_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = 1e-3,
    max_iterations: int = 2000,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = 1e-4,
    prior: float = 0.1,
    spectral_prior: float = 0.0,
    covariance_floor: float = 1e-2,
    prior_source: str = "scene",
    precondition: bool = True,
    projected_iterations: int = 40,
    endmembers: Endmembers | None = None,
    prior_weighting: str = "uniform",
    natural_prior: float = 0.0,
) -> SolverResult:
    """Eq. 1 + guided prior + spectral prior by block-Jacobi PCG, then ``S >= 0``.

    Minimises eq. 1 ``+ epsilon_r ||S - S_start||^2 + epsilon_p sum_p f_p M ||S_p -
    c_p||^2 + sum_p w_p (S_p - m_p)^T Q (S_p - m_p)`` (see the module docstring) by
    block-Jacobi PCG, the priors' diagonals in the preconditioner, then refines on
    ``S >= 0``. The keyword defaults are eq. 1 with the guided prior; the presets of
    :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS` set every one.

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`
        with its inputs.
    initial, tolerance, max_iterations, callback, dtype, ridge, prior, precondition
        As for :func:`~.block_jacobi_pcg.block_jacobi_pcg`; the default start is the guided
        prior's centre.
    spectral_prior
        Weight of the spectral prior relative to the mean diagonal of ``A^T A`` (0: none).
    covariance_floor
        ``delta`` of ``Q`` (:mod:`.spectral_prior`).
    prior_source
        One of :data:`~.spectral_prior.PRIOR_SOURCES`: where the spectral prior's mean and
        covariance are learnt (:func:`~.spectral_prior.spectral_prior_term`). With
        ``"mixture"`` the guided prior and the start are centred on the mixture estimate
        too.
    projected_iterations
        Projected-gradient steps on ``S >= 0`` (0: none; the result may then have negative
        values).
    endmembers
        With ``prior_source="mixture"``: the mixture's dictionary, learnt before (a set
        solved tile by tile learns it once,
        :func:`~..estimators.endmember_mixture.set_endmembers`, so every tile mixes the same
        endmembers); None: learnt from the problem's inputs.
    prior_weighting
        One of :data:`~.spectral_prior.PRIOR_WEIGHTINGS`: ``"brightness"`` weighs the
        guided prior of each pixel by its relative brightness ``f_p`` (mean 1,
        :func:`~.spectral_prior.prior_brightness`); ``"uniform"``: ``f_p = 1``.
    natural_prior
        With ``prior_source="natural"``: weight of the natural-spectra prior
        (:mod:`.natural_prior`) relative to the mean diagonal of ``A^T A``, per pixel times
        the band evidence for it (:mod:`.band_evidence`) and ``1 / max(b_p, b_min)^2``;
        it joins the spectral prior, whose centre (and the guided prior's and the start)
        moves towards the Wiener estimate by the pixel's share of the two weights
        (:func:`~.spectral_prior.spectral_prior_term`). 0: the ``"mixture"`` source.

    Returns
    -------
    SolverResult
        ``method="prior_pcg"``; iterations count both stages.

    Raises
    ------
    ParameterError
        For an unknown ``prior_weighting``.
    ReconstructionError
        With ``prior_weighting="brightness"`` for a problem not built from its inputs.
    """
    started = time.perf_counter()
    if prior_weighting not in PRIOR_WEIGHTINGS:
        raise ParameterError.single(
            "prior_weighting", f"one of {PRIOR_WEIGHTINGS}", repr(prior_weighting)
        )
    x, rhs, operator, preconditioner = _prior_system(
        problem,
        np.dtype(dtype),
        initial=initial,
        ridge=ridge,
        prior=prior,
        spectral_prior=spectral_prior,
        covariance_floor=covariance_floor,
        prior_source=prior_source,
        endmembers=endmembers,
        prior_weighting=prior_weighting,
        natural_prior=natural_prior,
    )
    x, history, iterations = pixel_pcg(
        operator,
        x,
        rhs,
        preconditioner,
        operator.order,
        precondition=precondition,
        tolerance=tolerance,
        max_iterations=max_iterations,
        callback=callback,
    )
    converged = history[-1] <= tolerance
    if projected_iterations > 0:
        scale = preconditioner.inverse_scalar_diagonal_pixels()
        # the preconditioner is done with: the refinement's buffers take its place (the
        # peak is the larger of the two stages, not their sum)
        del preconditioner
        x = projected_refinement(
            operator,
            rhs,
            scale,
            x,
            int(projected_iterations),
            gradient=lambda vector, out: operator(vector, out, rhs)[0],
        )
    return SolverResult(
        operator.order.to_cube(x),
        iterations + int(projected_iterations),
        np.asarray(history),
        converged,
        time.perf_counter() - started,
        "prior_pcg",
        {
            "ridge": float(ridge),
            "prior": float(prior),
            "spectral_prior": float(spectral_prior) if operator.weight is not None else 0.0,
            "prior_source": prior_source,
            "prior_weighting": prior_weighting,
            "natural_prior": float(natural_prior) if prior_source == "natural" else 0.0,
            "projected_iterations": int(projected_iterations),
        },
    )


def _prior_system(
    problem: ReconstructionProblem,
    dtype: np.dtype,
    *,
    initial: np.ndarray | None,
    ridge: float,
    prior: float,
    spectral_prior: float,
    covariance_floor: float,
    prior_source: str,
    endmembers: Endmembers | None,
    prior_weighting: str,
    natural_prior: float,
) -> tuple[np.ndarray, np.ndarray, _PriorOperator, BlockJacobiPreconditioner]:
    """The system :func:`prior_pcg` solves, set up in ``dtype``: the start ``x`` and the
    right-hand side, pixel-major in the appearance order, ``H`` and its block-Jacobi
    preconditioner (the priors' diagonals in its ridge). Arguments as for
    :func:`prior_pcg`."""
    work = problem.astype(dtype)
    mask = shot_mask(problem)  # (w, m, 1, 1)
    mean_diagonal = normal_mean_diagonal(work)
    # the spectral prior first: the estimates its centre is made from (float64 cubes) are
    # gone before the guided prior's cubes are made
    term = _spectral_prior(
        problem,
        mean_diagonal,
        dtype,
        weight=spectral_prior,
        covariance_floor=covariance_floor,
        source=prior_source,
        endmembers=endmembers,
        natural_prior=natural_prior,
    )
    # epsilon_p f_p M / mean(diag A^T A), and f_p where the prior is weighted by brightness
    guided, brightness = _guided_prior_weight(
        problem, prior * mask, prior=prior, prior_weighting=prior_weighting, dtype=dtype
    )
    relative = _preconditioner_ridge(term, ridge + guided, mean_diagonal, dtype)
    if term is not None and prior_source in ("mixture", "natural"):
        centre = term.centre  # the guided prior pulls towards the same estimate (read only)
    else:
        centre = np.asarray(guided_initial(problem), dtype=dtype).reshape(work.shape)
    order = work.pixel_order("appearance")
    preconditioner = BlockJacobiPreconditioner(work, dtype, ridge=relative, order=order)
    del relative
    # the ridges alone (without the spectral prior's diagonal), absolute
    towards = dtype.type(ridge * mean_diagonal)
    start = centre if initial is None else np.asarray(initial, dtype=dtype).reshape(work.shape)
    rhs = work.normal_rhs() + towards * start
    epsilon, brightness_pixels, shots = _guided_prior_terms(
        rhs,
        guided,
        brightness,
        mask,
        centre,
        ridge=ridge,
        prior=prior,
        mean_diagonal=mean_diagonal,
        order=order,
        dtype=dtype,
    )
    del guided, brightness
    if term is not None:
        rhs += term.rhs()
    del centre
    x = order.to_pixels(start)
    del start
    rhs = order.to_pixels(rhs)
    precision, weight = _pixel_spectral_prior(term, order, dtype)
    del term
    operator = _PriorOperator(
        work, order, epsilon, precision, weight, brightness=brightness_pixels, shots=shots
    )
    return x, rhs, operator, preconditioner


def _guided_prior_weight(
    problem: ReconstructionProblem,
    guided: np.ndarray,
    *,
    prior: float,
    prior_weighting: str,
    dtype: np.dtype,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The guided prior's weight ``epsilon_p f_p M`` relative to the mean diagonal of
    ``A^T A``, from ``guided = epsilon_p M`` ``(w, m, 1, 1)``: unchanged with
    ``prior_weighting="uniform"``; with ``"brightness"``, times each pixel's relative
    brightness ``f_p`` (one cube in ``dtype``), returned beside it ``(m, y, x)``.

    Raises
    ------
    ReconstructionError
        With ``"brightness"`` for a problem not built from its inputs (no RGB to weigh by).
    """
    if prior_weighting != "brightness" or not prior > 0:
        return guided, None
    inputs = problem.extras.get("inputs")
    if inputs is None:
        raise ReconstructionError.single(
            "problem.extras['inputs']",
            "the inputs the problem was built from (prior_weighting='brightness' weighs the "
            "guided prior by their RGB)",
            "none",
        )
    brightness = prior_brightness(inputs.rgb).astype(dtype)
    return guided.astype(dtype) * brightness[None], brightness  # per pixel: one cube


def _spectral_prior(
    problem: ReconstructionProblem,
    mean_diagonal: float,
    dtype: np.dtype,
    *,
    weight: float,
    covariance_floor: float,
    source: str,
    endmembers: Endmembers | None,
    natural_prior: float,
) -> SpectralPrior | None:
    """The spectral prior term in ``dtype`` (None for ``weight=0``, or where its source
    has none, :func:`~.spectral_prior.spectral_prior_term`)."""
    if not weight > 0:
        return None
    term = spectral_prior_term(
        problem,
        weight,
        mean_diagonal,
        covariance_floor=covariance_floor,
        source=source,
        endmembers=endmembers,
        natural_prior=natural_prior,
    )
    return None if term is None else term.astype(dtype)


def _preconditioner_ridge(
    term: SpectralPrior | None, relative: np.ndarray, mean_diagonal: float, dtype: np.dtype
) -> np.ndarray:
    """The preconditioner's ridge relative to the mean diagonal of ``A^T A``: the ridges
    ``relative``, plus the spectral prior's diagonal where it has one (one cube in
    ``dtype``)."""
    if term is None:
        return relative
    diagonal = term.diagonal()
    diagonal *= dtype.type(1.0 / mean_diagonal)
    diagonal += np.asarray(relative, dtype=dtype)
    return diagonal


def _guided_prior_terms(
    rhs: np.ndarray,
    guided: np.ndarray,
    brightness: np.ndarray | None,
    mask: np.ndarray,
    centre: np.ndarray,
    *,
    ridge: float,
    prior: float,
    mean_diagonal: float,
    order: PixelOrder,
    dtype: np.dtype,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The guided prior ``epsilon_p f_p M`` in ``H`` and ``rhs`` (``+ epsilon_p f_p M c``,
    added to the band-major ``rhs`` in place).

    Uniform per band and image (``brightness`` None): a ridge of the compiled operator,
    ``epsilon`` ``(w, m, 1, 1)`` with the ridge towards the start. Per pixel: ``epsilon``
    is the ridge alone, and the operator's pass applies ``f_p`` (pixel-major, in ``order``)
    times ``epsilon_p M`` per image (``shots``, ``(m, w)``) beside ``w_p Q``; ``guided`` is
    used up.

    Returns
    -------
    epsilon, brightness, shots
        Absolute, in ``dtype``; the last two None for a uniform prior.
    """
    if brightness is None:
        epsilon = ((ridge + prior * mask) * mean_diagonal).astype(dtype)
        rhs += (guided * mean_diagonal).astype(dtype) * centre
        return epsilon, None, None
    epsilon = np.asarray(ridge * mean_diagonal, dtype=dtype)
    guided *= dtype.type(mean_diagonal)  # + epsilon_p f_p M c, in the weights' cube
    guided *= centre
    rhs += guided
    brightness_pixels = np.ascontiguousarray(brightness.reshape(-1)[order.order], dtype=dtype)
    shots = np.ascontiguousarray((mask[:, :, 0, 0].T * (prior * mean_diagonal)).astype(dtype))
    return epsilon, brightness_pixels, shots


def _pixel_spectral_prior(
    term: SpectralPrior | None, order: PixelOrder, dtype: np.dtype
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``Q`` ``(w, w)`` and ``w_p`` pixel-major in ``order``, in ``dtype``, for the compiled
    pass (None, None without a spectral prior)."""
    if term is None:
        return None, None
    precision = np.ascontiguousarray(term.precision, dtype=dtype)
    weight = np.ascontiguousarray(term.weight.reshape(-1)[order.order], dtype=dtype)
    return precision, weight


@dataclass(frozen=True)
class _PriorOperator:
    """``H`` of :func:`prior_pcg` on pixel-major vectors (a
    :data:`~.common.PixelOperator`): eq. 1's normal operator, the ridges and the per-pixel
    priors ``w_p Q S_p`` and ``epsilon_p f_p M S_p`` in one compiled pass
    (:meth:`~..operators.ReconstructionProblem.prior_normal_pixels`), which returns
    ``S . H S`` too; with ``subtract``, ``H S - subtract`` (the refinement's gradient)."""

    work: ReconstructionProblem
    order: PixelOrder
    epsilon: np.ndarray
    precision: np.ndarray | None
    weight: np.ndarray | None
    brightness: np.ndarray | None = None
    shots: np.ndarray | None = None

    def __call__(
        self, vector: np.ndarray, out: np.ndarray, subtract: np.ndarray | None = None
    ) -> tuple[np.ndarray, float]:
        curvature = self.work.prior_normal_pixels(
            vector,
            order=self.order,
            epsilon=self.epsilon,
            out=out,
            precision=self.precision,
            weight=self.weight,
            brightness=self.brightness,
            shots=self.shots,
            subtract=subtract,
        )
        return out, curvature
