"""OECF recovery: Robertson et al. (2003) and the paper's low-SNR extension (section 4).

Vocabulary (paper eq. 5): a pixel value is ``I = floor(f^-1(x t Q) + Delta_ADC + N_sigma)``,
clamped to the bit depth. ``f^-1`` is the OECF; its inverse ``f`` is the camera *response*:
it maps a pixel value (code, DN) to the relative exposure ``x t`` that produced it. This
module recovers ``f`` from exposure series and represents it as an :class:`xarray.DataArray`
over a ``code`` dim (the pixel value in DN) whose values are relative exposures
(units ``"1"``), normalised so that the response at the mid code is 1.

Two recoveries:

- :func:`recover_oecf`: Robertson's iteration on raw integer codes, per camera and channel,
  any bit depth 8..16, RGB or monochrome.
- :func:`recover_oecf_low_snr`: the paper's extension for the spectral camera, whose useful
  pixel values lie a few DN above the dark level: subtract the averaged dark frame (float,
  negative values kept), Gaussian-filter as in the reconstruction, stretch the small interval
  of filtered values to the full integer range, round, run Robertson, and map the response
  back to dark-subtracted pixel values. Its ``code`` coordinate is fractional DN above dark.

:func:`combine_responses` joins a low-SNR response to a full-range one, and
:func:`apply_response` linearises pixel values through any response (linear interpolation
between tabulated codes, linear extrapolation beyond them, so negative dark-subtracted values
stay negative instead of being clipped).

References
----------
M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic range
enhancement using multiple exposures", Journal of Electronic Imaging 12(2), 219-228, 2003.

Fast Capture of Spectral Image Series, section 4 ("Calibration") and eq. 5.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Hashable, Mapping
from dataclasses import dataclass
from typing import Literal

import dask
import numpy as np
import xarray as xr
from scipy import ndimage, sparse
from scipy.sparse import linalg as sparse_linalg

from spectralize.schemas import CalibrationError, SchemaError

__all__ = [
    "WEIGHTING_FUNCTIONS",
    "Weighting",
    "weighting_function",
    "RobertsonResult",
    "robertson_response",
    "recover_oecf",
    "recover_oecf_low_snr",
    "combine_responses",
    "apply_response",
    "response_at_codes",
    "isotonic_regression",
]

Weighting = Literal["gaussian", "hat", "uniform"]
Operator = Literal["auto", "dense", "sparse", "samples"]
Solver = Literal["lanczos", "power"]

#: Largest number of distinct codes for which the iteration uses a dense code-by-code matrix.
DENSE_MAX_CODES = 4096


# -- weighting functions ---------------------------------------------------------------------
def _gaussian(u: np.ndarray) -> np.ndarray:
    # Robertson et al. (1999/2003): exp(-4 (z - mid)^2 / mid^2), shifted and rescaled so that
    # it is exactly 0 at both ends of the valid interval and 1 at its middle.
    floor = math.exp(-4.0)
    return (np.exp(-4.0 * (2.0 * u - 1.0) ** 2) - floor) / (1.0 - floor)


def _hat(u: np.ndarray) -> np.ndarray:
    # Debevec & Malik (1997) triangle.
    return 1.0 - np.abs(2.0 * u - 1.0)


def _uniform(u: np.ndarray) -> np.ndarray:
    return np.ones_like(u)


#: Weighting functions of the normalised position ``u`` in the valid interval, ``u in (0, 1)``.
WEIGHTING_FUNCTIONS = {"gaussian": _gaussian, "hat": _hat, "uniform": _uniform}


def weighting_function(
    codes: np.ndarray, *, black_level: float, saturation: float, kind: Weighting = "gaussian"
) -> np.ndarray:
    """Certainty weight ``w(code)`` of pixel values for Robertson's estimator.

    Parameters
    ----------
    codes
        Pixel values [DN], any shape.
    black_level
        Codes at or below it are under-exposed (dark noise) and get weight 0.
    saturation
        Codes at or above it are saturated and get weight 0.
    kind
        ``"gaussian"``: Robertson's ``exp(-4 (z - c)^2 / h^2)`` with ``c`` the middle and
        ``h`` the half width of ``(black_level, saturation)``, shifted to be 0 at both ends;
        ``"hat"``: Debevec's triangle; ``"uniform"``: 1 inside the interval.

    Returns
    -------
    numpy.ndarray
        Weights in [0, 1], float64, the shape of ``codes``.

    Notes
    -----
    Domain: any real codes. Range: [0, 1]; exactly 0 outside the open interval
    ``(black_level, saturation)``.

    References
    ----------
    Robertson, Borman, Stevenson 2003, section 3 (weighting function).
    """
    if kind not in WEIGHTING_FUNCTIONS:
        raise CalibrationError(
            f"weighting {kind!r} is unknown; known: {', '.join(WEIGHTING_FUNCTIONS)}")
    if not saturation > black_level:
        raise CalibrationError(
            f"saturation ({saturation}) must be above black_level ({black_level})")
    codes = np.asarray(codes, dtype=np.float64)
    u = (codes - black_level) / (saturation - black_level)
    inside = (u > 0.0) & (u < 1.0)
    w = np.where(inside, WEIGHTING_FUNCTIONS[kind](np.clip(u, 0.0, 1.0)), 0.0)
    return np.clip(w, 0.0, 1.0)


# -- monotone regression and table helpers ----------------------------------------------------
def isotonic_regression(values: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Weighted least-squares non-decreasing fit (pool adjacent violators).

    Parameters
    ----------
    values
        1-D sequence.
    weights
        Positive weights (e.g. the number of samples behind each value); default 1.

    Returns
    -------
    numpy.ndarray
        The non-decreasing sequence closest to ``values`` in weighted least squares.
    """
    y = np.asarray(values, dtype=np.float64)
    w = np.ones_like(y) if weights is None else np.asarray(weights, dtype=np.float64)
    if y.ndim != 1 or w.shape != y.shape:
        raise ValueError(f"values and weights must be 1-D of one length, got {y.shape}, {w.shape}")
    if y.size == 0 or np.all(np.diff(y) >= 0):
        return y.copy()
    means: list[float] = []
    sums: list[float] = []
    lengths: list[int] = []
    for value, weight in zip(y.tolist(), w.tolist(), strict=True):
        means.append(value)
        sums.append(weight)
        lengths.append(1)
        while len(means) > 1 and means[-2] > means[-1]:
            total = sums[-2] + sums[-1]
            merged = (means[-2] * sums[-2] + means[-1] * sums[-1]) / total
            length = lengths[-2] + lengths[-1]
            del means[-1], sums[-1], lengths[-1]
            means[-1], sums[-1], lengths[-1] = merged, total, length
    return np.repeat(np.asarray(means), lengths)


