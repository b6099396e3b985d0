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

__all__ = ["CHART_RESPONSE_KNOTS", "codes_reached", "log_spline_response"]

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
