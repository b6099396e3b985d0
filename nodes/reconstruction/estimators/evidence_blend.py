"""A set's two estimates weighed per texel by the band evidence: the default's spectra and
the material choice's.

Two estimates of a set's cube, ``a`` (the default: eq. 1 with its priors and its set model)
and ``b`` (each texel's few endmembers chosen over the set, :mod:`.sparse_choice`), each
predict every band shot ``D_i`` (wavelength ``b_i`` of image ``m_i``, white noise
``sigma_i``, :func:`~.endmember_mixture.band_noise_sigma`). The choice is made per texel,
not per image, so the evidence of a texel ``p`` is pooled over all its images' shots:
under Gaussian noise the log-likelihood ratio of ``b`` over ``a`` is [1]_

``Lambda_p = sum_i [(D_i(p) - a_{b_i m_i}(p))^2 - (D_i(p) - b_{b_i m_i}(p))^2]
/ (2 sigma_i^2)``.

Texels that look alike over the set, the same chromaticity ``(r, g) / (r + g + b)`` and
relative brightness of their RGB averaged over the images (each image's RGB relative to its
mean; an ``n_c x n_c x n_l`` histogram, the brightness bins in log2 steps), mostly hold the
same materials, so the estimate that fits one fits the others more often than not. As in
:mod:`~..solvers.band_evidence` each texel adds the evidence of an average texel of its bin
with a shot of each of the ``n_b`` wavelengths (empirical Bayes [2]_):

``Lambda_p <- Lambda_p + n_b lambda_bin(p)``,  ``lambda_bin = mean_q Lambda_q / n``,

``n`` the set's shots (every texel of a set has them all).

Both estimates were fitted to the same shots (eq. 1's band term, the choice's band
chi^2), so neither likelihood is an honest out-of-sample one, and the choice picked its
support among many by these shots. The default keeps prior log-odds ``c``: the choice must
show at least "strong" evidence on Kass and Raftery's scale (``ln B >= 3``) to reach even
odds. The posterior probability of the default is

``pi_p = 1 / (1 + exp(Lambda_p - c))``

and each image's spectra are the posterior mean of the two,

``S_mp = pi_p a_mp + (1 - pi_p) b_mp``.

Where the shots say little (band SNR near one per shot: both residuals are the noise) the
texel keeps the default; where its shots or its bin clearly prefer the choice (a material
the library holds, which the default's pooling smeared), the choice. Without band shots
there is no evidence and the default is kept.

As the default's set step (:func:`material_choice_blend`, ``set_model="evidence-blend"``)
the choice is made from the run's library (a set's own is too coarse for it) among each
texel's :data:`CHOICE_CANDIDATES` nearest endmembers by the dichromatic fit and the
highlight: the blend leans on the choice only where the evidence is strong, and there the
nearest endmembers are the ones the texel's RGB lines meet, so more candidates add cost
(their supports grow combinatorially) rather than weight.

References
----------
.. [1] Kass, R. E., Raftery, A. E. (1995). Bayes factors. Journal of the American
   Statistical Association 90(430) (the log-likelihood ratio; the scale of evidence).
.. [2] Efron, B., Morris, C. (1975). Data analysis using Stein's estimator and its
   generalizations. Journal of the American Statistical Association 70(350).
.. [3] Iordache, M.-D., Bioucas-Dias, J. M., Plaza, A. (2011). Sparse unmixing of
   hyperspectral data. IEEE Transactions on Geoscience and Remote Sensing 49(6) (the
   choice of few library endmembers per pixel).
.. [4] Fast Capture of Spectral Image Series, section 3 (band shots, eq. 2; the image sets).
"""

from __future__ import annotations

import numpy as np

from ..inputs import ReconstructionInputs
from ..neighbourhoods import appearance_bins
from .endmember_mixture import Endmembers, band_noise_sigma
from .sparse_choice import sparse_choice

__all__ = [
    "material_choice_blend",
    "evidence_blend",
    "choice_log_odds",
    "set_appearance_bins",
    "DEFAULT_PRIOR_LOG_ODDS",
    "APPEARANCE_BINS",
    "CHOICE_CANDIDATES",
]

DEFAULT_PRIOR_LOG_ODDS = 3.0
"""``c``: the default's prior log-odds over the choice (Kass and Raftery's "strong"
evidence, ``2 ln B >= 6``)."""

APPEARANCE_BINS = (32, 8)
"""``(n_c, n_l)``: chromaticity bins per axis and brightness bins (log2 steps from 1/16 of
the set's mean) of the texels' appearance histogram."""

CHOICE_CANDIDATES = 2
"""Endmembers each texel's choice picks from besides the highlight atom, as the set step."""

MAX_LOG_ODDS = 50.0
"""``|Lambda_p - c|`` is clipped here before the exponential."""


def set_appearance_bins(rgb: np.ndarray) -> np.ndarray:
    """Per texel of a set its appearance bin (module docstring).

    Parameters
    ----------
    rgb
        ``R``, ``(n_image, height, width, 3)``.

    Returns
    -------
    numpy.ndarray
        ``(height, width)`` bin indices in ``[0, n_c^2 n_l)``.
    """
    rgb = np.maximum(np.asarray(rgb, dtype=np.float64), 0.0)
    level = rgb.sum(axis=-1).mean(axis=(1, 2), keepdims=True)
    relative = (rgb / np.maximum(level, 1e-300)[..., None]).mean(axis=0)  # (y, x, 3)
    return appearance_bins(relative, relative.sum(axis=-1).mean(), APPEARANCE_BINS)


