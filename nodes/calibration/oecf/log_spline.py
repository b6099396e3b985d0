"""A recovered camera response smoothed to a cubic spline in the log code.

The RGB response recovered from a scene's exposure series (Robertson's per-code estimate,
then a smooth spline over the codes) still ripples by a few per cent from code to code
where the series gave few samples. A scene's millions of pixels spread over many codes
average such a ripple out; a colour checker's two dozen patch means do not: each patch
sits at a few codes per exposure, so each carries the ripple's error there, and the camera
matrix ``C`` fitted to them bends to follow it where the chart's light is weak (a red row
that rises again beyond its infrared cut reproduces the patches as well as the true one,
and the reconstruction then puts too little radiance where a red material reflects most).
A response is smooth in the log of the code above the black level (a power law is a line
there), so :func:`log_spline_response` replaces the recovered response over the codes a
target reaches by its least-squares cubic spline in ``ln(c - b)``, of few coefficients:
the same response without the ripple, for the patch means the matrix is fitted to.

How many coefficients a response needs is the camera's: a power law is a line in the log
code, an early shoulder bends over few of its codes. :func:`chosen_log_spline_response`
chooses them per channel on the camera's own exposure series (:func:`code_residual`: the
series' codes predicted through the candidate response), keeping the recovered response where
no spline predicts them better; ``recover_rgb_oecf`` smooths every camera's response so by
default, so the scene's HDR and the chart's patch means are read through the same curve.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 (the camera matrix ``C`` from a
   colour checker's HDR RGB) and eq. 5 (the response ``f``).
.. [2] M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic
   range enhancement using multiple exposures", Journal of Electronic Imaging 12(2), 2003.
.. [3] C. de Boor, A Practical Guide to Splines, Springer 1978 (least-squares B-splines).
"""

from __future__ import annotations

import numpy as np

from spectralize.schemas import CalibrationError

__all__ = [
    "CHART_RESPONSE_KNOTS",
    "LOG_SPLINE_CANDIDATES",
    "chosen_log_spline_response",
    "code_residual",
    "codes_reached",
    "log_spline_response",
]

CHART_RESPONSE_KNOTS = 8
"""Cubic B-spline coefficients per channel of the response the chart's patch means are read
through (:func:`log_spline_response`): a response's shape over the codes, not a ripple."""


def codes_reached(
    counts: np.ndarray, black_level: float, saturation: float
) -> tuple[float, float] | None:
    """The lowest and highest code of ``counts`` strictly between ``black_level`` and
    ``saturation`` [DN]; None where there is none."""
    values = np.asarray(counts)
    inside = values[(values > black_level) & (values < saturation)]
    if inside.size == 0:
        return None
    return float(inside.min()), float(inside.max())


