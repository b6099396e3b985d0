"""Per-pixel band evidence between the natural prior and an estimate learnt from the bands.

Two estimates of a cube, the natural prior's Wiener estimate ``a`` (:mod:`.natural_prior`,
from the RGB and training reflectances only) and an estimate ``b`` learnt from the band
shots (the endmember mixture), each predict every band shot ``D_i`` (wavelength ``b_i`` of
image ``m_i``, white noise ``sigma_i``,
:func:`~..estimators.endmember_mixture.band_noise_sigma`). Under Gaussian noise the
log-likelihood ratio of ``b`` over ``a`` at a pixel, over its shots (pooled over a
``w x w`` window ``W(p)`` if ``w > 1``), is [1]_

``Lambda_p = sum_i sum_{q in W(p)} [(D_i(q) - a_{b_i}(q))^2 - (D_i(q) - b_{b_i}(q))^2]
/ (2 sigma_i^2)``.

Pixels that look alike, the same chromaticity ``(r, g) / (r + g + b)`` and relative
brightness (an ``n_c x n_c x n_l`` histogram, the brightness bins in log2 steps), are
mostly the same material, maybe under other light, so the estimate that fits one fits the
others more often than not. Each pixel's prior log-odds are the evidence of an average
pixel of its bin with a shot of each of the ``n_b`` wavelengths (empirical Bayes [2]_):

``Lambda_p <- Lambda_p + n_b lambda_bin(p)``,  ``lambda_bin = mean_q Lambda_q / n_q``

over the pixels ``q`` with shots in the bin, ``n_q`` their shots (0 where none looks
alike). A pixel with shots weighs its own evidence against its material's typical one; an
image of a set without band shots takes its evidence from the latter alone.

``b`` was learnt from the same shots, so it is only as credible as the information they
carry: the prior odds of ``a`` are ``1 + 1 / I_bin(p)``, with
``I_bin = sum_q sum_i a_{b_i}(q)^2 / sigma_i^2`` the band signal-to-noise energy (Fisher
information about the spectra's level) of the pixels with shots in the bin, the signal as
the RGB predicts it (``b``'s own prediction grows with the noise it fitted). Where the
bins' shots are informative (``I >> 1``, any real capture) the odds are even; where the
bands are pure noise (``I -> 0``) or no pixel with shots looks alike, ``a`` wins. The
posterior probability of ``a`` is

``pi_p = 1 / (1 + exp(Lambda_p) / (1 + 1 / I_bin(p)))``.

Where the bands are informative and favour one estimate, ``pi_p`` goes to 0 or 1; where
they say little (dark pixels, band SNR at or below 1: both residuals are the noise) it
stays near 1/2 (the centre between the two, whose errors partly cancel), or goes to 1 if
they say nothing at all.

References
----------
.. [1] Kass, R. E., Raftery, A. E. (1995). Bayes factors. Journal of the American
   Statistical Association 90(430).
.. [2] Efron, B., Morris, C. (1975). Data analysis using Stein's estimator and its
   generalizations. Journal of the American Statistical Association 70(350).
.. [3] Fast Capture of Spectral Image Series, section 3 (band shots, eq. 2).
"""

from __future__ import annotations

import numpy as np

from spectralize.schemas.errors import ParameterError

from ..estimators.endmember_mixture import band_noise_sigma
from ..inputs import ReconstructionInputs
from ..neighbourhoods import appearance_bins

__all__ = ["band_evidence", "EVIDENCE_WINDOW", "MAX_LOG_RATIO", "TRANSFER_BINS"]

EVIDENCE_WINDOW = 1
"""``w``: the side in pixels of the window the evidence is pooled over (1: the pixel's
own shots; wider windows favour the mixture, which the band shots themselves corrected
locally, so its residuals there are smaller than its error)."""

TRANSFER_BINS = (32, 8)
"""``(n_c, n_l)``: chromaticity bins per axis and brightness bins (log2 steps from 1/16 of
the image's mean) of the appearance histogram."""

