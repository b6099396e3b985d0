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

import numpy as np

from ..estimators.endmember_mixture import Endmembers
from ..operators import ReconstructionProblem
from .common import Callback, SolverResult, pixel_pcg
from .guided_estimate import guided_initial, shot_mask
from .preconditioner import BlockJacobiPreconditioner, normal_mean_diagonal
from .projected_refinement import projected_refinement
from .spectral_prior import PRIOR_WEIGHTINGS, prior_brightness, spectral_prior_term

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
    mask = shot_mask(problem)  # (w, m, 1, 1)
    guided = prior * mask  # epsilon_p M / mean(diag A^T A)
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
            natural_prior=natural_prior,
        )
    if term is not None:  # the prior's diagonal joins the ridges, one float32 cube
        term = term.astype(dtype)
        diagonal = term.diagonal()
        diagonal *= dtype.type(1.0 / mean_diagonal)
        diagonal += np.asarray(relative, dtype=dtype)
        relative = diagonal
        del diagonal
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
    brightness_pixels = shots = None  # epsilon_p f_p M per pixel: f_p and epsilon_p M per image
    if brightness is None:  # uniform per (band, image): a ridge of the compiled operator
        epsilon = ((ridge + prior * mask) * mean_diagonal).astype(dtype)
        rhs += (guided * mean_diagonal).astype(dtype) * centre  # + epsilon_p M c
    else:  # per pixel: epsilon_p f_p M, applied in the operator's pass beside ``w_p Q``
        epsilon = np.asarray(ridge * mean_diagonal, dtype=dtype)
        guided *= dtype.type(mean_diagonal)  # + epsilon_p f_p M c, in the weights' cube
        guided *= centre
        rhs += guided
        brightness_pixels = np.ascontiguousarray(brightness.reshape(-1)[order.order], dtype=dtype)
        shots = np.ascontiguousarray((mask[:, :, 0, 0].T * (prior * mean_diagonal)).astype(dtype))
        del brightness
    del guided
    if term is not None:
        rhs += term.rhs()
    del centre
    x = order.to_pixels(start)
    del start, initial
    rhs = order.to_pixels(rhs)
    precision = weight = None
    if term is not None:  # Q and w_p, pixel-major
        precision = np.ascontiguousarray(term.precision, dtype=dtype)
        weight = np.ascontiguousarray(term.weight.reshape(-1)[order.order], dtype=dtype)
        del term

    def operator(
        vector: np.ndarray, out: np.ndarray, subtract: np.ndarray | None = None
    ) -> tuple[np.ndarray, float]:
        # eq. 1's normal operator, the ridges and the per-pixel priors ``w_p Q S_p`` and
        # ``epsilon_p f_p M S_p`` in one compiled pass (and ``S . H S`` with it)
        curvature = work.prior_normal_pixels(
            vector,
            order=order,
            epsilon=epsilon,
            out=out,
            precision=precision,
            weight=weight,
            brightness=brightness_pixels,
            shots=shots,
            subtract=subtract,
        )
        return out, curvature

    x, history, iterations = pixel_pcg(
        operator,
        x,
        rhs,
        preconditioner,
        order,
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
        order.to_cube(x),
        iterations + int(projected_iterations),
        np.asarray(history),
        converged,
        time.perf_counter() - started,
        "prior_pcg",
        {
            "ridge": float(ridge),
            "prior": float(prior),
            "spectral_prior": float(spectral_prior) if weight is not None else 0.0,
            "prior_source": prior_source,
            "prior_weighting": prior_weighting,
            "natural_prior": float(natural_prior) if prior_source == "natural" else 0.0,
            "projected_iterations": int(projected_iterations),
        },
    )
