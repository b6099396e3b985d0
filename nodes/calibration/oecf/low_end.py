"""The low end of an RGB camera's response: its toe, from the reverse regression.

Robertson's weights (:mod:`~.weighting`) fall to almost nothing a few percent of the code
range above the black level, so the codes there hardly enter the fit: the smooth response
(a spline over the well-weighted codes) reaches down to the black level with the shape it
has above. A consumer camera's response often has a strong *toe*: it rises slowly above
black, then steeper; the fitted response cannot follow it, and the HDR radiance of the
darkest pixels, merged from those codes, is off by tens of percent.

:func:`low_end_response` takes the codes under an *anchor* (the first code whose weight
reaches :data:`ANCHOR_WEIGHT` of the largest) from the model the spectral camera's low-SNR
extension uses at its dark level: each sample's exposure estimated from the pixel's other
samples at or above the anchor through the fitted response (leave one out), the mean code per
exposure bin
(the reverse regression, :func:`~.reverse_regression.reverse_regression`), which follows
any toe the samples show without the regression-to-the-mean bias and the ripples of the
per-code mean. Over the upper half of the codes between the first weighted code and the
anchor it is blended into the fitted response, so the two join continuously; the result is
non-decreasing.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration") and Fig. 2.
.. [2] M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2),
   219-228, 2003.
"""

from __future__ import annotations

import numpy as np

from spectralize.nodes.calibration.oecf.reverse_regression import (
    exposure_estimates,
    reverse_regression,
)

__all__ = ["ANCHOR_WEIGHT", "low_end_anchor", "low_end_response"]

ANCHOR_WEIGHT = 0.02
"""The low end's anchor: the first code whose weight reaches this share of the largest weight
(Robertson's Gaussian weighting reaches it a few percent of the code range above the black
level). The codes under it are the low end; the fitted response is kept from it up."""

EXPOSURE_MARGIN = 1.25
"""Samples whose exposure estimate is at most this many times the response at the anchor
enter the reverse regression (a margin over the anchor, so the bins near it are full)."""

MIN_LOW_END_CODES = 4
"""Fewer codes than this between the first weighted code and the anchor: no low end to fit."""


def low_end_anchor(weights: np.ndarray, anchor_weight: float = ANCHOR_WEIGHT) -> tuple[int, int] | None:
    """``(first, anchor)``: the first code of non-zero weight and the low end's anchor (the
    first code under the weight's peak whose weight reaches ``anchor_weight`` of the
    largest); None where there is no low end (fewer than :data:`MIN_LOW_END_CODES` codes
    between them)."""
    positive = np.flatnonzero(weights > 0)
    if positive.size == 0:
        return None
    peak = int(np.argmax(weights))
    codes = np.arange(weights.size)
    reached = np.flatnonzero((weights >= anchor_weight * weights.max()) & (codes <= peak))
    first, anchor = int(positive[0]), int(reached[0]) if reached.size else peak
    if anchor - first < MIN_LOW_END_CODES:
        return None
    return first, anchor


def low_end_response(
    response: np.ndarray,
    codes: np.ndarray,
    times: np.ndarray,
    weights: np.ndarray,
    anchor_weight: float = ANCHOR_WEIGHT,
) -> np.ndarray:
    """``response`` with its codes under the anchor from the reverse regression.

    Parameters
    ----------
    response
        The fitted response at every code (non-decreasing), ``(n_codes,)``.
    codes
        Integer pixel values ``(image, exposure, pixel)`` the response was fitted to.
    times
        Exposure times ``(image, exposure)`` [s].
    weights
        The fit's weight of every code ``(n_codes,)`` (0: under-exposed or saturated).
    anchor_weight
        See :data:`ANCHOR_WEIGHT`.

    Returns
    -------
    numpy.ndarray
        The response at every code: the reverse regression's under the first weighted code
        and up to the middle of the low end, blended linearly into ``response`` from there
        to the anchor, ``response`` from the anchor up; non-negative and non-decreasing.
        ``response`` itself where there is no low end or no sample in it.
    """
    ends = low_end_anchor(weights, anchor_weight)
    if ends is None:
        return response
    first, anchor = ends
    top = EXPOSURE_MARGIN * float(response[anchor])
    # each sample's exposure from the pixel's other samples at or above the anchor only: the
    # fitted response under it is what is being replaced
    trusted = np.where(np.arange(weights.size) >= anchor, weights, 0.0)
    exposures, values = [], []
    for g in range(codes.shape[0]):
        estimate = exposure_estimates(codes[g], times[g], trusted, response)
        keep = np.isfinite(estimate) & (estimate <= top)
        exposures.append(estimate[keep])
        values.append(codes[g][keep].astype(np.float64))
    exposure, value = np.concatenate(exposures), np.concatenate(values)
    if exposure.size == 0:
        return response
    grid = np.arange(anchor + 1, dtype=np.float64)
    levels = np.maximum.accumulate(np.maximum(response[: anchor + 1], 0.0))
    low = reverse_regression(exposure, value, levels, grid)
    start = first + (anchor - first) // 2
    blend = np.clip((grid - start) / (anchor - start), 0.0, 1.0)
    out = np.array(response, dtype=np.float64)
    out[: anchor + 1] = np.maximum((1.0 - blend) * low + blend * response[: anchor + 1], 0.0)
    return np.maximum.accumulate(out)