MAX_LOG_RATIO = 50.0
"""``|Lambda_p|`` is clipped here before the exponential (``pi_p`` is then 0 or 1 to
float64 precision anyway)."""


def band_evidence(
    inputs: ReconstructionInputs,
    natural: np.ndarray,
    learnt: np.ndarray,
    *,
    window: int = EVIDENCE_WINDOW,
    sigma: np.ndarray | None = None,
) -> np.ndarray:
    """``pi_p``: the posterior probability of ``natural`` over ``learnt`` (module docstring).

    Parameters
    ----------
    inputs
        The checked input arrays (band shots, their wavelength and image).
    natural, learnt
        ``a`` and ``b`` of the module docstring, ``(n_wavelength, n_image, height, width)``.
    window
        ``w``, >= 1.
    sigma
        Per shot the noise standard deviation; None: estimated from the shots
        (:func:`~..estimators.endmember_mixture.band_noise_sigma`).

    Returns
    -------
    numpy.ndarray
        ``pi_p``, ``(n_image, height, width)`` in [0, 1], float64.

    Raises
    ------
    ReconstructionError
        If an estimate's shape is not ``inputs.cube_shape``.
    ParameterError
        If ``window < 1``.
    """
    from scipy import ndimage

    inputs.check_cubes(natural=natural, learnt=learnt)
    if window < 1:
        raise ParameterError.single("window", ">= 1 (pixels)", window)
    if sigma is None:
        sigma = band_noise_sigma(inputs)
    shape = (inputs.n_image, inputs.height, inputs.width)
    log_ratio = np.zeros(shape)
    information = np.zeros(shape)  # sum_i a_{b_i}^2 / sigma_i^2 per pixel
    for i in range(len(inputs.band)):
        b, m = int(inputs.band[i]), int(inputs.image[i])
        variance = max(float(sigma[i]), 1e-30) ** 2
        difference = inputs.shot_log_ratio_terms(i, natural, learnt)
        if window > 1:
            difference = ndimage.uniform_filter(difference, window, mode="reflect") * window**2
        log_ratio[m] += difference / (2.0 * variance)
        information[m] += np.asarray(natural[b, m], dtype=np.float64) ** 2 / variance
    band = np.asarray(inputs.band)
    shots = np.array(  # n_p: shots of distinct wavelengths per image
        [np.unique(band[np.asarray(inputs.image) == m]).size for m in range(inputs.n_image)],
        dtype=np.float64,
    )
    bins = _appearance_bins(inputs.rgb)
    size = int(np.prod(TRANSFER_BINS[:1]) ** 2 * TRANSFER_BINS[1])
    known = shots > 0
    if known.any():
        per_shot = log_ratio[known] / shots[known][:, None, None]
        sums = np.bincount(bins[known].ravel(), weights=per_shot.ravel(), minlength=size)
        counts = np.bincount(bins[known].ravel(), minlength=size)
        log_ratio += inputs.n_wavelength * (sums / np.maximum(counts, 1))[bins]
    pooled = np.bincount(bins[known].ravel(), weights=information[known].ravel(), minlength=size)
    log_ratio -= np.log1p(1.0 / np.maximum(pooled[bins], 1e-300))  # prior odds of ``natural``
    np.clip(log_ratio, -MAX_LOG_RATIO, MAX_LOG_RATIO, out=log_ratio)
    return 1.0 / (1.0 + np.exp(log_ratio))


def _appearance_bins(rgb: np.ndarray) -> np.ndarray:
    """Per pixel of ``rgb`` ``(n_image, height, width, 3)`` its histogram bin (module
    docstring; brightness relative to its image's mean), ``(n_image, height, width)``
    integers."""
    rgb = np.maximum(np.asarray(rgb, dtype=np.float64), 0)
    return appearance_bins(rgb, rgb.sum(axis=-1).mean(axis=(1, 2), keepdims=True), TRANSFER_BINS)
