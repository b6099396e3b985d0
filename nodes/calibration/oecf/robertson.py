"""Robertson et al. (2003): the camera response from exposure series of raw integer codes.

:func:`robertson_response` is the numpy core (one channel); :func:`recover_oecf` runs it per
camera and channel on xarray exposure series of any bit depth 8..16, RGB or monochrome, and
returns the response table (:mod:`~spectralize.nodes.calibration.oecf.response`);
:func:`recover_rgb_oecf` (node ``recover_rgb_oecf``) runs it on the ``raw/rgb`` group.

References
----------
.. [1] M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic
   range enhancement using multiple exposures", Journal of Electronic Imaging 12(2),
   219-228, 2003.
.. [2] M. D. Grossberg, S. K. Nayar, "Determining the camera response from images: what is
   knowable?", IEEE TPAMI 25(11), 2003.
.. [3] Fast Capture of Spectral Image Series, section 4 ("Calibration") and eq. 5.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Annotated, Literal, NamedTuple

import numpy as np
import xarray as xr
from pydantic import Field
from scipy import sparse
from scipy.sparse import linalg as sparse_linalg

from spectralize.engine import Choices
from spectralize.nodes.calibration.exposure_series import (
    check_bit_depth,
    check_exposure_times,
    check_frames,
    check_integer,
    counts_array,
    frame_extremes,
    raise_first,
    raise_for_frames,
    refused,
    warn_if_geometric,
)
from spectralize.nodes.calibration.oecf.log_spline import chosen_log_spline_response, codes_reached
from spectralize.nodes.calibration.oecf.low_end import low_end_response
from spectralize.nodes.calibration.oecf.response import response_dataarray
from spectralize.nodes.calibration.oecf.weighting import (
    WEIGHTING_FUNCTIONS,
    Weighting,
    weighting_function,
)
from spectralize.nodes.calibration.white_level import (
    CameraWhiteLevel,
    camera_white_levels,
    white_level_variables,
)
from spectralize.schemas import CalibrationError, SchemaError, SpectralizeError
from spectralize.schemas.errors import Problem

__all__ = [
    "Operator",
    "Solver",
    "RobertsonResult",
    "robertson_response",
    "recover_oecf",
    "recover_rgb_oecf",
    "default_black_level",
    "camera_black_levels",
    "with_target_series",
    "rgb_oecf_refusals",
    "SMOOTH_RGB",
    "LOG_SPLINE_PIXELS",
    "log_spline_smoothed",
]

Operator = Literal["auto", "dense", "sparse", "samples"]
Solver = Literal["lanczos", "power"]


def _fill_unobserved(known: np.ndarray, values: np.ndarray, n_codes: int, tail: int = 8) -> np.ndarray:
    """Response at every code ``0 .. n_codes-1`` from values at the increasing codes ``known``.

    Linear interpolation between known codes; linear extrapolation beyond them with the
    least-squares slope of the ``tail`` nearest known codes, clipped at 0 so that a
    non-decreasing response stays non-decreasing. Never NaN.
    """
    codes = np.arange(n_codes, dtype=np.float64)
    out = np.interp(codes, known, values)
    if known.size == 1:
        return out

    def slope(c: np.ndarray, v: np.ndarray) -> float:
        return max(float(np.polyfit(c, v, 1)[0]), 0.0)

    below = codes < known[0]
    if below.any():
        s = slope(known[:tail], values[:tail])
        out[below] = values[0] + s * (codes[below] - known[0])
    above = codes > known[-1]
    if above.any():
        s = slope(known[-tail:], values[-tail:])
        out[above] = values[-1] + s * (codes[above] - known[-1])
    return out


@dataclass(frozen=True)
class RobertsonResult:
    """Outcome of :func:`robertson_response`.

    Attributes
    ----------
    response
        ``f(code)`` for every code ``0 .. n_codes-1``, float64, normalised to 1 at the mid code;
        codes never observed are interpolated (never NaN).
    samples
        Number of samples (from pixels with at least one weighted sample) per code.
    iterations
        Iterations run.
    converged
        Whether the relative change fell below the tolerance.
    change
        Relative change of the last iteration.
    """

    response: np.ndarray
    samples: np.ndarray
    iterations: int
    converged: bool
    change: float


class _CodeBins(NamedTuple):
    """The response's unknowns: bins of ``width`` consecutive codes (:func:`_code_bins`)."""

    n_codes: int
    saturation: int
    """One past the last code of non-zero weight; the codes from it up form one bin."""
    width: int
    n_main: int
    """Bins below saturation."""
    n_bins: int
    centres: np.ndarray
    bin_weights: np.ndarray
    code_to_bin: np.ndarray
    code_weights: np.ndarray
    """The weight of every code's bin."""
    identity: bool
    """One bin per code: the codes are the bins."""


@dataclass
class _SampleTally:
    """Samples per bin and per code of the pixels with a weighted sample, as
    :func:`_image_terms` folds the images in."""

    per_bin: np.ndarray
    samples: np.ndarray
    any_valid: bool = False


class _ObservedBins(NamedTuple):
    """The bins with samples (``obs_*``, ``counts``) and among them the bins of non-zero
    weight (``active``, ``act_bins``, ``a_*``), on which Robertson's iteration runs."""

    obs_bins: np.ndarray
    obs_centres: np.ndarray
    counts: np.ndarray
    active: np.ndarray
    act_bins: np.ndarray
    a_counts: np.ndarray
    a_weights: np.ndarray
    a_centres: np.ndarray