def _spline_design(u: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
    """(len(u), n) cubic B-splines with uniform knots on ``[lo, hi]`` at ``u`` (clipped into it)."""
    from scipy.interpolate import BSpline  # not at import: `spectralize nodes` lists nodes without it

    inner = np.linspace(lo, hi, n - 2)
    step = inner[1] - inner[0]
    knots = np.concatenate(
        [inner[0] - step * np.arange(3, 0, -1), inner, inner[-1] + step * np.arange(1, 4)]
    )
    return BSpline.design_matrix(np.clip(u, lo, hi), knots, 3).toarray()


def log_spline_response(
    response: np.ndarray,
    black_level: float,
    reached: tuple[float, float],
    knots: int = CHART_RESPONSE_KNOTS,
) -> np.ndarray:
    """``response`` (channel, code) with ``exp(s(ln(c - b)))`` on the codes ``reached``.

    Per channel, ``s`` is the least-squares cubic spline of ``knots`` coefficients (uniform
    knots in ``u = ln(c - b)`` over the codes ``reached``) fitted to ``ln f(c)`` on the codes
    ``c`` in ``reached`` where ``f > 0``; the table is ``exp(s(u))`` there and ``f`` elsewhere
    (codes the target does not reach keep the recovered response).

    Parameters
    ----------
    response
        (channel, code) relative exposure per code (code = index), the recovered response.
    black_level
        ``b`` [DN].
    reached
        (lowest, highest) code [DN] the target's frames reach (:func:`codes_reached`).
    knots
        Spline coefficients per channel (at least 4).

    Returns
    -------
    numpy.ndarray
        (channel, code) float64.

    Raises
    ------
    CalibrationError
        Fewer than 4 knots, or fewer codes with a positive response in ``reached`` than
        ``2 * knots`` in some channel.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    if knots < 4:
        raise CalibrationError(f"log_spline_response: knots must be >= 4, got {knots}")
    table = np.array(response, dtype=np.float64, copy=True)
    codes = np.arange(table.shape[-1], dtype=np.float64)
    lo, hi = max(float(reached[0]), black_level + 1.0), float(reached[1])
    in_range = (codes >= lo) & (codes <= hi)
    u = np.log(np.where(codes > black_level, codes - black_level, 1.0))
    u_lo, u_hi = float(np.log(lo - black_level)), float(np.log(max(hi, lo + 1.0) - black_level))
    for ch in range(table.shape[0]):
        use = in_range & (table[ch] > 0)
        if int(use.sum()) < 2 * knots:
            raise CalibrationError(
                f"log_spline_response: channel {ch} has {int(use.sum())} codes with a positive "
                f"response in {lo:.0f}..{hi:.0f} DN, need at least {2 * knots}"
            )
        coefficients = np.linalg.lstsq(
            _spline_design(u[use], u_lo, u_hi, knots), np.log(table[ch, use]), rcond=None
        )[0]
        table[ch, in_range] = np.exp(_spline_design(u[in_range], u_lo, u_hi, knots) @ coefficients)
    return table


LOG_SPLINE_CANDIDATES = (5, 6, 8, 10, 12, 14, 16, 20, 24)
"""Spline coefficients :func:`chosen_log_spline_response` chooses among per channel (and the
recovered response itself): from a power law's few to a shoulder's many."""


def code_residual(
    response: np.ndarray,
    codes: np.ndarray,
    times: np.ndarray,
    weights: np.ndarray,
    reached: tuple[float, float],
) -> float:
    """Weighted mean squared residual [DN^2] of an exposure series' codes under one response.

    Each pixel's exposure is Robertson's estimate under ``response``,
    ``x_i = sum_j w(y_ij) t_j f(y_ij) / sum_j w(y_ij) t_j^2``; each sample's predicted code is
    the response's inverse at ``t_j x_i``; the residual ``y_ij - f^-1(t_j x_i)`` is weighted
    by ``w(y_ij)`` over the samples in ``reached`` of non-zero weight. The noise of a camera
    is in its codes, so a response nearer the truth predicts the codes better, while
    Robertson's own objective (residuals in exposure) is the one the recovered response's
    ripple already minimises.

    Parameters
    ----------
    response
        (code,) relative exposure per code.
    codes
        (image, exposure, pixel) integer codes of one channel.
    times
        (image, exposure) exposure times [s].
    weights
        (code,) certainty weight per code (:func:`~.weighting.weighting_function`).
    reached
        (lowest, highest) code [DN] whose samples count.

    Returns
    -------
    float
        The weighted mean squared residual [DN^2]; ``inf`` with no sample.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    .. [2] M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2),
       2003 (the exposure estimate).
    """
    f = np.asarray(response, dtype=np.float64)
    w = weights[codes]
    t = np.asarray(times, dtype=np.float64)[:, :, None]
    num = (w * t * f[codes]).sum(axis=1)
    den = (w * t * t).sum(axis=1)
    x = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
    predicted = np.interp(t * x[:, None, :], np.maximum.accumulate(f), np.arange(f.size))
    use = (w > 0) & (codes >= reached[0]) & (codes <= reached[1])
    if not use.any():
        return float("inf")
    return float(((codes - predicted) ** 2 * w)[use].sum() / w[use].sum())


def chosen_log_spline_response(
    response: np.ndarray,
    black_level: float,
    reached: tuple[float, float],
    codes: np.ndarray,
    times: np.ndarray,
    weights: np.ndarray,
    candidates: tuple[int, ...] = LOG_SPLINE_CANDIDATES,
) -> tuple[np.ndarray, list[int]]:
    """``response`` (channel, code) smoothed by :func:`log_spline_response` with, per channel,
    the number of coefficients the camera's own exposure series chooses.

    A fixed flexibility suits one camera's response and not another's (a late, gentle
    shoulder needs few coefficients in the log code, an early one more). Per channel every
    candidate in ``candidates`` (those the codes in ``reached`` allow, the spline fitted from
    the first code of a positive response up, made non-decreasing above the black level by a
    running maximum, as a response does not fall; one that is not finite is left out) and the
    recovered response itself are scored by :func:`code_residual` on ``codes``, and the one of
    least residual is kept: a response the spline cannot follow keeps its freedom.

    Parameters
    ----------
    response
        (channel, code) the recovered response.
    black_level
        ``b`` [DN].
    reached
        (lowest, highest) code [DN] the camera's frames reach (:func:`codes_reached`).
    codes
        (image, exposure, pixel, channel) integer codes of the camera's exposure series.
    times
        (image, exposure) exposure times [s].
    weights
        (code,) certainty weight per code.
    candidates
        Spline coefficients to choose among (each at least 4).

    Returns
    -------
    tuple of numpy.ndarray and list of int
        The (channel, code) float64 table and the coefficients chosen per channel (0: the
        recovered response kept).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    table = np.array(response, dtype=np.float64, copy=True)
    lo = max(float(reached[0]), black_level + 1.0)
    codes_all = np.arange(table.shape[-1])
    rising = codes_all > black_level
    chosen = []
    for ch in range(table.shape[0]):
        positive = (codes_all >= lo) & (codes_all <= reached[1]) & (table[ch] > 0)
        if not positive.any():
            chosen.append(0)
            continue
        span = (float(codes_all[positive][0]), float(reached[1]))  # from the first positive code
        options = {0: table[ch]}
        for k in candidates:
            if int(positive.sum()) >= 2 * k:
                with np.errstate(over="ignore"):
                    smoothed = log_spline_response(table[ch : ch + 1], black_level, span, k)[0]
                if np.isfinite(smoothed).all():
                    smoothed[rising] = np.maximum.accumulate(smoothed[rising])
                    options[k] = smoothed
        scores = {
            k: code_residual(f, codes[..., ch], times, weights, (lo, reached[1]))
            for k, f in options.items()
        }
        best = min(scores, key=lambda k: scores[k])
        table[ch] = options[best]
        chosen.append(int(best))
    return table, chosen
