"""The white reference's own response: a smooth response fitted jointly with its flat field.

The white reference's frames of one RGB camera are an exposure series of one smooth scene:
each pixel's codes follow ``c = f(g F(p) t)``, ``F`` the flat field, ``t`` the exposure time.
Merged through the camera's recovered response, whose slope ripples from code to code where
the scene gave few samples, the frame's darker corners sit at other codes than its centre
and the ripple reads as falloff (each exposure's frame measures ``F`` to the power of the
response's local slope error over its codes). The series separates the two when the
response is smooth: a pixel's ratio between exposures depends on the response alone, its
level at one exposure on ``F``. So

``s(ln(c - b)) = a + ln F(p) + ln t``

is fitted by weighted least squares to the series' block means, ``s`` a cubic spline of
:data:`KNOTS` coefficients in the log code above the black level ``b`` per channel (the
exposure times fix its slope; a response too smooth to follow a ripple), ``ln F`` a
Legendre polynomial in the frame coordinates shared by the channels (a lens's falloff is
geometric). :func:`white_reference_response` returns ``exp(s)`` as a response table, through
which :func:`~spectralize.nodes.calibration.flat_field.rgb_flat_field` merges the white
reference for its flat field; the scene's images keep the camera's recovered response (the
white reference reaches only a few clusters of codes).

The spectral camera's white reference is a band series: each band's exposures of one block
see the same light, so ``s(ln d) = c + ln t``, with one unknown ``c`` per band and block
(``d`` the block's mean dark-subtracted code), holds whatever the falloff, and
:func:`band_series_response` fits one smooth ``s`` shared by the bands from the ratios
between exposures alone (:func:`band_block_statistics` gives the blocks); the bands'
different brightnesses spread the blocks' codes over the range the series reaches.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("taking images of a white diffuse
   reference surface") and eq. 5 (``I = f^-1(x t Q_lambda)``, here with ``Q_lambda F(p)``).
.. [2] M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic
   range enhancement using multiple exposures", Journal of Electronic Imaging 12(2), 2003.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import BSpline

from spectralize.nodes.calibration.flat_field_maps import (
    BLOCKS,
    DEGREE,
    flat_field_basis,
    legendre_powers,
)
from spectralize.nodes.calibration.oecf.weighting import Weighting, weighting_function

__all__ = [
    "KNOTS",
    "RESPONSE_BLOCKS",
    "white_reference_response",
    "white_reference_frames",
    "band_block_statistics",
    "band_series_response",
]

KNOTS = 5
"""Cubic B-spline coefficients of the white reference's response per channel, over the log
codes above the black level its series reaches."""

RESPONSE_BLOCKS = 8
"""Blocks per frame side whose mean codes the spectral camera's smooth response is fitted to
(:func:`band_series_response`): enough pixels per block that the log of its mean is not
biased by the pixels' noise."""


def _spline_design(u: np.ndarray, lo: float, hi: float, n: int) -> np.ndarray:
    """(len(u), n) the ``n`` cubic B-splines with uniform knots on ``[lo, hi]`` at ``u``
    (clipped into it: constant beyond)."""
    inner = np.linspace(lo, hi, n - 2)
    step = inner[1] - inner[0]
    knots = np.concatenate(
        [inner[0] - step * np.arange(3, 0, -1), inner, inner[-1] + step * np.arange(1, 4)]
    )
    return BSpline.design_matrix(np.clip(u, lo, hi), knots, 3).toarray()


def _block_sums(values: np.ndarray, edges_y: np.ndarray, edges_x: np.ndarray) -> np.ndarray:
    """Sums of ``values`` (y, x, ...) over the blocks between ``edges_y`` and ``edges_x``."""
    return np.add.reduceat(np.add.reduceat(values, edges_y[:-1], axis=0), edges_x[:-1], axis=1)


def _log_codes(
    codes: np.ndarray, black_level: float, saturation: float
) -> tuple[np.ndarray, np.ndarray]:
    """``ln(c - b)`` of the codes strictly between the levels (0 elsewhere) and where they are."""
    valid = (codes > black_level) & (codes < saturation)
    return np.log(np.where(valid, codes - black_level, 1.0)), valid


