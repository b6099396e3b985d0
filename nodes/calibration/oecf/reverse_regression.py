"""The reverse regression of a response: the mean pixel value per exposure, ``E[v | X]``.

Robertson's update takes the mean exposure per code, ``E[X | v]``: a regression of exposure on
the code, with the noise in the code. Where the noise is as large as the response's slope
(a few DN above the dark level: the spectral camera's low-SNR range, an RGB camera's toe) that
mean is pulled towards the exposures the samples crowd at, and ripples with them. The reverse
regression bins the samples by their exposure, estimated without the sample's own noise
(:func:`exposure_estimates`, leave one out), and takes the mean value per bin, which the
noise in the code averages out of. The paper's low-SNR extension
(:mod:`~spectralize.nodes.calibration.oecf.low_snr`) and the low end of the RGB response
(:mod:`~spectralize.nodes.calibration.oecf.low_end`) both use it.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration") and Fig. 2.
.. [2] M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2),
   219-228, 2003.
"""

from __future__ import annotations

import numpy as np

from spectralize.nodes.calibration.oecf.response import lookup

__all__ = ["exposure_estimates", "reverse_regression"]


def exposure_estimates(
    codes: np.ndarray, times: np.ndarray, weights: np.ndarray, response: np.ndarray
) -> np.ndarray:
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


def reverse_regression(
    exposure: np.ndarray, values: np.ndarray, levels: np.ndarray, grid: np.ndarray
) -> np.ndarray:
    """Response on ``grid`` from the mean pixel value per exposure bin, ``E[v | X]``.

    Samples are binned by exposure ``X`` at the midpoints of ``levels`` (a non-decreasing
    response on ``grid``); per bin the mean ``X`` and mean ``v`` are one point of the curve
    ``v = f^-1(X)``. The points are made monotone (pool adjacent violators, weighted by the
    samples per bin) and interpolated at ``grid`` (linear); beyond the outermost points the
    shape of ``levels`` is kept, scaled to join continuously.
    """
    from scipy.optimize import isotonic_regression

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
    v_mean = isotonic_regression(np.bincount(b, v, minlength=grid.size)[seen] / n, weights=n).x
    v_points, which = np.unique(v_mean, return_inverse=True)
    if v_points.size < 2:
        return levels.copy()
    x_points = np.bincount(which, x_mean * n) / np.bincount(which, n)
    out = lookup(grid, x_points, v_points)
    # beyond the outermost bin means the reverse regression has no data: there the table
    # keeps the shape of ``levels``, scaled to join continuously (no extrapolated slope)
    for end, outside in ((0, grid < v_points[0]), (-1, grid > v_points[-1])):
        if outside.any():
            ref = float(np.interp(v_points[end], grid, levels))
            if ref > 0:
                out[outside] = levels[outside] * (x_points[end] / ref)
    return out