def _as_groups(codes: np.ndarray, exposure_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    codes = np.asarray(codes)
    times = np.asarray(exposure_times, dtype=np.float64)
    shapes = f"got codes {codes.shape}, exposure_times {times.shape}"
    if codes.ndim == 2:
        codes = codes[None]
    if times.ndim == 1 and codes.ndim == 3:
        times = np.broadcast_to(times, (codes.shape[0], times.size))
    if codes.ndim != 3 or times.shape != codes.shape[:2]:
        raise CalibrationError(
            "codes must be (exposure, pixel) or (image, exposure, pixel) with exposure_times "
            f"(exposure,) or (image, exposure); {shapes}"
        )
    return codes, times


def _checked_inputs(
    codes: np.ndarray,
    exposure_times: np.ndarray,
    n_codes: int,
    weights: np.ndarray,
    solver: str,
    operator: str,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(codes (image, exposure, pixel), times (image, exposure), weights)`` of
    :func:`robertson_response`, checked: shapes, integer codes in ``0 .. n_codes-1``,
    positive finite times, the solver and the operator (a :class:`CalibrationError` naming
    what was found otherwise)."""
    codes, times = _as_groups(codes, exposure_times)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != (n_codes,):
        raise CalibrationError(f"weights must have shape ({n_codes},), got {weights.shape}")
    if codes.size == 0:
        raise CalibrationError("codes is empty: an exposure series needs pixels")
    if not np.issubdtype(codes.dtype, np.integer):
        raise CalibrationError(f"codes must be integers, got dtype {codes.dtype}")
    lo, hi = int(codes.min()), int(codes.max())
    if lo < 0 or hi >= n_codes:
        raise CalibrationError(f"codes must lie in [0, {n_codes - 1}], found [{lo}, {hi}]")
    if not np.all(times > 0) or not np.all(np.isfinite(times)):
        raise CalibrationError(f"exposure_times must be positive and finite, got {times}")
    if solver not in ("lanczos", "power"):
        raise CalibrationError(f"solver must be 'lanczos' or 'power', got {solver!r}")
    if operator not in ("auto", "dense", "sparse", "samples"):
        raise CalibrationError(
            f"operator must be 'auto', 'dense', 'sparse' or 'samples', got {operator!r}"
        )
    return codes, times, weights


def _code_bins(weights: np.ndarray, n_codes: int, max_bins: int) -> _CodeBins:
    """Bins of ``width`` consecutive codes (width 1: no binning), at most ``max_bins``.

    The saturated codes, above the last code of non-zero weight, form one bin of their own:
    clamping collapses a wide range of exposures onto them, which must not leak into the
    bins below. A bin's weight is the weight at its centre, 0 where it holds a code of zero
    weight.
    """
    positive = np.flatnonzero(weights > 0)
    if positive.size == 0:
        raise CalibrationError("weights are zero for every code")
    saturation = int(positive[-1]) + 1
    width = max(1, -(-saturation // max(int(max_bins) - 1, 1)))
    n_main = -(-saturation // width)
    first = np.arange(n_main) * width
    last = np.minimum(first + width - 1, saturation - 1)
    if saturation < n_codes:
        first = np.append(first, saturation)
        last = np.append(last, n_codes - 1)
    centres = (first + last) / 2.0
    bin_weights = np.where(
        (weights[first] > 0) & (weights[last] > 0), np.interp(centres, np.arange(n_codes), weights), 0.0
    )
    code_to_bin = np.minimum(np.arange(n_codes) // width, n_main)
    if saturation < n_codes:
        code_to_bin[saturation:] = n_main
    return _CodeBins(
        n_codes=n_codes,
        saturation=saturation,
        width=width,
        n_main=n_main,
        n_bins=first.size,
        centres=centres,
        bin_weights=bin_weights,
        code_to_bin=code_to_bin,
        code_weights=bin_weights[code_to_bin],
        identity=width == 1 and saturation >= n_codes - 1,
    )


def _image_terms(
    codes: np.ndarray, times: np.ndarray, bins: _CodeBins, tally: _SampleTally
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per image (group) ``(bins (E, P), t (E,), 1/den (P,))`` for :func:`_gram_operator`,
    ``den = sum_j w(y_ij) t_j^2``, counting the samples into ``tally`` as it goes.

    One image at a time: its bins, its per-pixel denominators and its sample counts are
    made, folded into ``C`` and the counts, and dropped before the next image's; the pooled
    images never have intp bins or float64 denominators all at once. Pixels without a
    weighted sample are left out: ``1/den = 0`` removes them from every sum (no copy of the
    samples); they are subtracted from the counts.
    """
    n_bins, n_codes, identity = bins.n_bins, bins.n_codes, bins.identity
    for g in range(codes.shape[0]):
        own = codes[g]  # (E, P)
        if identity:  # bin of every sample (E, P)
            idx = own if own.dtype.itemsize < 8 else own.astype(np.intp, copy=False)
        else:
            idx = bins.code_to_bin[own]
        den = np.zeros(own.shape[1])  # sum_j w(y_ij) t_j^2 per pixel
        for j in range(own.shape[0]):
            den += np.take(bins.code_weights * times[g, j] ** 2, own[j])
        valid = den > 0
        inv_den = np.divide(1.0, den, out=np.zeros_like(den), where=valid)
        del den
        own_bins = np.bincount(idx.ravel(), minlength=n_bins)
        tally.per_bin[:] += own_bins
        tally.samples[:] += own_bins if identity else np.bincount(own.ravel(), minlength=n_codes)
        p_out = np.flatnonzero(~valid)
        if p_out.size:
            left_out = idx[:, p_out].ravel()
            tally.per_bin[:] -= np.bincount(left_out, minlength=n_bins)
            tally.samples[:] -= np.bincount(
                own[:, p_out].ravel() if not identity else left_out, minlength=n_codes
            )
        if valid.any():
            tally.any_valid = True
            yield idx, times[g], inv_den


def _observed_bins(per_bin: np.ndarray, bins: _CodeBins) -> _ObservedBins:
    """The bins with samples and, among them, those of non-zero weight ("active").

    The iteration runs on the active bins; samples of zero weight enter it only through
    ``den``. Bins of zero weight follow from the converged response by one last update (in
    Robertson's update they never feed back).
    """
    observed = per_bin > 0
    obs_bins = np.flatnonzero(observed)
    obs_centres = bins.centres[observed]
    counts = per_bin[observed].astype(np.float64)
    w_obs = bins.bin_weights[observed]
    active = w_obs > 0
    if int(active.sum()) == 0:
        raise CalibrationError(
            "no code with non-zero weight was observed; check black_level and saturation"
        )
    return _ObservedBins(
        obs_bins=obs_bins,
        obs_centres=obs_centres,
        counts=counts,
        active=active,
        act_bins=obs_bins[active],
        a_counts=counts[active],
        a_weights=w_obs[active],
        a_centres=obs_centres[active],
    )


def _matrix_update(
    f: np.ndarray, c: np.ndarray | sparse.csr_array, weights: np.ndarray, counts: np.ndarray
) -> np.ndarray:
    """Robertson's update from ``C`` (rows: the bins updated, columns: the active bins):
    ``C W f / N``, both steps at once."""
    return c @ (weights * f) / counts


def _samples_update(
    f: np.ndarray,
    cmul: Callable[[np.ndarray], np.ndarray],
    obs: _ObservedBins,
    n_bins: int,
    rows: np.ndarray,
    counts: np.ndarray,
) -> np.ndarray:
    """Robertson's update with ``C v`` computed from the samples (``cmul``), at ``rows``."""
    v = np.zeros(n_bins)
    v[obs.act_bins] = obs.a_weights * f
    return cmul(v)[rows] / counts


def _robertson_updates(
    gram: np.ndarray | sparse.csr_array | Callable, obs: _ObservedBins, n_bins: int
) -> tuple[Callable[[np.ndarray], np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    """``(step, last_update)``: Robertson's update ``f <- B f`` on the active bins, and the
    one last update of every observed bin from the converged active ones."""
    if callable(gram):  # operator "samples": C v from the samples
        return (
            partial(
                _samples_update,
                cmul=gram,
                obs=obs,
                n_bins=n_bins,
                rows=obs.act_bins,
                counts=obs.a_counts,
            ),
            partial(
                _samples_update, cmul=gram, obs=obs, n_bins=n_bins, rows=obs.obs_bins, counts=obs.counts
            ),
        )
    # C once: an update is one matrix-vector product
    c_active = gram[obs.act_bins][:, obs.act_bins]
    c_observed = gram[obs.obs_bins][:, obs.act_bins]
    return (
        partial(_matrix_update, c=c_active, weights=obs.a_weights, counts=obs.a_counts),
        partial(_matrix_update, c=c_observed, weights=obs.a_weights, counts=obs.counts),
    )


def _normalise(f: np.ndarray, mid: float, centres: np.ndarray) -> np.ndarray:
    """``f`` (at the bin ``centres``) scaled to 1 at the mid code."""
    scale = np.interp(mid, centres, f)
    if not scale > 0:
        raise CalibrationError(
            f"the response at the mid code {mid} is {scale}: no usable signal around it"
        )
    return f / scale


def _fixed_point(
    step: Callable[[np.ndarray], np.ndarray],
    obs: _ObservedBins,
    mid: float,
    *,
    solver: Solver,
    tolerance: float,
    max_iterations: int,
    smooth: int | None,
) -> tuple[np.ndarray, int, bool, float]:
    """Robertson's response on the active bins: ``(f, iterations, converged, change)``.

    From the linear start ``(m + 0.5) / (mid + 0.5)``: with ``smooth`` (and enough active
    bins) the maximiser over a spline space (:func:`_smooth_fixed_point`, no iteration);
    else Robertson's updates until the relative change falls below ``tolerance``, from
    Lanczos' Perron vector (:func:`_perron_vector`) with ``solver="lanczos"``.
    """
    centres = obs.a_centres
    f = _normalise((centres + 0.5) / (mid + 0.5), mid, centres)
    nw = obs.a_counts * obs.a_weights
    if smooth is not None and centres.size > int(smooth) + 2:
        f, iterations = _smooth_fixed_point(step, centres, nw, int(smooth))
        return _normalise(f, mid, centres), iterations, True, 0.0
    iterations = 0
    if solver == "lanczos":
        start, matvecs = _perron_vector(step, np.sqrt(nw), f)
        iterations += matvecs
        if start is not None:
            f = _normalise(start, mid, centres)
    change = math.inf
    while iterations < max_iterations:
        new = _normalise(step(f), mid, centres)
        iterations += 1
        change = float(np.max(np.abs(new - f) / np.maximum(np.abs(new), 1e-12)))
        f = new
        if change < tolerance:
            return f, iterations, True, change
    return f, iterations, False, change


def _response_at_codes(
    f: np.ndarray,
    last_update: Callable[[np.ndarray], np.ndarray],
    obs: _ObservedBins,
    bins: _CodeBins,
    mid: float,
    monotone: bool,
) -> np.ndarray:
    """The response at every code from the converged active bins ``f``.

    All observed bins get one last update (zero-weight bins included; the active bins keep
    the converged values), the result is made non-decreasing when ``monotone``, codes never
    observed are filled (:func:`_fill_unobserved`) and the saturated codes get their bin's
    value, never below the code under them.
    """
    from scipy.optimize import isotonic_regression

    f = np.where(obs.active, f[np.cumsum(obs.active) - 1], last_update(f))
    f = _normalise(f, mid, obs.obs_centres)
    if monotone:
        f = _normalise(isotonic_regression(f, weights=obs.counts).x, mid, obs.obs_centres)
    main = obs.obs_bins < bins.n_main
    full = _fill_unobserved(obs.obs_centres[main], f[main], bins.n_codes)
    saturation = bins.saturation
    if saturation < bins.n_codes and not main.all():
        full[saturation:] = np.maximum(f[~main][0], full[saturation - 1])
    return full


def robertson_response(
    codes: np.ndarray,
    exposure_times: np.ndarray,
    *,
    n_codes: int,
    weights: np.ndarray,
    mid_code: float | None = None,
    tolerance: float = 1e-6,
    max_iterations: int = 5000,
    monotone: bool = True,
    max_bins: int = 1024,
    solver: Solver = "lanczos",
    operator: Operator = "auto",
    smooth: int | None = None,
    low_end: bool = False,
) -> RobertsonResult:
    """Robertson et al. (2003) response recovery for one channel (numpy core).

    Alternates the two maximum-likelihood steps until the response stops changing:

    ``x_i = sum_j w(y_ij) t_j f(y_ij) / sum_j w(y_ij) t_j^2`` (irradiance of pixel ``i``),
    ``f(m) = mean over samples with y_ij = m of t_j x_i`` (response at code ``m``),

    rescaling ``f`` after every update so that ``f(mid_code) = 1``.

    Parameters
    ----------
    codes
        Integer pixel values, ``(exposure, pixel)`` or ``(image, exposure, pixel)``.
    exposure_times
        ``(exposure,)`` or ``(image, exposure)`` [s], positive.
    n_codes
        Number of codes (``2**bit_depth``); every code must be below it.
    weights
        ``w(code)`` for every code, shape ``(n_codes,)`` (see :func:`~.weighting_function`).
    mid_code
        Normalisation point; default ``(n_codes - 1) / 2``. When it was not observed, the
        response is interpolated there from the nearest observed codes.
    tolerance
        Convergence criterion: stop when one Robertson update changes the response by less
        than ``tolerance`` relatively, ``max_m |f_k+1(m) - f_k(m)| / |f_k+1(m)| < tolerance``
        over the observed codes.
    max_iterations
        Safety limit on updates; reaching it returns ``converged=False``.
    monotone
        Project the converged response on non-decreasing sequences (least squares weighted
        by the samples per code, :func:`scipy.optimize.isotonic_regression`) before filling
        unobserved codes.
    max_bins
        At most this many response unknowns: when the ``s`` codes below saturation (``s``:
        one past the last code of non-zero weight) outnumber ``max_bins - 1`` (11..16 bit
        with the default 1024), they are grouped into bins of ``ceil(s / (max_bins - 1))``
        consecutive codes (the saturated codes form one more bin), each bin is one unknown
        placed at its centre code, and the response at every
        code is interpolated between bin centres. A bin that contains a code of zero weight
        gets weight 0. With 16-bit data this trades a negligible interpolation error (far
        below the read noise) for many samples per unknown.
    solver
        ``"power"``: Robertson's iteration from the linear initialisation. ``"lanczos"``
        (default): the same fixed point reached faster; see Notes. Either way the result
        satisfies the convergence criterion above for Robertson's own update.
    operator
        How an update is computed: ``"dense"`` or ``"sparse"`` fold all samples once into a
        code-by-code matrix (one ``np.bincount`` over the sample pairs of each pixel), after
        which an update is one matrix-vector product; ``"samples"`` recomputes every update
        from the samples. ``"auto"``: dense up to 2048 unknowns, else sparse. Same iterates.

    smooth
        ``None`` (default): one unknown per code (or bin). An integer ``K``: the response
        is a cubic spline with ``K`` coefficients (knots at quantiles of the weighted
        samples, never more than an eighth of the code range apart), the maximiser of
        Robertson's objective over that space (Rayleigh-Ritz, :func:`_smooth_fixed_point`;
        no iteration, ``converged`` is True). Crowded exposures (a scene of few materials,
        uniform targets) with noise in the codes, and few exposure ratios (Grossberg & Nayar
        2003), leave the per-code response with ripples of a few percent; the spline
        removes them. Used when more than ``K + 2`` codes (bins) have weighted samples.
    low_end
        Take the codes under the low end's anchor, where the weights are all but zero,
        from the reverse regression of the samples (:func:`~.low_end.low_end_response`:
        the spectral camera's dark-level model), so that the response follows a toe
        there; the rest of the response is kept.

    Returns
    -------
    RobertsonResult

    Raises
    ------
    CalibrationError
        If no pixel has a sample with non-zero weight (all saturated or all dark), codes
        lie outside ``0 .. n_codes-1``, or exposure times are not positive.

    Notes
    -----
    Initialisation: linear, ``f_0(m) = (m + 0.5) / (mid_code + 0.5)``.

    Both steps are linear in ``f``, so one update is ``f <- B f`` with the fixed matrix
    ``B = N^-1 C W``: ``N`` the samples per code, ``W`` the weights, and
    ``C[m, n] = sum_i sum_{j,l} [y_ij = m][y_il = n] t_j t_l / sum_j w(y_ij) t_j^2`` (symmetric,
    positive semi-definite). Robertson's normalised iteration is thus a power iteration
    and its fixed point is the Perron eigenvector of ``B``. ``B`` is similar to the
    symmetric ``(W/N)^1/2 C (W/N)^1/2``, whose top eigenvector symmetric Lanczos
    (ARPACK) finds in far fewer products than the power iteration needs when the second
    eigenvalue is close to the first; Robertson updates then run until the tolerance is met.

    The iteration runs over the codes of non-zero weight; codes of zero weight (under-exposed,
    saturated) get their value from one last update once it has converged (in Robertson's
    update they never feed back): the matrix ``C`` covers all bins, so that update is one more
    product with its rows of zero-weight bins. The saturated codes form one bin
    of their own, so clamping never leaks into the codes below. Pixels without any weighted
    sample are left out. Codes never observed are filled by linear interpolation between
    observed ones and by linear extrapolation (slope >= 0, from the nearest 8 observed codes)
    beyond them: never NaN.

    The tolerance bounds the change per update, not the distance to the fixed point; with
    the Lanczos start the two agree to about the tolerance (tested against 50 000 power
    iterations).

    Memory: ``C``, the samples per code and the per-pixel ``den`` are built image by image
    (``operator`` ``"dense"``, the default's choice up to 2048 unknowns): besides ``codes``
    the fit holds one image's bins and denominators at a time, not every image's (the bands
    that :func:`~.recover_spectral_oecf` pools as images would need them all at once).

    The steps: the inputs checked (:func:`_checked_inputs`), the codes binned
    (:func:`_code_bins`), the samples folded into ``C`` image by image (:func:`_image_terms`,
    :func:`_gram_operator`), the fixed point on the bins of non-zero weight
    (:func:`_fixed_point`) and the response at every code (:func:`_response_at_codes`).

    Identifiability: if all exposure-time ratios are equal (a geometric bracket, or only
    two exposures) the data determine ``f`` only up to a factor periodic in log exposure
    with that ratio as period (Grossberg & Nayar 2003); only noise breaks the tie. Use
    exposure times with unequal ratios (e.g. 1, 3, 8, 25, 60).

    Domain: integer codes in ``[0, n_codes)``. Range: non-negative relative exposures,
    non-decreasing when ``monotone``.

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003, section 3 (iterative estimation, weighting).
    .. [2] Grossberg, Nayar 2003 (ambiguity of equal exposure ratios).
    """
    codes, times, weights = _checked_inputs(codes, exposure_times, n_codes, weights, solver, operator)
    mid = (n_codes - 1) / 2.0 if mid_code is None else float(mid_code)
    bins = _code_bins(weights, n_codes, max_bins)
    tally = _SampleTally(np.zeros(bins.n_bins, dtype=np.intp), np.zeros(n_codes, dtype=np.intp))
    gram = _gram_operator(_image_terms(codes, times, bins, tally), bins.n_bins, operator)
    if not tally.any_valid:
        raise CalibrationError(
            "no pixel has a single sample with non-zero weight: every sample is saturated or "
            "under-exposed; check the exposure times, black_level and saturation"
        )
    obs = _observed_bins(tally.per_bin, bins)
    step, last_update = _robertson_updates(gram, obs, bins.n_bins)
    f, iterations, converged, change = _fixed_point(
        step,
        obs,
        mid,
        solver=solver,
        tolerance=tolerance,
        max_iterations=max_iterations,
        smooth=smooth,
    )
    full = _response_at_codes(f, last_update, obs, bins, mid, monotone)
    if low_end:
        full = low_end_response(full, codes, times, weights)
        full = full / np.interp(mid, np.arange(n_codes), full)
    return RobertsonResult(full, tally.samples, iterations, converged, change)


def _spline_basis(x: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """Cubic B-spline design matrix ``(x.size, k)`` on ``x`` (increasing): interior knots at
    the ``weights``-quantiles of ``x``, with knots added where two lie more than an eighth of
    the range apart (sparse data near saturation still gets a flexible shoulder)."""
    from scipy.interpolate import BSpline

    lo, hi = float(x[0]), float(x[-1])
    cdf = np.cumsum(weights) / weights.sum()
    inner = np.interp(np.linspace(0.0, 1.0, k - 2)[1:-1], cdf, x)
    knots = np.unique(np.concatenate([[lo], inner, [hi]]))
    gaps = np.diff(knots)
    extra = [
        np.linspace(a, b, int(np.ceil(g / ((hi - lo) / 8.0))) + 1)[1:-1]
        for a, b, g in zip(knots[:-1], knots[1:], gaps, strict=True)
    ]
    knots = np.unique(np.concatenate([knots, *extra]))
    t = np.concatenate([[lo] * 3, knots, [hi] * 3])
    return BSpline.design_matrix(x, t, 3).toarray()


def _smooth_fixed_point(
    step: Callable[[np.ndarray], np.ndarray], x: np.ndarray, nw: np.ndarray, k: int
) -> tuple[np.ndarray, int]:
    """Robertson's response restricted to a cubic spline space, by Rayleigh-Ritz.

    ``B = N^-1 C W`` (``step``: ``f -> B f``) is self-adjoint in the inner product weighted by
    ``N W`` (``nw``), and its dominant eigenvector maximises the Rayleigh quotient
    ``f^T N W B f / f^T N W f``, which is Robertson's objective with the irradiances
    eliminated. Over ``f = Phi a`` (``Phi``: :func:`_spline_basis` at the bin centres ``x``)
    the maximiser solves ``Phi^T N W B Phi a = lambda Phi^T N W Phi a`` (``K`` products with
    ``B``). Negative values (near the black level) are set to 0. Returns ``(f, products)``.
    """
    from scipy.linalg import eigh

    phi = _spline_basis(x, nw, k)
    phi = phi[:, phi.T @ nw > 0]  # basis functions without weighted samples are left out
    b_phi = np.stack([step(phi[:, j]) for j in range(phi.shape[1])], axis=1)
    lhs = phi.T @ (nw[:, None] * b_phi)
    lhs = 0.5 * (lhs + lhs.T)
    rhs = phi.T @ (nw[:, None] * phi)
    rhs[np.diag_indices_from(rhs)] += 1e-12 * np.trace(rhs) / rhs.shape[0]
    _, vectors = eigh(lhs, rhs)
    f = phi @ vectors[:, -1]
    f = f if f @ nw >= 0 else -f
    return np.maximum(f, 0.0), phi.shape[1]


def _gram_operator(
    groups: Iterable[tuple[np.ndarray, np.ndarray, np.ndarray]], k: int, operator: Operator
) -> np.ndarray | sparse.csr_array | Callable:
    """``C[m, n] = sum_i (1/den_i) sum_{j,l} [y_ij=m][y_il=n] t_j t_l`` over bins ``0..k-1``.

    ``groups`` yields per image ``(bins (E, P) in 0..k-1, t (E,), 1/den (P,))``; pixels with
    ``1/den = 0`` contribute nothing. ``"dense"`` folds the images in one pass, in order (an
    iterator that makes them one at a time then holds one image's terms at a time);
    ``"sparse"`` and ``"samples"`` keep every image's. ``C`` is symmetric positive
    semi-definite (a sum of rank-one terms ``a_i a_i^T / den_i`` with
    ``a_i[m] = sum_j [y_ij=m] t_j``).

    Returns the matrix (``"dense"``: a numpy array, or a CSR array when at most 1/8 of it is
    non-zero; ``"sparse"``: a CSR array), or for ``"samples"`` the function ``v -> C v``
    evaluated from the samples at every call.
    """
    if operator == "auto":
        operator = "dense" if k <= 2048 else "sparse"
    if operator == "dense":
        upper = np.zeros(k * k)
        diagonal = np.zeros(k)
        for r, t, inv_den in groups:
            # the pairs (j, l), j < l, in one bincount over flat indices m k + n (the matrix is
            # symmetrised below); the pairs (j, j) only reach the diagonal
            j, m = np.triu_indices(r.shape[0], 1)
            pairs = np.empty((j.size, r.shape[1]), dtype=np.intp)
            for i in range(j.size):
                np.multiply(r[j[i]], k, out=pairs[i], dtype=np.intp)
                np.add(pairs[i], r[m[i]], out=pairs[i])
            upper += np.bincount(
                pairs.ravel(), ((t[j] * t[m])[:, None] * inv_den).ravel(), minlength=k * k
            )
            diagonal += np.bincount(r.ravel(), ((t * t)[:, None] * inv_den).ravel(), minlength=k)
        nonzero = np.flatnonzero(upper)
        if nonzero.size > 0.125 * k * k:
            dense = upper.reshape(k, k)
            dense = dense + dense.T
            dense[np.diag_indices(k)] += diagonal
            return dense
        # codes co-occur in bands only: a sparse matrix makes each product cheap
        rows, cols = np.divmod(nonzero, k)
        values = upper[nonzero]
        on = np.arange(k)
        return sparse.csr_array(
            (
                np.concatenate([values, values, diagonal]),
                (np.concatenate([rows, cols, on]), np.concatenate([cols, rows, on])),
            ),
            shape=(k, k),
        )
    if operator == "sparse":
        rows, cols, vals = [], [], []
        for r, t, inv_den in groups:
            for j in range(r.shape[0]):
                for m in range(r.shape[0]):
                    rows.append(r[j])
                    cols.append(r[m])
                    vals.append(t[j] * t[m] * inv_den)
        return sparse.coo_array(
            (
                np.concatenate(vals),
                (np.concatenate(rows).astype(np.intp), np.concatenate(cols).astype(np.intp)),
            ),
            shape=(k, k),
        ).tocsr()
    if operator == "samples":
        groups = list(groups)

        def cmul(v: np.ndarray) -> np.ndarray:
            out = np.zeros(k)
            for r, t, inv_den in groups:
                s = (t[:, None] * v[r]).sum(axis=0) * inv_den  # a_i . v / den_i
                for j in range(r.shape[0]):
                    out += np.bincount(r[j], t[j] * s, minlength=k)
            return out

        return cmul
    raise CalibrationError(f"operator must be 'auto', 'dense', 'sparse' or 'samples', got {operator!r}")


def _perron_vector(
    step: Callable[[np.ndarray], np.ndarray], similarity: np.ndarray, f0: np.ndarray
) -> tuple[np.ndarray | None, int]:
    """Fixed point of Robertson's update ``f <- B f``, ``B = N^-1 C W``, by symmetric Lanczos.

    With all weights positive, ``B`` is similar to the symmetric positive semi-definite
    ``A = D C D``, ``D = (W / N)^(1/2)``: ``S B S^-1 = A`` for ``S = (N W)^(1/2)``
    (``similarity``). So ``B``'s dominant eigenvector is ``S^-1 u`` with ``u`` that of ``A``,
    which ARPACK's Lanczos finds in far fewer products than the power iteration. ``step`` is
    ``f -> B f``. Returns ``(None, products)`` if Lanczos fails.
    """
    n = similarity.size
    if n < 3:
        return None, 0
    calls = 0

    def matvec(u: np.ndarray) -> np.ndarray:
        nonlocal calls
        calls += 1
        return similarity * step(np.ravel(u) / similarity)

    a = sparse_linalg.LinearOperator((n, n), matvec=matvec, dtype=np.float64)
    try:
        _, vectors = sparse_linalg.eigsh(
            a,
            k=1,
            which="LA",
            v0=similarity * np.maximum(f0, 1e-12),
            tol=1e-8,
            maxiter=max(1000, 20 * n),
        )
    except (sparse_linalg.ArpackNoConvergence, sparse_linalg.ArpackError):
        return None, calls
    u = vectors[:, 0]
    u = u if u.sum() >= 0 else -u
    if np.any(u < -1e-9 * np.abs(u).max()):
        return None, calls
    return np.maximum(u, 0.0) / similarity, calls


def _checked_series(
    raw: xr.Dataset | xr.DataArray, bit_depth: int | None, where: str
) -> tuple[xr.DataArray, xr.DataArray, int]:
    """``(counts, exposure_time, bit depth)`` of :func:`recover_oecf`'s exposure series,
    checked: dims, integer values, the bit depth, at least two exposures with strictly
    increasing times (a warning for a geometric bracket).

    Raises
    ------
    SchemaError
        Missing dims or coords, non-integer data, an unknown bit depth.
    CalibrationError
        Fewer than two exposures, exposure times not strictly increasing.
    """
    counts = counts_array(raw)
    if "exposure_time" not in counts.coords:
        raise SchemaError(
            f"{where} has no exposure_time coord",
            [
                Problem(
                    f"{where}:exposure_time",
                    "a coord over exposure or (image, exposure) [s]",
                    f"coords {sorted(map(str, counts.coords))}",
                )
            ],
        )
    allowed = {"image", "exposure", "y", "x", "channel"}
    if not {"exposure", "y", "x"} <= set(counts.dims) or not set(counts.dims) <= allowed:
        raise SchemaError(
            f"{where} has the wrong dims",
            [
                Problem(
                    where, "dims exposure, y, x plus optional image and channel", f"dims {counts.dims}"
                )
            ],
        )
    check_integer(counts, where)
    depth = check_bit_depth(
        counts.attrs.get("bit_depth") if bit_depth is None else bit_depth,
        where=f"{where}.attrs['bit_depth']",
    )
    times = counts["exposure_time"]
    if not set(times.dims) <= {"image", "exposure"} or "exposure" not in times.dims:
        raise SchemaError(
            f"{where}: exposure_time has the wrong dims",
            [
                Problem(
                    f"{where}:exposure_time",
                    "dims (exposure,) or (image, exposure)",
                    f"dims {times.dims}",
                )
            ],
        )
    if counts.sizes["exposure"] < 2:
        raise CalibrationError(
            f"{where}: an exposure series needs at least 2 exposures, got {counts.sizes['exposure']}"
        )
    check_exposure_times(times, "exposure", where)
    warn_if_geometric(times, "exposure", where)
    return counts, times, depth


def recover_oecf(
    raw: xr.Dataset | xr.DataArray,
    *,
    bit_depth: int | None = None,
    black_level: int = 0,
    saturation: int | None = None,
    weighting: Weighting = "gaussian",
    tolerance: float = 1e-6,
    max_iterations: int = 5000,
    monotone: bool = True,
    max_bins: int = 1024,
    max_pixels: int | None = None,
    seed: int = 0,
    solver: Solver = "lanczos",
    operator: Operator = "auto",
    smooth: int | None = None,
    low_end: bool = False,
    frames_checked: bool = False,
) -> xr.Dataset:
    """Recover the camera response per camera and channel from exposure series (Robertson).

    Parameters
    ----------
    raw
        Group ``raw/rgb`` (variable ``counts`` (image, exposure, y, x, channel) uint16 [DN],
        coord ``exposure_time`` (image, exposure) [s], per-image ``camera``), or any integer
        DataArray/Dataset with dims ``exposure, y, x`` plus optional ``image`` and ``channel``
        and an ``exposure_time`` coord over ``exposure`` or ``(image, exposure)``.
        Monochrome series simply have no ``channel`` dim.
    bit_depth
        ADC bit depth 8..16; default ``attrs["bit_depth"]``.
    black_level
        Codes ``<= black_level`` are under-exposed and get weight 0 (e.g. the ADC offset plus
        a few noise sigmas).
    saturation
        Codes ``>= saturation`` are saturated and get weight 0; default ``2**bit_depth - 1``.
    weighting
        Weighting function, see :func:`~.weighting_function`.
    tolerance, max_iterations, monotone, max_bins, solver, operator, smooth, low_end
        See :func:`robertson_response`.
    max_pixels
        Use at most this many pixel positions (a reproducible random subset, the same for
        every exposure, image and channel); default all.
    seed
        Seed of that subset.
    frames_checked
        The caller has refused frames entirely saturated or dark already (on the same
        values): skip that check here.

    Returns
    -------
    xarray.Dataset
        Variable ``response`` with dims ``([camera,] [channel,] code)``: ``camera`` when the
        input has a per-image ``camera`` coord, ``channel`` when it has channels. Coord
        ``code`` = 0 .. 2**bit_depth - 1 [DN]; coord ``samples`` (samples per code, 0 where
        the value is interpolated). Attrs: ``units="1"``, ``bit_depth``, ``method``,
        ``iterations`` (the most over cameras and channels), ``converged`` (all),
        ``tolerance``, ``weighting``, ``black_level``, ``saturation``, ``mid_code``,
        ``normalisation``.

    Raises
    ------
    SchemaError
        Missing dims/coords, non-integer data, unknown bit depth.
    CalibrationError
        Fewer than two exposures, exposure times not strictly increasing (unsorted or
        duplicate), values beyond the bit depth, a frame entirely saturated or entirely dark.

    Notes
    -----
    Each camera and channel is solved independently; all images of one camera pool their
    pixels (exposure times may differ per image). Normalisation: ``response(mid) = 1`` with
    ``mid = (2**bit_depth - 1) / 2``. Domain: integer codes. Range: relative exposure,
    non-negative, non-decreasing when ``monotone``.

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003, section 3.
    .. [2] Fast Capture of Spectral Image Series, section 4.
    """
    where = "recover_oecf: counts"
    counts, times, depth = _checked_series(raw, bit_depth, where)
    n_codes = 2**depth
    saturation = n_codes - 1 if saturation is None else int(saturation)
    weights = weighting_function(
        np.arange(n_codes), black_level=black_level, saturation=saturation, kind=weighting
    )
    frame_dims = tuple(d for d in ("image", "exposure", "channel") if d in counts.dims)
    if not frames_checked:
        check_frames(
            counts,
            frame_dims,
            black_level=black_level,
            saturation=saturation,
            max_code=n_codes - 1,
            where=where,
            times=times,
        )

    if "image" not in counts.dims:
        counts = counts.expand_dims("image")
    if "image" not in times.dims:
        times = times.expand_dims(image=counts.sizes["image"])
    time_values = np.asarray(times.transpose("image", "exposure").values, dtype=np.float64)
    has_channel = "channel" in counts.dims
    if not has_channel:
        counts = counts.expand_dims("channel", axis=-1)
    counts = counts.transpose("image", "exposure", "y", "x", "channel")
    ny, nx = counts.sizes["y"], counts.sizes["x"]
    pick = None
    if max_pixels is not None and ny * nx > max_pixels:
        rng = np.random.default_rng(seed)
        pick = np.sort(rng.choice(ny * nx, size=int(max_pixels), replace=False))

    cameras = None
    if "camera" in counts.coords and counts["camera"].dims == ("image",):
        cameras = np.unique(counts["camera"].values)

    results: dict[tuple, RobertsonResult] = {}
    camera_list = list(cameras) if cameras is not None else [None]
    for camera in camera_list:
        if camera is None:
            images = np.arange(counts.sizes["image"])
        else:
            images = np.flatnonzero(counts["camera"].values == camera)
        # (G, E, y, x, C); every image: the caller's array itself, not a copy of it
        block = np.asarray((counts if camera is None else counts.isel(image=images)).values)
        block = block.reshape(block.shape[0], block.shape[1], ny * nx, block.shape[-1])
        if pick is not None:
            block = block[:, :, pick]
        block = np.ascontiguousarray(np.moveaxis(block, -1, 0))  # (C, G, E, P)
        for c in range(block.shape[0]):
            results[(camera, c)] = robertson_response(
                block[c],
                time_values[images],
                n_codes=n_codes,
                weights=weights,
                tolerance=tolerance,
                max_iterations=max_iterations,
                monotone=monotone,
                max_bins=max_bins,
                solver=solver,
                operator=operator,
                smooth=smooth,
                low_end=low_end,
            )

    n_channels = counts.sizes["channel"]
    values = np.stack(
        [np.stack([results[(cam, c)].response for c in range(n_channels)]) for cam in camera_list]
    )
    samples = np.stack(
        [np.stack([results[(cam, c)].samples for c in range(n_channels)]) for cam in camera_list]
    )
    dims: tuple[str, ...] = ("camera", "channel")
    coords: dict[Hashable, object] = {}
    if cameras is not None:
        coords["camera"] = ("camera", cameras)
    else:
        values, samples, dims = values[0], samples[0], dims[1:]
    if has_channel:
        if "channel" in counts.coords:
            coords["channel"] = ("channel", counts["channel"].values)
    else:
        values, samples, dims = values[..., 0, :], samples[..., 0, :], dims[:-1]
    attrs = {
        "bit_depth": depth,
        "method": "robertson2003",
        "iterations": int(max(r.iterations for r in results.values())),
        "converged": bool(all(r.converged for r in results.values())),
        "tolerance": float(tolerance),
        "weighting": weighting,
        "black_level": int(black_level),
        "saturation": int(saturation),
        "mid_code": (n_codes - 1) / 2.0,
        "normalisation": "response(mid_code) = 1",
        "smooth": -1 if smooth is None else int(smooth),
    }
    response = response_dataarray(
        values, samples, dims, coords, np.arange(n_codes, dtype=np.int32), attrs
    )
    return xr.Dataset({"response": response}, attrs={"bit_depth": depth})


def with_target_series(
    data: xr.Dataset, targets: list[xr.Dataset], camera: int, black_level: int, saturation: int
) -> xr.Dataset:
    """One camera's raw/rgb series plus its exposure series of the calibration targets.

    The white reference and the colour checker are photographed over a longer exposure range
    (9 times against raw/rgb's few) at every level of the chart's patches, so they reach the
    codes the scene seldom does (a sensor's shoulder in a channel the scene is dim in). Each
    target series is cut into windows of raw/rgb's exposure count (every second start), left
    out where a frame is entirely saturated or entirely at or below ``black_level``; each
    window is one more image of ``camera``.
    """
    counts = data["counts"].transpose("image", "exposure", "y", "x", "channel")
    n_exp = counts.sizes["exposure"]
    frames, times = [np.asarray(counts.values)], [np.asarray(data["exposure_time"].values)]
    for target in targets:
        if "camera" not in target["rgb_counts"].dims or camera not in target["camera"].values:
            continue
        pos = [int(v) for v in target["camera"].values].index(camera)
        series = np.asarray(
            target["rgb_counts"].isel(camera=pos).transpose("rgb_exposure", "y", "x", "channel").values
        )
        series_times = np.asarray(target["rgb_exposure_time"].isel(camera=pos).values, float)
        if series.shape[1:] != counts.shape[2:]:
            continue
        for start in range(0, series.shape[0] - n_exp + 1, 2):
            window = series[start : start + n_exp].reshape(n_exp, -1, series.shape[-1])
            if (window.min(1) >= saturation).any() or (window.max(1) <= black_level).any():
                continue
            frames.append(series[None, start : start + n_exp])
            times.append(series_times[None, start : start + n_exp])
    if len(frames) == 1:
        return data
    stacked = np.concatenate(frames)
    return xr.Dataset(
        {"counts": (("image", "exposure", "y", "x", "channel"), stacked)},
        coords={
            "exposure_time": (("image", "exposure"), np.concatenate(times)),
            "camera": ("image", np.full(stacked.shape[0], camera)),
            "channel": counts["channel"].values,
        },
        attrs=data.attrs,
    )


SMOOTH_RGB = 16
"""Spline coefficients of an RGB camera's response (:func:`recover_rgb_oecf`).

A scene of few materials and the uniform calibration targets crowd the samples into a few
exposures; Robertson's per-code mean of the exposure given the code (a regression of
exposure on code, with noise in the code) follows that crowding, and the response gets
ripples of a few percent from code to code, which the HDR merge turns into a level-dependent
radiance error. The response of a real sensor is smooth; a spline of 16 coefficients (knots
at the samples' quantiles) keeps its toe and shoulder and drops the ripples
(``benchmarks/calibration_oracle.py``).
"""


def recover_rgb_oecf(
    raw_rgb: xr.Dataset,
    colour_checker: xr.Dataset | None = None,
    white_reference: xr.Dataset | None = None,
    *,
    calibration_targets: Annotated[
        bool,
        Field(
            description="add each camera's exposure series of the colour checker and the white "
            "reference to its raw/rgb series (they reach codes the scene seldom does)"
        ),
    ] = True,
    per_camera: Annotated[
        bool,
        Field(
            description="one response per RGB camera (True) or one "
            "response per channel pooled over all cameras "
            "(False, with a warning when the cameras' own responses differ)"
        ),
    ] = True,
    black_level: Annotated[
        int | None,
        Field(
            ge=0,
            description="codes at or below it get "
            "weight 0 [DN]; None: per camera, capture.toml's rgb.black_level_dn plus 3, else "
            "the 0.1 % quantile of the camera's shortest exposures plus 3",
        ),
    ] = None,
    weighting: Annotated[str, Choices(WEIGHTING_FUNCTIONS, "weighting function")] = "gaussian",
    tolerance: Annotated[
        float,
        Field(
            gt=0,
            lt=1e-2,
            description="convergence: largest relative change of the response per Robertson update",
        ),
    ] = 1e-6,
    max_pixels: Annotated[
        int | None,
        Field(
            ge=100, description="pixel positions used per image (reproducible random subset); None: all"
        ),
    ] = 200_000,
    smooth: Annotated[
        int | None,
        Field(
            ge=6,
            le=256,
            description="the response as a cubic spline of this many coefficients, Robertson's "
            "maximum-likelihood solution over that space (None: one unknown per code bin)",
        ),
    ] = SMOOTH_RGB,
    low_end: Annotated[
        bool,
        Field(
            description="the codes just above the black level, where the weights are all but "
            "zero, from the reverse regression of the samples (a toe the smooth response cannot "
            "follow)"
        ),
    ] = True,
    log_spline: Annotated[
        bool,
        Field(
            description="smooth each channel's response to a cubic spline in the log code, of "
            "the number of coefficients that best predicts the camera's own exposure series' "
            "codes (or keep the recovered one where it predicts them best)"
        ),
    ] = True,
) -> xr.Dataset:
    """RGB camera response per channel (Robertson 2003) from the raw/rgb exposure series.

    The raw/rgb images (textured sample, many light directions, exposure series with unequal
    ratios) cover the whole code range densely; the uniform white reference only gives one
    cluster of codes per exposure, so raw/rgb is used (the colour checker's series gives a
    response many times further from the truth on the demo run).

    Parameters
    ----------
    raw_rgb
        Group ``raw/rgb``.
    colour_checker, white_reference
        Groups ``raw/colour_checker`` and ``raw/white_reference``: each camera's exposure
        series of them join its raw/rgb series (:func:`with_target_series`) unless
        ``calibration_targets`` is false.
    calibration_targets
        Whether they do.
    per_camera
        Recover one response per camera (the default: cameras of other models respond
        otherwise); else pool all cameras and copy the response to every camera, with a
        warning naming the largest difference of a camera's own response from the pooled one
        when it exceeds :data:`POOLING_TOLERANCE`.
    black_level
        Under-exposed codes (weight 0); default per camera (:func:`camera_black_levels`):
        ``rgb.black_level_dn`` of ``capture.toml`` plus 3 DN, else the 0.1 % quantile of the
        camera's shortest exposures plus 3 DN (the ADC offset plus noise).
    weighting
        A key of :data:`~spectralize.nodes.calibration.oecf.weighting.WEIGHTING_FUNCTIONS`.
    smooth
        Coefficients of the response's cubic spline (:data:`SMOOTH_RGB`), see
        :func:`robertson_response`; ``None``: one unknown per code bin.
    low_end
        The codes just above the black level from the reverse regression
        (:func:`~.low_end.low_end_response`), see :func:`robertson_response`: a camera whose
        response has a strong toe keeps it.
    log_spline
        Each camera's response smoothed over the codes its series reaches by
        :func:`~.log_spline.chosen_log_spline_response` (the spline's coefficients per channel
        chosen on the series itself, :func:`log_spline_smoothed`): the code-to-code ripple a
        crowded series leaves goes, for the scene's HDR and the chart's patch means alike.
    tolerance, max_pixels
        See :func:`recover_oecf`; ``max_pixels`` is lowered for a camera with so many
        images that images x positions exceed :data:`MAX_SAMPLES`.

    Notes
    -----
    raw/rgb is read once: at most :data:`MAX_IMAGES` images per camera
    (:func:`rgb_oecf_sample`, evenly spread over the camera's images in image order, so
    deterministic), loaded camera by camera; the refusals (:func:`rgb_oecf_refusals`) and the
    recovery run on those values. A run with fewer images per camera uses them all.

    Returns
    -------
    xarray.Dataset
        Group ``calibration/oecf_rgb``: ``response`` (camera, channel, code) float64
        [1], relative exposure per code normalised to 1 at the mid code; ``samples``
        (camera, channel, code); ``black_level`` (camera) int [DN], each camera's own
        black level, which the HDR merge weights that camera's images with;
        ``white_level`` (camera) int [DN], the code the camera's raw values clip at, and
        ``saturation`` (camera) int [DN], the first code taken as saturated (the white level
        less its noise; the top code when the white level is the top code), which the fit,
        the targets' series and the HDR merge use (:func:`~.white_level.camera_white_levels`:
        capture.toml's ``rgb.white_level_dn``, else a pile-up of codes below the top code in
        the camera's longest exposures). Attrs ``bit_depth``, ``black_level`` (the lowest
        camera's), ``black_levels`` (per camera, as the variable), ``saturation`` (the lowest
        camera's), ``white_level_source`` (per camera: ``"declared"``, ``"found"`` or
        ``"top code"``), ``weighting``, ``per_camera``, ``converged``, ``iterations``,
        ``sampled_images``.

    Raises
    ------
    SchemaError, CalibrationError
        See :func:`recover_oecf` (an invalid bit depth, unsorted or duplicate exposure
        times, all-saturated or all-dark frames).

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003.
    .. [2] Fast Capture of Spectral Image Series, section 4.
    """
    # one read of raw/rgb: the sampled images (rgb_oecf_sample), camera by camera, in memory;
    # the refusals and the recovery both run on these values
    images = rgb_oecf_sample(raw_rgb)
    loaded = _load_sample(raw_rgb, images)
    given = [t for t in (colour_checker, white_reference) if t is not None]
    refusals, whites = _rgb_oecf_refusals(
        raw_rgb, black_level=black_level, sample=loaded, images=images, targets=given
    )
    raise_first(refusals)
    depth = int(raw_rgb.attrs["bit_depth"])
    cameras = np.asarray(loaded["camera"].values)
    levels = camera_black_levels(loaded) if black_level is None else {}
    levels = {int(c): levels.get(int(c), black_level) for c in np.unique(cameras)}
    data = loaded[["counts"]].assign_attrs(bit_depth=depth)
    options = {
        "weighting": weighting,
        "tolerance": tolerance,
        "max_pixels": max_pixels,
        "smooth": smooth,
        "low_end": low_end,
        "frames_checked": True,
    }
    targets = given if calibration_targets else []
    own = {}  # one response per camera, each with its own levels (and target series)
    for c, level in levels.items():
        saturation = whites[c].saturation
        series = with_target_series(
            data.isel(image=np.flatnonzero(cameras == c)), targets, c, level, saturation
        )
        own[c] = recover_oecf(
            series,
            black_level=level,
            saturation=saturation,
            **{**options, "max_pixels": _capped(series, max_pixels)},
        )
        if log_spline:
            own[c] = log_spline_smoothed(own[c], series, level, saturation, weighting)
    black_level = min(levels.values())
    if per_camera:
        result = xr.concat([own[c] for c in levels], dim="camera", combine_attrs="override")
        result["response"].attrs["iterations"] = max(
            int(r["response"].attrs.get("iterations", 0)) for r in own.values()
        )
        result["response"].attrs["converged"] = all(
            bool(r["response"].attrs.get("converged", True)) for r in own.values()
        )
        if log_spline:
            result["response"].attrs["log_spline_knots"] = [
                k for c in levels for k in own[c]["response"].attrs.get("log_spline_knots", [])
            ]
    else:
        pooled = data.drop_vars("camera")  # the sample, in memory
        result = recover_oecf(
            pooled,
            black_level=black_level,
            saturation=min(w.saturation for w in whites.values()),
            **{**options, "max_pixels": _capped(pooled, max_pixels)},
        )
        _warn_pooled(own, result, "recover_rgb_oecf: raw/rgb")
        if log_spline:
            result = log_spline_smoothed(
                result, pooled, black_level, min(w.saturation for w in whites.values()), weighting
            )
    response = result["response"]
    samples = response["samples"].drop_vars("samples", errors="ignore")
    response = response.drop_vars("samples")
    if not per_camera:
        unique = np.unique(cameras)
        response = response.expand_dims(camera=unique)
        samples = samples.expand_dims(camera=unique)
    response = response.transpose("camera", "channel", "code")
    samples = samples.transpose("camera", "channel", "code")
    attrs = dict(response.attrs)
    per_camera_black = xr.DataArray(
        np.array([int(levels[int(c)]) for c in response["camera"].values], dtype=np.int64),
        dims="camera",
        attrs={
            "units": "DN",
            "long_name": "black level: codes at or below it are under-exposed (weight 0)",
        },
    )
    order = [int(c) for c in response["camera"].values]
    out = xr.Dataset(
        {
            "response": response.assign_attrs(attrs),
            "samples": samples.assign_attrs(units="1", long_name="samples per code (0: interpolated)"),
            "black_level": per_camera_black,
            **white_level_variables(whites, order),
        },
        attrs={
            "bit_depth": depth,
            "black_level": int(black_level),
            "saturation": min(whites[c].saturation for c in order),
            "white_level_source": [whites[c].source for c in order],
            "weighting": weighting,
            "per_camera": bool(per_camera),
            "black_levels": [int(levels[int(c)]) for c in response["camera"].values],
            "converged": bool(attrs.get("converged", True)),
            "iterations": int(attrs.get("iterations", 0)),
            "source": "raw/rgb",
            "sampled_images": int(images.size),
        },
    )
    out["camera"].attrs.update(long_name="RGB camera index")
    return out


LOG_SPLINE_PIXELS = 4000
"""Pixel positions per image whose samples score :func:`log_spline_smoothed`'s candidates."""


def log_spline_smoothed(
    recovered: xr.Dataset, series: xr.Dataset, black_level: int, saturation: int, weighting: Weighting
) -> xr.Dataset:
    """:func:`recover_oecf`'s result for one camera (or the pooled cameras), its response
    smoothed by :func:`~.log_spline.chosen_log_spline_response` over the codes ``series``
    reaches, the coefficients per channel chosen on ``series`` (at most
    :data:`LOG_SPLINE_PIXELS` positions per image, a reproducible subset).

    Parameters
    ----------
    recovered
        :func:`recover_oecf`'s result: ``response`` ([camera,] channel, code).
    series
        The exposure series it was recovered from: ``counts`` (image, exposure, y, x, channel)
        and ``exposure_time`` ((image,) exposure) [s].
    black_level, saturation
        The levels it was recovered with [DN].
    weighting
        Its weighting function.

    Returns
    -------
    xarray.Dataset
        ``recovered`` with the smoothed ``response``; attr ``log_spline_knots`` of the
        response: the coefficients chosen per channel (0: the recovered response kept).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    counts = series["counts"].transpose("image", "exposure", "y", "x", "channel")
    values = np.asarray(counts.values)
    # image by image: no temporaries the size of the whole series
    spans = [r for r in (codes_reached(v, black_level, saturation) for v in values) if r]
    if not spans:
        return recovered
    reached = (min(r[0] for r in spans), max(r[1] for r in spans))
    height, width = values.shape[2], values.shape[3]
    pick = np.arange(height * width)
    if pick.size > LOG_SPLINE_PIXELS:
        pick = np.sort(np.random.default_rng(0).choice(pick.size, LOG_SPLINE_PIXELS, replace=False))
    flat = values[:, :, pick // width, pick % width, :]  # (image, exposure, pixel, channel)
    times = series["exposure_time"]
    if "image" not in times.dims:
        times = times.expand_dims(image=flat.shape[0])
    n_codes = recovered.sizes["code"]
    weights = weighting_function(
        np.arange(n_codes), black_level=black_level, saturation=saturation, kind=weighting
    )
    response = recovered["response"]
    order = [d for d in response.dims if d not in ("channel", "code")] + ["channel", "code"]
    table = np.array(response.transpose(*order).values, dtype=np.float64).reshape(
        -1, response.sizes["channel"], n_codes
    )
    knots = []
    for k in range(table.shape[0]):
        table[k], chosen = chosen_log_spline_response(
            table[k],
            black_level,
            reached,
            flat.astype(np.intp),
            np.asarray(times.transpose("image", "exposure").values, dtype=np.float64),
            weights,
        )
        knots.extend(chosen)
    out = recovered.copy()
    out["response"] = response.transpose(*order).copy(
        data=table.reshape(response.transpose(*order).shape)
    )
    out["response"] = out["response"].transpose(*response.dims)
    out["response"].attrs["log_spline_knots"] = knots
    return out


def camera_black_levels(raw_rgb: xr.Dataset) -> dict[int, int]:
    """``{camera: black level}``: ``rgb.black_level_dn`` of ``capture.toml`` plus 3 DN where
    raw/rgb's attrs carry it (``black_level_dn``, -1: not given), else
    :func:`default_black_level` of the camera's own images (cameras of other models have
    other black offsets)."""
    cameras = np.asarray(raw_rgb["camera"].values)
    declared = list(raw_rgb.attrs.get("black_level_dn") or [])
    out = {}
    for c in np.unique(cameras):
        c = int(c)
        if c < len(declared) and int(declared[c]) >= 0:
            out[c] = int(declared[c]) + 3
        else:
            out[c] = default_black_level(raw_rgb.isel(image=np.flatnonzero(cameras == c)))
    return out


MAX_SAMPLES = 2_000_000
"""Pixel positions (over all images of a series) one response is recovered from at most:
a run of more images than ``MAX_SAMPLES / pixels per image`` per camera (a full run of tiny
frames: 4,752 images of 1,024 px) uses fewer positions per image, so the recovery's time and
memory stop growing with the image count. Below, nothing changes."""


def _capped(series: xr.Dataset, max_pixels: int | None) -> int | None:
    """``max_pixels`` per image, lowered so that images x positions <= :data:`MAX_SAMPLES`."""
    n_image = series.sizes.get("image", 1)
    per_image = series.sizes["y"] * series.sizes["x"]
    if max_pixels is not None:
        per_image = min(per_image, max_pixels)
    if n_image * per_image <= MAX_SAMPLES:
        return max_pixels
    return max(100, MAX_SAMPLES // n_image)


POOLING_TOLERANCE = 0.02
"""Largest relative difference between cameras' own responses that pooling passes silently."""


def _warn_pooled(own: dict[int, xr.Dataset], pooled: xr.Dataset, where: str) -> float:
    """Warn when a camera's own response differs from the pooled one by more than
    :data:`POOLING_TOLERANCE` (relative, at the codes both have samples at); return the
    largest difference."""
    import warnings

    ref = np.asarray(pooled["response"].values, float)
    seen_ref = np.asarray(pooled["response"]["samples"].values) >= 10  # codes both measured well
    worst, who = 0.0, None
    for c, result in own.items():
        mine = np.asarray(result["response"].isel(camera=0).values, float)
        seen = (
            (np.asarray(result["response"]["samples"].isel(camera=0).values) >= 10)
            & seen_ref
            & (ref > 0)
        )
        if seen.any():
            diff = float(np.nanmax(np.abs(mine[seen] / ref[seen] - 1.0)))
            if diff > worst:
                worst, who = diff, c
    if worst > POOLING_TOLERANCE:
        warnings.warn(
            f"{where}: per_camera=False pools cameras whose own responses differ from the "
            f"pooled one by up to {100 * worst:.1f} % (camera {who}): their images are merged "
            "through a response that is not theirs. Use per_camera=True (the default).",
            stacklevel=3,
        )
    return worst


def default_black_level(raw_rgb: xr.Dataset) -> int:
    """The under-exposed code level taken from the data: the shortest exposures' floor.

    ``black_level = q + 3`` with ``q`` the 0.1 % quantile of the codes of the shortest
    exposure (of at most about 8 images spread over the run): the ADC offset plus noise.

    Raises
    ------
    CalibrationError
        When that level is not below saturation (the shortest exposures are almost
        entirely saturated), naming the quantile and the exposure time.
    """
    where = "recover_rgb_oecf: raw/rgb"
    saturation = (
        2 ** check_bit_depth(raw_rgb.attrs.get("bit_depth"), where="raw/rgb.attrs['bit_depth']") - 1
    )
    counts, times = raw_rgb["counts"], raw_rgb["exposure_time"]
    shortest = counts.isel(exposure=0)
    if shortest.sizes["image"] > 8:
        shortest = shortest.isel(image=slice(0, None, shortest.sizes["image"] // 8))
    floor = int(np.quantile(np.asarray(shortest.values), 0.001))
    black_level = floor + 3
    if black_level >= saturation:
        raise CalibrationError(
            f"{where}:counts: the shortest exposures are (almost) entirely saturated: their "
            f"0.1 % quantile is {floor} DN, so the default black_level ({black_level}) is not "
            f"below saturation ({saturation}). Use shorter exposures, or set black_level",
            [
                Problem(
                    f"{where}:counts[exposure=0]",
                    f"a 0.1 % quantile below saturation - 3 = {saturation - 3} DN",
                    f"{floor} DN (exposure_time {float(times.isel(exposure=0).min()):g} s)",
                )
            ],
        )
    return black_level


MAX_IMAGES = 512
"""Images per camera :func:`recover_rgb_oecf` reads at most (:func:`rgb_oecf_sample`).

Robertson's estimate needs every code observed often, not every image: 512 images of a
camera, spread over the run's light directions and rotations, give a full run of 32 x 32 px
frames about 2 million samples per channel (4 exposures), some 500 per code at 12 bits. A run
with more images per camera (a full run: 4,752) reads this many instead of all, so the
node's read and time stop growing with the image count."""


def rgb_oecf_sample(raw_rgb: xr.Dataset, max_images: int = MAX_IMAGES) -> np.ndarray:
    """The raw/rgb images :func:`recover_rgb_oecf` reads: per camera at most ``max_images``.

    Deterministic: of a camera's ``n`` images (in image order) those at the positions
    ``round(linspace(0, n - 1, max_images))``, an even spread over the run (its rotations
    and light directions); all of them when ``n <= max_images``.

    Returns
    -------
    numpy.ndarray
        Sorted image positions (int).
    """
    cameras = np.asarray(raw_rgb["camera"].values)
    picked = []
    for c in np.unique(cameras):
        own = np.flatnonzero(cameras == c)
        if own.size > max_images:
            own = own[np.unique(np.round(np.linspace(0, own.size - 1, max_images)).astype(np.intp))]
        picked.append(own)
    return np.sort(np.concatenate(picked)) if picked else np.zeros(0, dtype=np.intp)


def _load_sample(raw_rgb: xr.Dataset, images: np.ndarray, batch: int = 256) -> xr.Dataset:
    """raw/rgb's ``counts`` of ``images`` in memory (one read, ``batch`` images per compute),
    with the coords the recovery uses (``exposure_time``, ``camera``, ``channel``) and the
    group's attrs. The other per-image coords are left out (a store's are chunked per image:
    loading them with the counts multiplies the tasks)."""
    counts = raw_rgb["counts"]
    image_axis = counts.get_axis_num("image")
    parts = [
        np.asarray(counts.isel(image=images[start : start + batch]).values)
        for start in range(0, len(images), batch)
    ]
    shape = list(counts.shape)
    shape[image_axis] = 0
    values = np.concatenate(parts, axis=image_axis) if parts else np.zeros(shape, counts.dtype)
    times = raw_rgb["exposure_time"]
    coords: dict[Hashable, object] = {
        "exposure_time": (times.dims, np.asarray(times.isel(image=images).values)),
        "camera": ("image", np.asarray(raw_rgb["camera"].values)[images]),
    }
    if "channel" in raw_rgb.coords:
        coords["channel"] = raw_rgb["channel"].values
    return xr.Dataset(
        {"counts": (counts.dims, values, counts.attrs)}, coords=coords, attrs=dict(raw_rgb.attrs)
    )


def rgb_oecf_refusals(
    raw_rgb: xr.Dataset,
    *,
    black_level: int | None = None,
    sample: xr.Dataset | None = None,
    images: np.ndarray | None = None,
    targets: Sequence[xr.Dataset] = (),
) -> list[SpectralizeError]:
    """What :func:`recover_rgb_oecf` refuses in raw/rgb before computing (its value check).

    The bit depth (8..16); exposure times positive, finite and strictly increasing per image
    (every image); and in the images the node reads (:func:`rgb_oecf_sample`): values within
    the bit depth; no frame entirely saturated (every value at or above its camera's
    saturation: its white level less its noise, :func:`~.white_level.camera_white_levels`,
    declared or found in the camera's longest exposures of raw/rgb and of the calibration
    ``targets``, as the node finds it); each camera's black level
    (:func:`camera_black_levels` when ``black_level`` is ``None``: from the data here, so
    ``validate --flow`` applies the threshold the node applies); no frame entirely dark
    (every value at or below its camera's black level). One pass over the sampled counts
    (none when ``sample``, those images already in memory, at the positions ``images`` of
    raw/rgb, is given). Errors name raw/rgb's positions.

    Returns
    -------
    list of SpectralizeError
        Each error the node would raise (empty: accepted).
    """
    return _rgb_oecf_refusals(
        raw_rgb, black_level=black_level, sample=sample, images=images, targets=targets
    )[0]


def _rgb_oecf_refusals(
    raw_rgb: xr.Dataset,
    *,
    black_level: int | None,
    sample: xr.Dataset | None,
    images: np.ndarray | None,
    targets: Sequence[xr.Dataset],
) -> tuple[list[SpectralizeError], dict[int, CameraWhiteLevel]]:
    """:func:`rgb_oecf_refusals` and the cameras' white levels it checked the frames with
    (empty where the values are beyond the bit depth), which the node then uses."""
    where = "recover_rgb_oecf: raw/rgb"
    depth = refused(
        lambda: check_bit_depth(raw_rgb.attrs.get("bit_depth"), where="raw/rgb.attrs['bit_depth']")
    )
    if depth:
        return depth, {}
    top = 2 ** int(raw_rgb.attrs["bit_depth"]) - 1
    times = raw_rgb["exposure_time"]
    found = refused(lambda: check_exposure_times(times.transpose(..., "exposure"), "exposure", where))
    if sample is None:
        images = rgb_oecf_sample(raw_rgb)
        sample = raw_rgb[["counts"]].isel(image=images)
    elif images is None:
        images = np.arange(sample.sizes["image"])
    counts = sample["counts"].transpose("image", ...)
    if counts.chunks is not None:  # reduced per block of images (a store's chunks: one image)
        counts = counts.chunk({"image": 256})
    frame_dims = [d for d in counts.dims if d in ("image", "exposure", "channel")]
    lo, hi, frame_min, frame_max = frame_extremes(
        counts, [d for d in counts.dims if d not in frame_dims]
    )
    n_image = raw_rgb.sizes["image"]
    if len(images) != n_image:  # at raw/rgb's positions (the errors name them); others pass
        full_min = np.zeros((n_image,) + frame_min.shape[1:], frame_min.dtype)
        full_max = np.full((n_image,) + frame_max.shape[1:], top, frame_max.dtype)
        full_min[images], full_max[images] = frame_min, frame_max
        frame_min, frame_max = full_min, full_max
    cameras = np.asarray(raw_rgb["camera"].values)
    shape = [1] * frame_max.ndim
    shape[0] = -1

    def frames(black: int, saturation: int, camera: int | Sequence[int] | None = None) -> None:
        other = True if camera is None else ~np.isin(cameras, camera).reshape(shape)
        raise_for_frames(
            lo,
            hi,
            (frame_min < saturation) | other,
            (frame_max > black) | other,
            frame_dims=frame_dims,
            black_level=black,
            saturation=saturation,
            max_code=top,
            where=f"{where}:counts",
            times=times,
        )

    # the values within the bit depth first; then each camera's saturated frames: they decide
    # the black level
    bright = refused(lambda: frames(-1, top + 1))
    if bright:
        return found + bright, {}
    whites = camera_white_levels(_in_memory(sample, raw_rgb), targets, int(raw_rgb.attrs["bit_depth"]))
    by_saturation: dict[int, list[int]] = {}  # cameras of one saturation checked together
    for camera in np.unique(cameras[images]).tolist():
        by_saturation.setdefault(whites[int(camera)].saturation, []).append(int(camera))
    for saturation, group in sorted(by_saturation.items(), reverse=True):
        bright += refused(lambda s=saturation, g=group: frames(-1, s, g))
    if bright:
        return found + bright[:1], whites
    levels: dict[int, int] = {}
    if black_level is None:
        found += refused(lambda: levels.update(camera_black_levels(_in_memory(sample, raw_rgb))))
    else:
        levels = {int(c): int(black_level) for c in np.unique(cameras[images])}
    for camera, level in levels.items():
        dark = refused(lambda c=camera, b=level: frames(b, top + 1, c))
        if dark:
            return found + dark, whites
    return found, whites


def _in_memory(sample: xr.Dataset, raw_rgb: xr.Dataset) -> xr.Dataset:
    """The sample with raw/rgb's attrs (black_level_dn, bit_depth); its counts loaded only
    where :func:`default_black_level` reads them (a few shortest exposures per camera)."""
    return sample.assign_attrs({**raw_rgb.attrs, **sample.attrs})