def _log_span(
    counts: np.ndarray, channel: int, black_level: float, saturation: float
) -> tuple[float, float] | None:
    """The lowest and highest ``ln(c - b)`` of ``channel``'s codes between the levels over
    every exposure; None where it has none."""
    lo, hi = np.inf, -np.inf
    for e in range(counts.shape[0]):
        u, valid = _log_codes(
            np.asarray(counts[e, ..., channel], dtype=np.float64), black_level, saturation
        )
        if valid.any():
            lo, hi = min(lo, float(u[valid].min())), max(hi, float(u[valid].max()))
    return (lo, hi) if np.isfinite(lo) else None


def white_reference_response(
    counts: np.ndarray,
    times: np.ndarray,
    black_level: float,
    saturation: float,
    n_codes: int,
    *,
    weighting: Weighting = "gaussian",
    knots: int = KNOTS,
    degree: int = DEGREE,
    blocks: int = BLOCKS,
) -> np.ndarray | None:
    """A smooth response per channel fitted jointly with the flat field on one camera's
    white-reference exposure series.

    Parameters
    ----------
    counts
        (exposure, y, x, channel) the white reference's raw codes [DN], integers.
    times
        (exposure,) exposure times [s].
    black_level, saturation
        Codes at or below ``black_level`` or at or above ``saturation`` are left out [DN].
    n_codes
        Codes of the returned table (``2**bit_depth``).
    weighting
        The certainty weight of a code, averaged over a block, weights its block mean
        (:func:`~spectralize.nodes.calibration.oecf.weighting.weighting_function`).
    knots
        Spline coefficients of the response per channel (at least 4).
    degree
        Total degree of ``ln F``'s Legendre polynomial.
    blocks
        Block means per frame side (fewer on a smaller frame); a block enters an exposure's
        rows only where all its codes are between the levels.

    Returns
    -------
    numpy.ndarray or None
        (channel, code) ``exp(s)`` for every code ``0 .. n_codes - 1`` (0 at or below the
        black level, constant beyond the series' lowest and highest codes), relative
        exposure per code; None where the series has fewer usable block means than
        unknowns, or reaches fewer than two exposures in a channel.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    n_exp, ny, nx, n_ch = counts.shape
    edges_y = np.linspace(0, ny, min(blocks, ny) + 1).round().astype(int)
    edges_x = np.linspace(0, nx, min(blocks, nx) + 1).round().astype(int)
    sizes = np.outer(np.diff(edges_y), np.diff(edges_x))
    powers = legendre_powers(degree)[1:]  # ln F without its constant (in each channel's s)
    spatial = _block_sums(np.moveaxis(flat_field_basis(powers, (ny, nx)), 0, -1), edges_y, edges_x)
    spatial = (spatial / sizes[..., None]).reshape(-1, len(powers))
    n_terms = len(powers)
    rows, targets, weights, spans = [], [], [], []
    for ch in range(n_ch):  # an exposure of a channel in memory at a time (large frames)
        span = _log_span(counts, ch, black_level, saturation)
        if span is None:
            return None
        lo, hi = span
        spans.append(span)
        used = 0
        for e in range(n_exp):
            codes = np.asarray(counts[e, ..., ch], dtype=np.float64)
            u, valid = _log_codes(codes, black_level, saturation)
            whole = (_block_sums(valid.astype(float), edges_y, edges_x) == sizes).ravel()
            if not whole.any() or hi <= lo:
                continue
            used += 1
            basis = _spline_design(u.ravel(), lo, hi, knots).reshape(ny, nx, knots)
            mean_basis = (_block_sums(basis, edges_y, edges_x) / sizes[..., None]).reshape(-1, knots)
            design = np.zeros((int(whole.sum()), n_terms + n_ch * knots))
            design[:, :n_terms] = -spatial[whole]
            design[:, n_terms + ch * knots : n_terms + (ch + 1) * knots] = mean_basis[whole]
            rows.append(design)
            targets.append(np.full(int(whole.sum()), np.log(float(times[e]))))
            w = weighting_function(codes, black_level=black_level, saturation=saturation, kind=weighting)
            weights.append((_block_sums(w, edges_y, edges_x) / sizes).ravel()[whole])
        if used < 2:
            return None
    design = np.concatenate(rows)
    if design.shape[0] < 2 * design.shape[1]:
        return None
    root_w = np.sqrt(np.concatenate(weights))
    coefficients = np.linalg.lstsq(
        design * root_w[:, None], np.concatenate(targets) * root_w, rcond=None
    )[0]
    table = np.zeros((n_ch, n_codes))
    u, valid = _log_codes(np.arange(n_codes, dtype=np.float64), black_level, np.inf)
    for ch, (lo, hi) in enumerate(spans):
        s = coefficients[n_terms + ch * knots : n_terms + (ch + 1) * knots]
        table[ch] = np.where(valid, np.exp(_spline_design(u, lo, hi, knots) @ s), 0.0)
    return table


def white_reference_frames(
    counts: np.ndarray,
    times: np.ndarray,
    table: np.ndarray,
    black_level: float,
    saturation: float,
    *,
    weighting: Weighting = "gaussian",
) -> np.ndarray | None:
    """(y, x, channel) the white reference's exposure per second through ``table`` (from
    :func:`white_reference_response`), the exposures averaged in the log with the weights of
    the joint fit, ``exp(sum_e w ln(f^-1(c) / t) / sum_e w)``: each exposure as the fit
    weighted it (not as Robertson's merge does, by ``t^2``, which leaves the frame to the
    longest exposures and to the spline's misfit over their codes). None where a pixel has
    no weighted code in some channel.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    n_exp, ny, nx, n_ch = counts.shape
    log_times = np.log(np.asarray(times, dtype=np.float64))
    out = np.empty((ny, nx, n_ch))
    for ch in range(n_ch):  # an exposure of a channel in memory at a time (large frames)
        total, weighted = np.zeros((ny, nx)), np.zeros((ny, nx))
        for e in range(n_exp):
            codes = np.asarray(counts[e, ..., ch])
            level = table[ch][np.clip(codes, 0, table.shape[1] - 1)]
            w = weighting_function(codes, black_level=black_level, saturation=saturation, kind=weighting)
            w = np.where(level > 0, w, 0.0)
            weighted += w * (np.log(np.where(level > 0, level, 1.0)) - log_times[e])
            total += w
        if not np.all(total > 0):
            return None
        out[..., ch] = np.exp(weighted / total)
    return out


def band_block_statistics(
    signal: np.ndarray, blocks: int = RESPONSE_BLOCKS
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means and variances of dark-subtracted frames over blocks.

    Parameters
    ----------
    signal
        (..., y, x) dark-subtracted codes ``I - dark`` [DN].
    blocks
        Blocks per frame side (fewer on a smaller frame).

    Returns
    -------
    tuple
        (..., block) the block means and the variances of the pixels about them [DN, DN^2],
        and (block,) the pixels of each block.
    """
    ny, nx = signal.shape[-2:]
    edges_y = np.linspace(0, ny, min(blocks, ny) + 1).round().astype(int)
    edges_x = np.linspace(0, nx, min(blocks, nx) + 1).round().astype(int)
    sizes = np.outer(np.diff(edges_y), np.diff(edges_x))

    def sums(values: np.ndarray) -> np.ndarray:
        out = np.add.reduceat(np.add.reduceat(values, edges_y[:-1], axis=-2), edges_x[:-1], axis=-1)
        return out.reshape(*values.shape[:-2], -1)

    means = sums(signal) / sizes.ravel()
    variances = np.maximum(sums(signal * signal) / sizes.ravel() - means**2, 0.0)
    return means, variances, sizes.ravel()


def band_series_response(
    means: np.ndarray,
    variances: np.ndarray,
    sizes: np.ndarray,
    times: np.ndarray,
    usable: np.ndarray,
    n_codes: int,
    *,
    knots: int = KNOTS,
) -> np.ndarray | None:
    """One smooth response of the spectral camera from its white reference's band series.

    Each band's exposures of one block of the white reference see the same light ``g``
    (the band's illuminant, ``Q_lambda`` and the block's flat field), so over the block's
    exposures ``s(ln d) = c + ln t`` (``d`` the block's mean dark-subtracted code, ``t``
    the exposure time, ``c = ln g`` one unknown per band and block): the ratio between two
    exposures of a block depends on the response alone, whatever the falloff. With ``c``
    eliminated (each band's and block's rows centred over its exposures) ``s``, a cubic
    spline of ``knots`` coefficients in the log code shared by the bands, is fitted by
    weighted least squares (weights: the inverse variance of ``ln d``, from the scatter of
    the block's pixels); the bands' different brightnesses and the falloff spread the
    blocks' codes over the range the series reaches. A response too smooth to follow a
    ripple: the camera's recovered OECF, whose slope ripples where its samples are few,
    reads as falloff when a band's frame is linearised through it.

    Parameters
    ----------
    means, variances
        (band, exposure, block) :func:`band_block_statistics` of the dark-subtracted frames.
    sizes
        (block,) pixels per block.
    times
        (exposure,) exposure times [s].
    usable
        (band, exposure) frames that enter (unsaturated, above the noise); a block of a
        frame enters where its mean is positive.
    n_codes
        Dark-subtracted codes of the returned table (``2**bit_depth``).
    knots
        Spline coefficients of the response (at least 4).

    Returns
    -------
    numpy.ndarray or None
        (code,) ``f(d)`` for ``d = 0 .. n_codes - 1``, relative exposure up to a scale:
        ``exp(s(ln d))`` over the codes the blocks reach, linear through 0 below them (a
        camera is linear at its lowest signal), continued with the spline's end slope in
        the log above them. None where fewer than two exposures of some band and block
        enter, or fewer rows than twice the unknowns.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    .. [2] M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic
       range enhancement using multiple exposures", Journal of Electronic Imaging 12(2), 2003.
    """
    enter = usable[..., None] & (means > 0)
    u = np.log(np.where(enter, means, 1.0))
    weights = np.where(enter, sizes * means**2 / np.maximum(variances, 1e-12 * means**2 + 1e-300), 0.0)
    weights = np.where(enter.sum(axis=1, keepdims=True) >= 2, weights, 0.0)
    rows = weights > 0
    if rows.sum() < 2 * knots or not enter.any():
        return None
    lo, hi = float(u[rows].min()), float(u[rows].max())
    if not hi > lo:
        return None
    design = _spline_design(u.ravel(), lo, hi, knots).reshape(*u.shape, knots)
    target = np.broadcast_to(np.log(np.asarray(times, dtype=np.float64))[None, :, None], u.shape)
    total = np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
    design = design - (weights[..., None] * design).sum(axis=1, keepdims=True) / total[..., None]
    target = target - (weights * target).sum(axis=1, keepdims=True) / total
    root_w = np.sqrt(weights[rows])
    coefficients = np.linalg.lstsq(design[rows] * root_w[:, None], target[rows] * root_w, rcond=None)[0]
    return _band_table(coefficients, lo, hi, knots, n_codes)


def _band_table(coefficients: np.ndarray, lo: float, hi: float, knots: int, n_codes: int) -> np.ndarray:
    """(code,) ``exp(s(ln d))`` of the spline ``coefficients`` on ``[lo, hi]`` for ``d = 0 ..
    n_codes - 1``: linear through 0 below ``exp(lo)``, the spline's end slope in the log above
    ``exp(hi)``."""
    inner = np.linspace(lo, hi, knots - 2)
    step = inner[1] - inner[0]
    knot_vector = np.concatenate(
        [inner[0] - step * np.arange(3, 0, -1), inner, inner[-1] + step * np.arange(1, 4)]
    )
    spline = BSpline(knot_vector, coefficients, 3)
    codes = np.arange(n_codes, dtype=np.float64)
    u = np.log(np.maximum(codes, np.exp(lo)))
    s = np.where(u > hi, spline(hi) + spline.derivative()(hi) * (u - hi), spline(np.clip(u, lo, hi)))
    table = np.exp(s)
    below = codes < np.exp(lo)
    table[below] = codes[below] * np.exp(spline(lo) - lo)
    return table