def _fill_unobserved(known: np.ndarray, values: np.ndarray, n_codes: int,
                     tail: int = 8) -> np.ndarray:
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


def _lookup(values: np.ndarray, table: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Piecewise-linear ``table(values)`` on the increasing grid ``codes``; extrapolates.

    ``table`` has the grid on its last axis and broadcasts against ``values[..., None]``.
    """
    values = np.asarray(values, dtype=np.float64)
    table = np.asarray(table, dtype=np.float64)
    n = codes.size
    nd = max(values.ndim, table.ndim - 1)
    values = values.reshape((1,) * (nd - values.ndim) + values.shape)
    table = table.reshape((1,) * (nd + 1 - table.ndim) + table.shape)
    i = np.clip(np.searchsorted(codes, values, side="right"), 1, n - 1)
    c0 = codes[i - 1]
    frac = (values - c0) / (codes[i] - c0)
    f0 = np.take_along_axis(table, (i - 1)[..., None], axis=-1)[..., 0]
    f1 = np.take_along_axis(table, i[..., None], axis=-1)[..., 0]
    return f0 + frac * (f1 - f0)


# -- Robertson's iteration (numpy core) --------------------------------------------------------
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
            f"(exposure,) or (image, exposure); {shapes}")
    return codes, times


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
        ``w(code)`` for every code, shape ``(n_codes,)`` (see :func:`weighting_function`).
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
        by the samples per code, pool-adjacent-violators) before filling unobserved codes.
    max_bins
        At most this many response unknowns: for ``n_codes > max_bins`` (13..16 bit by
        default) codes are grouped into bins of ``ceil(n_codes / max_bins)`` consecutive
        codes, each bin is one unknown placed at its centre code, and the response at every
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

    Identifiability: if all exposure-time ratios are equal (a geometric bracket, or only
    two exposures) the data determine ``f`` only up to a factor periodic in log exposure
    with that ratio as period (Grossberg & Nayar 2003); only noise breaks the tie. Use
    exposure times with unequal ratios (e.g. 1, 3, 8, 25, 60).

    Domain: integer codes in ``[0, n_codes)``. Range: non-negative relative exposures,
    non-decreasing when ``monotone``.

    References
    ----------
    Robertson, Borman, Stevenson 2003, section 3 (iterative estimation, weighting).
    M. D. Grossberg, S. K. Nayar, "Determining the camera response from images: what is
    knowable?", IEEE TPAMI 25(11), 2003 (ambiguity of equal exposure ratios).
    """
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
    mid = (n_codes - 1) / 2.0 if mid_code is None else float(mid_code)

    # Bins of `width` consecutive codes (width 1: no binning). The saturated codes, above the
    # last code of non-zero weight, form one bin of their own: clamping collapses a wide range
    # of exposures onto them, which must not leak into the bins below.
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
    n_bins = first.size
    centres = (first + last) / 2.0
    bin_weights = np.where((weights[first] > 0) & (weights[last] > 0),
                           np.interp(centres, np.arange(n_codes), weights), 0.0)
    code_to_bin = np.minimum(np.arange(n_codes) // width, n_main)
    if saturation < n_codes:
        code_to_bin[saturation:] = n_main

    identity = width == 1 and saturation >= n_codes - 1
    if identity:                                             # bin of every sample (G, E, P)
        idx = codes if codes.dtype.itemsize < 8 else codes.astype(np.intp, copy=False)
    else:
        idx = code_to_bin[codes]
    code_weights = bin_weights[code_to_bin]
    den = np.zeros((codes.shape[0], codes.shape[2]))         # sum_j w(y_ij) t_j^2 per pixel
    for g in range(codes.shape[0]):
        for j in range(codes.shape[1]):
            den[g] += np.take(code_weights * times[g, j]**2, codes[g, j])
    valid = den > 0
    if not valid.any():
        raise CalibrationError(
            "no pixel has a single sample with non-zero weight: every sample is saturated or "
            "under-exposed; check the exposure times, black_level and saturation")
    # Pixels without a weighted sample are left out: 1/den = 0 removes them from every sum
    # (no copy of the samples); they are subtracted from the counts below.
    inv_den = np.divide(1.0, den, out=np.zeros_like(den), where=valid)
    per_bin = np.bincount(idx.ravel(), minlength=n_bins)
    samples = per_bin.copy() if identity else np.bincount(codes.ravel(), minlength=n_codes)
    g_out, p_out = np.nonzero(~valid)
    if g_out.size:
        left_out = idx[g_out, :, p_out].ravel()
        per_bin -= np.bincount(left_out, minlength=n_bins)
        samples -= np.bincount(codes[g_out, :, p_out].ravel() if not identity else left_out,
                               minlength=n_codes)
    observed = per_bin > 0
    obs_bins = np.flatnonzero(observed)
    obs_centres = centres[observed]
    counts = per_bin[observed].astype(np.float64)
    w_obs = bin_weights[observed]
    # The iteration runs on the observed bins of non-zero weight ("active"); samples of zero
    # weight enter it only through den. Bins of zero weight follow from the converged
    # response by one last update (in Robertson's update they never feed back).
    active = w_obs > 0
    n_active = int(active.sum())
    if n_active == 0:
        raise CalibrationError(
            "no code with non-zero weight was observed; check black_level and saturation")
    act_bins = obs_bins[active]
    groups = [(idx[g], times[g], inv_den[g]) for g in range(idx.shape[0]) if valid[g].any()]
    gram = _gram_operator(groups, n_bins, operator)
    a_counts = counts[active]
    a_weights = w_obs[active]
    a_centres = obs_centres[active]
    if callable(gram):                 # operator "samples": C v from the samples
        def wide(f: np.ndarray) -> np.ndarray:
            v = np.zeros(n_bins)
            v[act_bins] = a_weights * f
            return v

        def step(f: np.ndarray) -> np.ndarray:  # one Robertson update, both steps at once
            return gram(wide(f))[act_bins] / a_counts

        def last_update(f: np.ndarray) -> np.ndarray:
            return gram(wide(f))[obs_bins] / counts
    else:                              # C once: an update is one matrix-vector product
        c_active = gram[act_bins][:, act_bins]
        c_observed = gram[obs_bins][:, act_bins]

        def step(f: np.ndarray) -> np.ndarray:
            return c_active @ (a_weights * f) / a_counts

        def last_update(f: np.ndarray) -> np.ndarray:
            return c_observed @ (a_weights * f) / counts

    def normalise(f: np.ndarray, centres: np.ndarray = a_centres) -> np.ndarray:
        scale = np.interp(mid, centres, f)
        if not scale > 0:
            raise CalibrationError(
                f"the response at the mid code {mid} is {scale}: no usable signal around it")
        return f / scale

    f = normalise((a_centres + 0.5) / (mid + 0.5))
    iterations = 0
    if solver == "lanczos":
        start, matvecs = _perron_vector(step, np.sqrt(a_counts * a_weights), f)
        iterations += matvecs
        if start is not None:
            f = normalise(start)
    change = math.inf
    converged = False
    while iterations < max_iterations:
        new = normalise(step(f))
        iterations += 1
        change = float(np.max(np.abs(new - f) / np.maximum(np.abs(new), 1e-12)))
        f = new
        if change < tolerance:
            converged = True
            break

    # all observed bins: one last update (zero-weight bins included); the active bins keep
    # the converged values
    f = np.where(active, f[np.cumsum(active) - 1], last_update(f))
    f = normalise(f, obs_centres)
    if monotone:
        f = normalise(isotonic_regression(f, counts), obs_centres)
    main = obs_bins < n_main
    full = _fill_unobserved(obs_centres[main], f[main], n_codes)
    if saturation < n_codes and not main.all():
        full[saturation:] = np.maximum(f[~main][0], full[saturation - 1])
    return RobertsonResult(full, samples, iterations, converged, change)


def _gram_operator(groups: list[tuple[np.ndarray, np.ndarray, np.ndarray]], k: int,
                   operator: Operator) -> np.ndarray | sparse.csr_array | Callable:
    """``C[m, n] = sum_i (1/den_i) sum_{j,l} [y_ij=m][y_il=n] t_j t_l`` over bins ``0..k-1``.

    ``groups`` holds per image ``(bins (E, P) in 0..k-1, t (E,), 1/den (P,))``; pixels with
    ``1/den = 0`` contribute nothing. ``C`` is symmetric positive semi-definite (a sum of
    rank-one terms ``a_i a_i^T / den_i`` with ``a_i[m] = sum_j [y_ij=m] t_j``).

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
            upper += np.bincount(pairs.ravel(), ((t[j] * t[m])[:, None] * inv_den).ravel(),
                                 minlength=k * k)
            diagonal += np.bincount(r.ravel(), ((t * t)[:, None] * inv_den).ravel(),
                                    minlength=k)
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
            (np.concatenate([values, values, diagonal]),
             (np.concatenate([rows, cols, on]), np.concatenate([cols, rows, on]))),
            shape=(k, k))
    if operator == "sparse":
        rows, cols, vals = [], [], []
        for r, t, inv_den in groups:
            for j in range(r.shape[0]):
                for m in range(r.shape[0]):
                    rows.append(r[j])
                    cols.append(r[m])
                    vals.append(t[j] * t[m] * inv_den)
        return sparse.coo_array(
            (np.concatenate(vals),
             (np.concatenate(rows).astype(np.intp), np.concatenate(cols).astype(np.intp))),
            shape=(k, k)).tocsr()
    if operator == "samples":
        def cmul(v: np.ndarray) -> np.ndarray:
            out = np.zeros(k)
            for r, t, inv_den in groups:
                s = (t[:, None] * v[r]).sum(axis=0) * inv_den      # a_i . v / den_i
                for j in range(r.shape[0]):
                    out += np.bincount(r[j], t[j] * s, minlength=k)
            return out
        return cmul
    raise CalibrationError(
        f"operator must be 'auto', 'dense', 'sparse' or 'samples', got {operator!r}")


def _perron_vector(step: Callable[[np.ndarray], np.ndarray], similarity: np.ndarray,
                   f0: np.ndarray) -> tuple[np.ndarray | None, int]:
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
        _, vectors = sparse_linalg.eigsh(a, k=1, which="LA",
                                         v0=similarity * np.maximum(f0, 1e-12),
                                         tol=1e-8, maxiter=max(1000, 20 * n))
    except (sparse_linalg.ArpackNoConvergence, sparse_linalg.ArpackError):
        return None, calls
    u = vectors[:, 0]
    u = u if u.sum() >= 0 else -u
    if np.any(u < -1e-9 * np.abs(u).max()):
        return None, calls
    return np.maximum(u, 0.0) / similarity, calls


# -- validation helpers ---------------------------------------------------------------------
def _counts_array(data: xr.Dataset | xr.DataArray, name: str = "counts") -> xr.DataArray:
    if isinstance(data, xr.Dataset):
        if name not in data.data_vars:
            raise SchemaError(f"cannot use the exposure series: it has no variable {name!r}",
                              [f"variables found: {sorted(map(str, data.data_vars))}"])
        array = data[name]
        attrs = {**data.attrs, **array.attrs}
        return array.assign_attrs(attrs)
    return data


def _bit_depth(counts: xr.DataArray, bit_depth: int | None, where: str) -> int:
    if bit_depth is None:
        bit_depth = counts.attrs.get("bit_depth")
    if bit_depth is None:
        raise SchemaError(f"{where}: the bit depth is unknown",
                          ["expected attrs['bit_depth'] (8..16) or the keyword bit_depth=..."])
    if int(bit_depth) != bit_depth or not 8 <= int(bit_depth) <= 16:
        raise CalibrationError(f"{where}: bit_depth must be an integer in 8..16, got {bit_depth!r}")
    return int(bit_depth)


def _check_integer(counts: xr.DataArray, where: str) -> None:
    if not np.issubdtype(counts.dtype, np.integer):
        raise SchemaError(f"{where}: pixel values must be integers (raw DN)",
                          [f"dtype found: {counts.dtype}"])


def _check_times(times: xr.DataArray, series_dim: str, where: str) -> None:
    """Exposure times: positive, finite, strictly increasing along ``series_dim``."""
    values = np.asarray(times.transpose(..., series_dim).values, dtype=np.float64)
    if not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise CalibrationError(f"{where}: exposure_time must be positive and finite, got "
                               f"{values.tolist()}")
    rows = values.reshape(-1, values.shape[-1])
    for row_index, row in enumerate(rows):
        steps = np.diff(row)
        if np.any(steps <= 0):
            bad = int(np.argmax(steps <= 0))
            label = f" (image {row_index})" if rows.shape[0] > 1 else ""
            kind = "duplicate" if steps[bad] == 0 else "unsorted"
            raise CalibrationError(
                f"{where}: exposure_time{label} must be strictly increasing along "
                f"{series_dim!r}; found {kind} values {row[bad]} then {row[bad + 1]} at "
                f"positions {bad}, {bad + 1} of {row.tolist()}; sort the series by exposure "
                "time (e.g. ds.sortby('exposure_time')) and drop repeated exposures")


def _warn_if_geometric(times: xr.DataArray, series_dim: str, where: str) -> None:
    """Warn when every exposure-time ratio is the same (response not identifiable)."""
    values = np.asarray(times.transpose(..., series_dim).values, dtype=np.float64)
    rows = values.reshape(-1, values.shape[-1])
    ratios = np.unique(np.round(np.log(rows[:, 1:] / rows[:, :-1]), 2))
    if ratios.size == 1:
        warnings.warn(
            f"{where}: every exposure-time ratio is {math.exp(ratios[0]):.3g}; the response is "
            "then determined only up to a factor periodic in log exposure (Grossberg & Nayar "
            "2003) and only noise decides it. Use exposure times with unequal ratios "
            "(e.g. 1, 3, 8, 25, 60) or several series with different ratios",
            RuntimeWarning, stacklevel=3)


def _check_frames(counts: xr.DataArray, frame_dims: tuple[str, ...], *, black_level: float,
                  saturation: float, max_code: int, where: str,
                  times: xr.DataArray | None = None) -> None:
    """No value beyond the bit depth, no frame entirely saturated or entirely dark."""
    frame_dims = tuple(d for d in counts.dims if d in frame_dims)
    pixel_dims = [d for d in counts.dims if d not in frame_dims]
    if counts.chunks is None:   # numpy: two reductions, no xarray/dask overhead
        axes = tuple(counts.get_axis_num(pixel_dims))
        # pixel dims last and flattened (one copy when they are not already last): numpy
        # reduces a contiguous last axis many times faster than axes in the middle
        values = np.ascontiguousarray(
            np.moveaxis(counts.values, axes, tuple(range(-len(axes), 0))))
        values = values.reshape(values.shape[:values.ndim - len(axes)] + (-1,))
        frame_min, frame_max = values.min(axis=-1), values.max(axis=-1)
        lo, hi = frame_min.min(), frame_max.max()
        not_saturated, not_dark = frame_min < saturation, frame_max > black_level
    else:
        lo, hi, not_saturated, not_dark = (np.asarray(v) for v in dask.compute(
            counts.min().data, counts.max().data, (counts < saturation).any(pixel_dims).data,
            (counts > black_level).any(pixel_dims).data))
    lo, hi = int(lo), int(hi)
    if lo < 0 or hi > max_code:
        raise CalibrationError(f"{where}: pixel values must lie in [0, {max_code}] for the bit "
                               f"depth, found [{lo}, {hi}]; is bit_depth right?")
    for flags, what, bound in ((not_saturated, "saturated (>= saturation", saturation),
                               (not_dark, "dark (<= black_level", black_level)):
        bad = np.argwhere(~np.asarray(flags, dtype=bool))
        if bad.size:
            position = dict(zip(frame_dims, bad[0].tolist(), strict=True))
            t = ""
            if times is not None:
                at = {k: v for k, v in position.items() if k in times.dims}
                t = f", exposure_time {float(times.isel(at).values)} s"
            raise CalibrationError(
                f"{where}: frame {position}{t} is entirely {what} = {bound}): it carries no "
                f"information; {len(bad)} such frame(s) in all. Drop it or fix its exposure")


# -- xarray: Robertson on raw codes ------------------------------------------------------------
def _response_dataarray(values: np.ndarray, samples: np.ndarray, dims: tuple[str, ...],
                        coords: Mapping[Hashable, object], code: np.ndarray,
                        attrs: dict[str, object]) -> xr.DataArray:
    code_coord = xr.DataArray(code, dims=("code",),
                              attrs={"units": "DN", "long_name": "pixel value"})
    out = xr.DataArray(
        values.astype(np.float64), dims=dims + ("code",),
        coords={**coords, "code": code_coord,
                "samples": (dims + ("code",), samples.astype(np.int64),
                            {"long_name": "samples per code (0: interpolated)"})},
        name="response",
        attrs={"units": "1",
               "long_name": "camera response f: relative exposure x t per pixel value",
               **attrs},
    )
    return out


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
        Weighting function, see :func:`weighting_function`.
    tolerance, max_iterations, monotone, max_bins, solver, operator
        See :func:`robertson_response`.
    max_pixels
        Use at most this many pixel positions (a reproducible random subset, the same for
        every exposure, image and channel); default all.
    seed
        Seed of that subset.

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
    Robertson, Borman, Stevenson 2003. Fast Capture of Spectral Image Series, section 4.
    """
    where = "recover_oecf: counts"
    counts = _counts_array(raw)
    if "exposure_time" not in counts.coords:
        raise SchemaError(f"{where} has no exposure_time coord",
                          [f"coords found: {sorted(map(str, counts.coords))}"])
    allowed = {"image", "exposure", "y", "x", "channel"}
    if not {"exposure", "y", "x"} <= set(counts.dims) or not set(counts.dims) <= allowed:
        raise SchemaError(f"{where} has the wrong dims",
                          [f"expected exposure, y, x plus optional image and channel; "
                           f"found {counts.dims}"])
    _check_integer(counts, where)
    depth = _bit_depth(counts, bit_depth, where)
    n_codes = 2**depth
    saturation = n_codes - 1 if saturation is None else int(saturation)
    times = counts["exposure_time"]
    if not set(times.dims) <= {"image", "exposure"} or "exposure" not in times.dims:
        raise SchemaError(f"{where}: exposure_time has the wrong dims",
                          [f"expected (exposure,) or (image, exposure), found {times.dims}"])
    if counts.sizes["exposure"] < 2:
        raise CalibrationError(f"{where}: an exposure series needs at least 2 exposures, got "
                               f"{counts.sizes['exposure']}")
    _check_times(times, "exposure", where)
    _warn_if_geometric(times, "exposure", where)
    weights = weighting_function(np.arange(n_codes), black_level=black_level,
                                 saturation=saturation, kind=weighting)
    frame_dims = tuple(d for d in ("image", "exposure", "channel") if d in counts.dims)
    _check_frames(counts, frame_dims, black_level=black_level, saturation=saturation,
                  max_code=n_codes - 1, where=where, times=times)

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
        block = np.asarray(counts.isel(image=images).values)  # (G, E, y, x, C)
        block = block.reshape(block.shape[0], block.shape[1], ny * nx, block.shape[-1])
        if pick is not None:
            block = block[:, :, pick]
        block = np.ascontiguousarray(np.moveaxis(block, -1, 0))   # (C, G, E, P)
        for c in range(block.shape[0]):
            results[(camera, c)] = robertson_response(
                block[c], time_values[images], n_codes=n_codes, weights=weights,
                tolerance=tolerance, max_iterations=max_iterations, monotone=monotone,
                max_bins=max_bins, solver=solver, operator=operator)

    n_channels = counts.sizes["channel"]
    values = np.stack([np.stack([results[(cam, c)].response for c in range(n_channels)])
                       for cam in camera_list])
    samples = np.stack([np.stack([results[(cam, c)].samples for c in range(n_channels)])
                        for cam in camera_list])
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
    }
    response = _response_dataarray(values, samples, dims, coords,
                                   np.arange(n_codes, dtype=np.int32), attrs)
    return xr.Dataset({"response": response}, attrs={"bit_depth": depth})


# -- the paper's low-SNR extension ----------------------------------------------------------
def _series_dim(counts: xr.DataArray, where: str) -> str:
    others = [d for d in counts.dims if d not in ("y", "x")]
    if len(others) != 1 or not {"y", "x"} <= set(counts.dims):
        raise SchemaError(f"{where} has the wrong dims",
                          [f"expected (exposure or shot, y, x), found {counts.dims}"])
    return str(others[0])


def _dark_for_times(dark: xr.Dataset | xr.DataArray, times: np.ndarray,
                    shape: tuple[int, int], where: str) -> np.ndarray:
    mean = dark["mean"] if isinstance(dark, xr.Dataset) else dark
    if "exposure_time" not in mean.dims or not {"y", "x"} <= set(mean.dims):
        raise SchemaError("dark: wrong dims",
                          [f"expected mean (exposure_time, y, x), found {mean.dims}"])
    mean = mean.transpose("exposure_time", "y", "x")
    if (mean.sizes["y"], mean.sizes["x"]) != shape:
        raise CalibrationError(
            f"dark: mean frame is {mean.sizes['y']}x{mean.sizes['x']} px but {where} is "
            f"{shape[0]}x{shape[1]} px; use dark frames of the same camera and region")
    available = np.asarray(mean["exposure_time"].values, dtype=np.float64)
    picks = []
    for t in times:
        match = np.flatnonzero(np.isclose(available, t, rtol=1e-6, atol=0.0))
        if match.size == 0:
            raise CalibrationError(
                f"dark: no dark frame for exposure_time {t} s of {where}; dark frames exist for "
                f"{available.tolist()} s. Record dark frames at every exposure time used")
        picks.append(int(match[0]))
    return np.asarray(mean.isel(exposure_time=picks).values, dtype=np.float64)


def _exposure_estimates(codes: np.ndarray, times: np.ndarray, weights: np.ndarray,
                        response: np.ndarray) -> np.ndarray:
    """Leave-one-out exposure ``X_ij = t_j x_i^(-j)`` of every sample (NaN where undefined).

    ``x_i^(-j)`` is Robertson's irradiance step (weights ``w``, response ``f``) from the other
    samples of pixel ``i``, so that ``X_ij`` is independent of the noise of sample ``j``.
    ``codes`` (E, P) integers, ``times`` (E,), ``weights`` and ``response`` per code.
    """
    t = times[:, None]
    w = weights[codes] * t
    wf = w * response[codes]
    w *= t
    num = wf.sum(axis=0) - wf
    den = w.sum(axis=0) - w
    ok = den > 1e-12 * max(float(den.max()), 1e-300)
    return np.where(ok, t * num / np.where(ok, den, 1.0), np.nan)


def _reverse_regression(exposure: np.ndarray, values: np.ndarray, levels: np.ndarray,
                        grid: np.ndarray) -> np.ndarray:
    """Response on ``grid`` from the mean pixel value per exposure bin, ``E[v | X]``.

    Samples are binned by exposure ``X`` at the midpoints of ``levels`` (a non-decreasing
    response on ``grid``); per bin the mean ``X`` and mean ``v`` are one point of the curve
    ``v = f^-1(X)``. The points are made monotone (pool adjacent violators, weighted by the
    samples per bin) and interpolated at ``grid`` (linear); beyond the outermost points the
    shape of ``levels`` is kept, scaled to join continuously.
    """
    keep = np.isfinite(exposure)
    x, v = exposure[keep], values[keep]
    edges = 0.5 * (levels[1:] + levels[:-1])
    b = np.searchsorted(edges, x)
    n = np.bincount(b, minlength=grid.size)
    seen = n > 0
    if seen.sum() < 2:
        return levels.copy()
    n = n[seen].astype(np.float64)
    x_mean = np.bincount(b, x, minlength=grid.size)[seen] / n
    v_mean = isotonic_regression(np.bincount(b, v, minlength=grid.size)[seen] / n, n)
    v_points, which = np.unique(v_mean, return_inverse=True)
    if v_points.size < 2:
        return levels.copy()
    x_points = np.bincount(which, x_mean * n) / np.bincount(which, n)
    out = _lookup(grid, x_points, v_points)
    # beyond the outermost bin means the reverse regression has no data: there the table
    # keeps the shape of ``levels``, scaled to join continuously (no extrapolated slope)
    for end, outside in ((0, grid < v_points[0]), (-1, grid > v_points[-1])):
        if outside.any():
            ref = float(np.interp(v_points[end], grid, levels))
            if ref > 0:
                out[outside] = levels[outside] * (x_points[end] / ref)
    return out


def _quadratic_through_zero(exposure: np.ndarray, values: np.ndarray,
                            top: float) -> tuple[float, float] | None:
    """Least-squares ``v = c1 X + c2 X^2`` over samples with ``0 <= X <= top``; None if unfit."""
    keep = np.isfinite(exposure)
    x, v = exposure[keep], values[keep]
    sel = (x >= 0) & (x <= top)
    if sel.sum() < 16:
        return None
    x, v = x[sel] / top, v[sel]                     # scaled for conditioning
    x2 = x * x
    a = np.array([[np.dot(x, x), np.dot(x, x2)], [np.dot(x, x2), np.dot(x2, x2)]])
    rhs = np.array([np.dot(x, v), np.dot(x2, v)])
    try:
        c1, c2 = np.linalg.solve(a, rhs)
    except np.linalg.LinAlgError:
        return None
    c1, c2 = c1 / top, c2 / top**2
    if not c1 > 0 or not c1 + 2 * c2 * top > 0:       # not increasing over the fit range
        return None
    return float(c1), float(c2)


def _invert_quadratic(v: np.ndarray, c1: float, c2: float) -> np.ndarray:
    """``X`` with ``c1 X + c2 X^2 = v`` on the increasing branch through 0 (stable form)."""
    root = np.sqrt(np.maximum(c1 * c1 + 4.0 * c2 * v, 0.0))
    return 2.0 * v / (c1 + root)


def recover_oecf_low_snr(
    series: xr.Dataset | xr.DataArray,
    dark: xr.Dataset | xr.DataArray,
    *,
    filter_size: float = 25.0,
    bit_depth: int | None = None,
    levels: int | None = None,
    weighting: Weighting = "gaussian",
    tolerance: float = 1e-6,
    max_iterations: int = 5000,
    monotone: bool = True,
    max_bins: int = 1024,
    max_pixels: int | None = None,
    seed: int = 0,
    solver: Solver = "lanczos",
    debias: bool = True,
    fit_below: float | None = None,
) -> xr.Dataset:
    """Response of a camera working at its noise floor (the paper's extension of Robertson).

    Steps (paper section 4): (1) subtract the averaged dark frame of the same exposure time,
    in float, keeping negative values (clipping them would bias the result, paper Fig. 2);
    (2) Gaussian-filter every frame as in the reconstruction (``sigma = filter_size / 5``,
    truncated at ``filter_size / 2``), keeping only pixels whose kernel lies inside the
    image; (3) stretch the interval ``[lo, hi]`` of filtered values to the integer range
    ``0 .. levels-1`` and round; (4) run Robertson (:func:`robertson_response`) on these
    codes; (5) map stretched code ``k`` back to the dark-subtracted pixel value
    ``lo + k (hi - lo) / (levels - 1)``; with ``debias`` (default) two more steps follow:
    (6) de-bias by reverse regression and (7) fit the lowest values through 0 (see Notes).

    Filtering averages many pixels, so the noise (Gaussian read noise, shot noise and the
    quantisation of ``floor`` in eq. 5, which the noise dithers) shrinks by the filter
    (3 DN read noise: 0.11 DN after ``filter_size`` 40) and the recovered response holds
    down to pixel values with per-pixel SNR of 1 or less.

    Parameters
    ----------
    series
        Integer frames ``(exposure or shot, y, x)`` [DN] of a spatially smooth target (white
        reference, grey card, smooth illumination gradient) with an ``exposure_time`` coord
        [s] along the first dim; a Dataset with variable ``counts`` (group ``raw/spectral``
        of one wavelength) works as well.
    dark
        Group ``dark`` (``mean`` (exposure_time, y, x) float [DN]) or that DataArray; it must
        have a frame for every exposure time of ``series``.
    filter_size
        Gaussian filter size ``s`` [px] (eq. 3); ``sigma = s / 5``.
    bit_depth
        ADC bit depth; default ``attrs["bit_depth"]``.
    levels
        Number of integer levels of the stretch; default ``2**bit_depth`` ("the full range of
        integers corresponding to the camera's bit depth").
    weighting, tolerance, max_iterations, monotone, max_bins, solver
        As for :func:`robertson_response`; the weights apply to the stretched codes, whose
        ends are the extremes of the data, not saturation.
    max_pixels, seed
        Optional reproducible subset of filtered pixel positions.
    debias
        Steps (6) and (7): replace Robertson's estimate ``E[x t | v]`` by the reverse
        regression ``E[v | x t]`` and fit the lowest values through 0 (Notes). ``False``:
        the plain fixed point of step (4).
    fit_below
        Top [DN above dark] of the quadratic fit through 0 of step (7); the fit replaces the
        table below ``fit_below / 2`` and is cross-faded into it up to ``fit_below``.
        Default: 10% of the top of the stretched interval. 0 switches step (7) off.

    Returns
    -------
    xarray.Dataset
        Variable ``response`` (code): ``code`` is the dark-subtracted pixel value [DN]
        (fractional, may be negative) on a grid of ``levels`` points spanning ``[lo, hi]``;
        values are relative exposures normalised to 1 at the middle of the grid. Attrs as
        :func:`recover_oecf` plus ``dark_subtracted=True``, ``dark_level`` (mean dark value
        [DN]; add it to ``code`` for raw pixel values), ``stretch_low``, ``stretch_high``,
        ``filter_size``, ``levels``, ``debiased``, ``fit_below`` (NaN when step (7) did not
        run). ``iterations``/``converged`` are those of Robertson's iteration (step 4).

    Raises
    ------
    SchemaError
        Wrong dims, non-integer data, unknown bit depth.
    CalibrationError
        Fewer than two exposures, unsorted or duplicate exposure times, a dark frame missing
        for an exposure time or of another size, a frame smaller than the filter, filtered
        values without spread.

    Notes
    -----
    Domain: the returned table covers ``[lo, hi]``; :func:`apply_response` extrapolates
    linearly beyond it. The target must be smooth on the scale of the filter: the filter acts
    on pixel values, so a non-linear OECF mixes neighbouring exposures at edges.

    Why de-bias (step 6): Robertson's update sets ``f(m)`` to the mean exposure ``X = x t`` of
    the samples *observed* at ``m``, ``E[X | v]``. With noise of variance ``s^2`` on ``v``
    this is regression to the mean: ``E[X | v] ~ f(v + s^2 d/dv log p(v))``, ``p`` the
    density of observed values. At the bottom of a low-SNR series ``p`` falls steeply
    (filtered noise 0.11 DN gave -2% at 1 DN, -1.5% at 1.5 DN in the benchmark). The noise is
    additive and independent of the exposure, so the reverse regression ``E[v | X]`` is
    unbiased: every sample gets the leave-one-out exposure ``X_ij = t_j x_i^(-j)`` from
    Robertson's irradiance step with the converged response (independent of the noise of
    sample ``j``), samples are binned by ``X`` at the levels of that response, and the mean
    ``X`` and mean ``v`` of each bin are a point of the curve (made monotone by pool adjacent
    violators, interpolated at the grid).

    Step (7): a handful of DN above dark the mean of a bin still scatters (filtered noise is
    correlated over the kernel, so few independent patches fall into one bin: about 1% at
    1.25 DN in the benchmark). The dark-subtracted response passes through 0 (zero exposure
    gives zero signal after subtracting the mean dark frame), and over a few DN it is smooth,
    so ``v = c1 X + c2 X^2`` is fitted by least squares to all samples with
    ``0 <= X <= f(fit_below)`` (noise in ``v`` only: unbiased) and inverted below
    ``fit_below``; negative values follow its increasing branch.

    References
    ----------
    Fast Capture of Spectral Image Series, section 4 and Fig. 2. Robertson, Borman,
    Stevenson 2003.
    """
    where = "recover_oecf_low_snr: series"
    counts = _counts_array(series)
    dim = _series_dim(counts, where)
    _check_integer(counts, where)
    depth = _bit_depth(counts, bit_depth, where)
    if "exposure_time" not in counts.coords or counts["exposure_time"].dims != (dim,):
        raise SchemaError(f"{where} needs an exposure_time coord along {dim!r}",
                          [f"coords found: {sorted(map(str, counts.coords))}"])
    if counts.sizes[dim] < 2:
        raise CalibrationError(f"{where}: an exposure series needs at least 2 exposures, got "
                               f"{counts.sizes[dim]}")
    _check_times(counts["exposure_time"], dim, where)
    _warn_if_geometric(counts["exposure_time"], dim, where)
    if filter_size <= 0:
        raise CalibrationError(f"filter_size must be positive, got {filter_size}")
    levels = 2**depth if levels is None else int(levels)
    if levels < 16:
        raise CalibrationError(f"levels must be at least 16, got {levels}")
    counts = counts.transpose(dim, "y", "x")
    times = np.asarray(counts["exposure_time"].values, dtype=np.float64)
    ny, nx = counts.sizes["y"], counts.sizes["x"]
    dark_mean = _dark_for_times(dark, times, (ny, nx), where)
    raw_values = np.asarray(counts.values)
    hi_code = int(raw_values.max())
    if raw_values.min() < 0 or hi_code > 2**depth - 1:
        raise CalibrationError(f"{where}: pixel values must lie in [0, {2**depth - 1}], found "
                               f"[{int(raw_values.min())}, {hi_code}]")
    if hi_code == 2**depth - 1:
        raise CalibrationError(f"{where}: saturated pixels (value {hi_code}) in a low-SNR "
                               "series; use shorter exposures")

    sigma = filter_size / 5.0
    radius = int(math.ceil(filter_size / 2.0))
    if ny <= 2 * radius or nx <= 2 * radius:
        raise CalibrationError(f"{where}: frames of {ny}x{nx} px are too small for "
                               f"filter_size {filter_size} (kernel radius {radius} px)")
    filtered = np.empty((times.size, ny - 2 * radius, nx - 2 * radius))
    for j in range(times.size):
        signal = raw_values[j].astype(np.float64) - dark_mean[j]   # negative values kept
        smooth = ndimage.gaussian_filter(signal, sigma, mode="nearest", truncate=2.5)
        filtered[j] = smooth[radius:ny - radius, radius:nx - radius]
    values = filtered.reshape(times.size, -1)
    if max_pixels is not None and values.shape[1] > max_pixels:
        rng = np.random.default_rng(seed)
        values = values[:, np.sort(rng.choice(values.shape[1], int(max_pixels), replace=False))]
    lo, hi = float(values.min()), float(values.max())
    if not hi - lo > 0:
        raise CalibrationError(f"{where}: filtered values have no spread ({lo} .. {hi})")
    step = (hi - lo) / (levels - 1)
    codes = np.rint((values - lo) / step).astype(np.int64)
    weights = weighting_function(np.arange(levels), black_level=-1.0, saturation=levels,
                                 kind=weighting)
    result = robertson_response(codes, times, n_codes=levels, weights=weights,
                                tolerance=tolerance, max_iterations=max_iterations,
                                monotone=monotone, max_bins=max_bins, solver=solver)
    grid = lo + step * np.arange(levels)
    table = result.response
    fit = None
    if debias:
        exposure = _exposure_estimates(codes, times, weights, table)
        table = _reverse_regression(exposure, values, table, grid)
        fit_top = 0.1 * hi if fit_below is None else float(fit_below)
        if fit_top > 0:
            fit = _quadratic_through_zero(exposure, values, float(np.interp(fit_top, grid,
                                                                            table)))
        if fit is not None:
            alpha = np.clip((grid - 0.5 * fit_top) / (0.5 * fit_top), 0.0, 1.0)
            table = (1 - alpha) * _invert_quadratic(grid, *fit) + alpha * table
        if monotone:
            table = isotonic_regression(table)
        mid_value = float(np.interp(lo + step * (levels - 1) / 2, grid, table))
        if not mid_value > 0:
            raise CalibrationError(f"{where}: the de-biased response is not positive at the "
                                   "middle of the stretched interval")
        table = table / mid_value
    attrs = {
        "bit_depth": depth,
        "method": "robertson2003_low_snr",
        "iterations": result.iterations,
        "converged": bool(result.converged),
        "tolerance": float(tolerance),
        "weighting": weighting,
        "dark_subtracted": True,
        "dark_level": float(dark_mean.mean()),
        "stretch_low": lo,
        "stretch_high": hi,
        "filter_size": float(filter_size),
        "levels": levels,
        "mid_code": float(grid[(levels - 1) // 2] + step * ((levels - 1) / 2 % 1)),
        "normalisation": "response at the middle of the stretched interval = 1",
        "debiased": bool(debias),
        "fit_below": float(fit_top) if fit is not None else float("nan"),
    }
    response = _response_dataarray(table, result.samples, (), {}, grid, attrs)
    response["code"].attrs.update(long_name="dark-subtracted pixel value")
    return xr.Dataset({"response": response}, attrs={"bit_depth": depth})


# -- using responses --------------------------------------------------------------------------
def _as_response(response: xr.Dataset | xr.DataArray) -> xr.DataArray:
    if isinstance(response, xr.Dataset):
        if "response" not in response.data_vars:
            raise SchemaError("response: the Dataset has no variable 'response'",
                              [f"variables found: {sorted(map(str, response.data_vars))}"])
        response = response["response"]
    if "code" not in response.dims:
        raise SchemaError("response: no 'code' dim", [f"dims found: {response.dims}"])
    code = np.asarray(response["code"].values, dtype=np.float64)
    if code.size < 2 or np.any(np.diff(code) <= 0):
        raise CalibrationError("response: its code coordinate must be strictly increasing")
    if not np.all(np.isfinite(response.values)):
        raise CalibrationError("response: contains NaN or inf values")
    return response


def apply_response(
    values: xr.DataArray, response: xr.Dataset | xr.DataArray
) -> xr.DataArray:
    """Linearise pixel values: relative exposure ``f(values)`` by the response table.

    Parameters
    ----------
    values
        Pixel values [DN]: raw codes for a response over raw codes, dark-subtracted values
        for a low-SNR response (``attrs["dark_subtracted"]``). Any dims; dims the response
        has besides ``code`` (``channel``, ``camera``) are matched by name. Dask-backed input
        stays lazy.
    response
        A response from :func:`recover_oecf`, :func:`recover_oecf_low_snr` or
        :func:`combine_responses`.

    Returns
    -------
    xarray.DataArray
        float64 relative exposure, dims of ``values`` (plus any response dims it lacked).

    Notes
    -----
    Linear interpolation between tabulated codes; linear extrapolation with the end slopes
    beyond them, so noise-negative dark-subtracted values map to negative exposures instead
    of being clipped (clipping biases averages, paper Fig. 2).
    """
    table = _as_response(response)
    grid = np.asarray(table["code"].values, dtype=np.float64)
    table = table.drop_vars([c for c in table.coords if c not in table.dims or c == "code"])
    out = xr.apply_ufunc(
        _lookup, values, table, kwargs={"codes": grid},
        input_core_dims=[[], ["code"]], output_core_dims=[[]],
        dask="parallelized", output_dtypes=[np.float64],
    )
    return out.assign_attrs(units="1", long_name="relative exposure (linearised pixel value)")


def response_at_codes(response: xr.Dataset | xr.DataArray, codes: np.ndarray) -> xr.DataArray:
    """Evaluate a response table at other codes (e.g. integer codes for an HDR merge)."""
    table = _as_response(response)
    grid = np.asarray(table["code"].values, dtype=np.float64)
    stacked = table.transpose(..., "code")
    result = _lookup(np.asarray(codes, dtype=np.float64), np.asarray(stacked.values)[..., None, :],
                     grid)
    dims = stacked.dims
    coords = {k: v for k, v in stacked.coords.items() if k != "code" and "code" not in v.dims}
    coords["code"] = ("code", np.asarray(codes), table["code"].attrs)
    return xr.DataArray(result, dims=dims, coords=coords, name="response",
                        attrs=dict(table.attrs))


def combine_responses(
    low_snr: xr.Dataset | xr.DataArray,
    full: xr.Dataset | xr.DataArray,
    *,
    dark_level: float | None = None,
    overlap: tuple[float, float] | None = None,
) -> xr.Dataset:
    """Join a low-SNR response (dark-subtracted values) to a full-range Robertson response.

    Parameters
    ----------
    low_snr
        From :func:`recover_oecf_low_snr` (monochrome, ``code`` = DN above dark).
    full
        From :func:`recover_oecf` on the same camera (monochrome, ``code`` = raw DN).
    dark_level
        Raw value of zero signal [DN], ``code_raw = code_dark_subtracted + dark_level``;
        default ``low_snr.attrs["dark_level"]`` (the mean dark frame).
    overlap
        Interval of dark-subtracted values [DN] where both are trusted; the low-SNR response
        is scaled onto the full one by least squares there and the two are cross-faded
        linearly across it. Default: 50% .. 90% of the low-SNR interval.

    Returns
    -------
    xarray.Dataset
        ``response`` (code) over dark-subtracted values [DN]: the low-SNR grid below the end
        of ``overlap``, the full response's codes (shifted by ``-dark_level``) above;
        normalised like ``full``. Attrs of ``full`` plus ``method="combined"``,
        ``dark_subtracted=True``, ``dark_level``, ``overlap``, ``scale``.

    Raises
    ------
    CalibrationError
        When the overlap holds no code of the full response, or the responses have extra dims.
    """
    low = _as_response(low_snr)
    high = _as_response(full)
    if low.ndim != 1 or high.ndim != 1:
        raise CalibrationError("combine_responses: both responses must be monochrome (code,)")
    if dark_level is None:
        if "dark_level" not in low.attrs:
            raise CalibrationError("combine_responses: give dark_level (raw DN of zero signal)")
        dark_level = float(low.attrs["dark_level"])
    v_low = np.asarray(low["code"].values, dtype=np.float64)
    f_low = np.asarray(low.values, dtype=np.float64)
    v_high = np.asarray(high["code"].values, dtype=np.float64) - dark_level
    f_high = np.asarray(high.values, dtype=np.float64)
    if overlap is None:
        span = v_low[-1] - v_low[0]
        overlap = (v_low[0] + 0.5 * span, v_low[0] + 0.9 * span)
    a, b = float(overlap[0]), float(overlap[1])
    inside = (v_high >= a) & (v_high <= b)
    if not b > a or inside.sum() < 2:
        raise CalibrationError(
            f"combine_responses: overlap {overlap} DN holds {int(inside.sum())} codes of the "
            "full response; it needs at least 2. Record the low-SNR series up to higher values")
    g = np.interp(v_high[inside], v_low, f_low)
    scale = float(np.dot(g, f_high[inside]) / np.dot(g, g))
    grid = np.concatenate([v_low[v_low <= b], v_high[v_high > b]])
    f_l = _lookup(grid, f_low * scale, v_low)
    f_h = _lookup(grid, f_high, v_high)
    alpha = np.clip((grid - a) / (b - a), 0.0, 1.0)
    values = (1 - alpha) * f_l + alpha * f_h
    attrs = {**high.attrs, "method": "combined", "dark_subtracted": True,
             "dark_level": float(dark_level), "overlap": [a, b], "scale": scale,
             "low_snr_method": low.attrs.get("method", ""),
             "converged": bool(low.attrs.get("converged", True))
             and bool(high.attrs.get("converged", True))}
    samples = np.concatenate([low["samples"].values[v_low <= b],
                              high["samples"].values[v_high > b]])
    response = _response_dataarray(values, samples, (), {}, grid, attrs)
    response["code"].attrs.update(long_name="dark-subtracted pixel value")
    return xr.Dataset({"response": response})