def choice_log_odds(
    inputs: ReconstructionInputs,
    default: np.ndarray,
    choice: np.ndarray,
    *,
    prior_log_odds: float = DEFAULT_PRIOR_LOG_ODDS,
    sigma: np.ndarray | None = None,
) -> np.ndarray:
    """``Lambda_p - c``: per texel the posterior log-odds of ``choice`` over ``default``
    (module docstring).

    Parameters
    ----------
    inputs
        The checked inputs of one set (pixel ``(y, x)`` the same texel in every image).
    default, choice
        ``a`` and ``b``, ``(n_wavelength, n_image, height, width)``.
    prior_log_odds
        ``c``, the default's prior log-odds.
    sigma
        Per shot the noise standard deviation; None: estimated from the shots
        (:func:`~.endmember_mixture.band_noise_sigma`).

    Returns
    -------
    numpy.ndarray
        ``(height, width)`` float64; ``-c`` everywhere when the set has no band shots.

    Raises
    ------
    ReconstructionError
        If an estimate's shape is not ``inputs.cube_shape``.
    """
    inputs.check_cubes(default=default, choice=choice)
    log_ratio = np.zeros((inputs.height, inputs.width))
    n_shot = len(inputs.band)
    if n_shot == 0:
        return log_ratio - float(prior_log_odds)
    if sigma is None:
        sigma = band_noise_sigma(inputs)
    for i in range(n_shot):
        log_ratio += inputs.shot_log_ratio_terms(i, default, choice) / (
            2.0 * max(float(sigma[i]), 1e-30) ** 2
        )
    bins = set_appearance_bins(inputs.rgb).ravel()
    size = APPEARANCE_BINS[0] ** 2 * APPEARANCE_BINS[1]
    sums = np.bincount(bins, weights=log_ratio.ravel() / n_shot, minlength=size)
    counts = np.bincount(bins, minlength=size)
    pooled = (sums / np.maximum(counts, 1))[bins].reshape(log_ratio.shape)
    return log_ratio + inputs.n_wavelength * pooled - float(prior_log_odds)


def evidence_blend(
    inputs: ReconstructionInputs,
    default: np.ndarray,
    choice: np.ndarray,
    *,
    prior_log_odds: float = DEFAULT_PRIOR_LOG_ODDS,
    sigma: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``S = pi a + (1 - pi) b`` per texel, ``pi`` the default's posterior probability
    (module docstring).

    Parameters
    ----------
    inputs, default, choice, prior_log_odds, sigma
        As :func:`choice_log_odds`.

    Returns
    -------
    spectra : numpy.ndarray
        ``(n_wavelength, n_image, height, width)`` float64.
    pi : numpy.ndarray
        ``(height, width)``: per texel the posterior probability of ``default``; 1 where
        the set has no band shots.

    Raises
    ------
    ReconstructionError
        If an estimate's shape is not ``inputs.cube_shape``.
    """
    log_odds = choice_log_odds(inputs, default, choice, prior_log_odds=prior_log_odds, sigma=sigma)
    if len(inputs.band) == 0:
        pi = np.ones_like(log_odds)
    else:
        pi = 1.0 / (1.0 + np.exp(np.clip(log_odds, -MAX_LOG_ODDS, MAX_LOG_ODDS)))
    a = np.asarray(default, dtype=np.float64)
    b = np.asarray(choice, dtype=np.float64)
    return b + pi * (a - b), pi


def material_choice_blend(
    inputs: ReconstructionInputs,
    cube: np.ndarray,
    endmembers: Endmembers,
    *,
    candidates: int = CHOICE_CANDIDATES,
    prior_log_odds: float = DEFAULT_PRIOR_LOG_ODDS,
) -> np.ndarray:
    """The set step after the default's set model: each texel's materials chosen over its
    set from the run's library (:func:`~.sparse_choice.sparse_choice`), and the set's
    spectra moved towards the choice's by the posterior of the band evidence
    (:func:`evidence_blend`).

    Parameters
    ----------
    inputs
        The checked inputs of one set, its images on one texel grid.
    cube
        ``a``, the set's spectra ``(n_wavelength, n_image, height, width)`` after the set
        model; overwritten by the blend.
    endmembers
        The run's library (:mod:`~..endmember_library`), on the bands' wavelengths.
    candidates
        Endmembers each texel chooses from besides the highlight atom.
    prior_log_odds
        ``c``, the default's prior log-odds.

    Returns
    -------
    numpy.ndarray
        ``cube``, blended in place: ``a + (1 - pi) (b - a)`` per texel. Left as it was
        where the set has no band shots.

    Raises
    ------
    ReconstructionError
        If ``cube`` is not ``inputs.cube_shape`` or the library is on other wavelengths.

    References
    ----------
    .. [1] Kass, R. E., Raftery, A. E. (1995). Bayes factors. Journal of the American
       Statistical Association 90(430).
    .. [2] Iordache, M.-D., Bioucas-Dias, J. M., Plaza, A. (2011). Sparse unmixing of
       hyperspectral data. IEEE Transactions on Geoscience and Remote Sensing 49(6).
    .. [3] Fast Capture of Spectral Image Series, section 3 (the image sets, eq. 2).
    """
    inputs.check_cubes(cube=cube)
    if len(inputs.band) == 0:
        return cube
    choice = sparse_choice(inputs, endmembers=endmembers, candidates=int(candidates))
    log_odds = choice_log_odds(inputs, cube, choice, prior_log_odds=prior_log_odds)
    weight = 1.0 - 1.0 / (1.0 + np.exp(np.clip(log_odds, -MAX_LOG_ODDS, MAX_LOG_ODDS)))
    for b in range(inputs.n_wavelength):  # plane by plane: no temporary of the cube's size
        plane = cube[b]
        np.add(plane, weight * (choice[b] - plane), out=plane, casting="same_kind")
    return cube
