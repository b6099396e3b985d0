"""The natural-spectra prior: a Gaussian over spectra learnt from natural reflectances.

Natural radiances ``t = diag(L) rho`` (reflectances ``rho`` of colour-science's RAW-to-ACES
v1 training set, :func:`~..baselines.training.training_reflectances`, lit by the
illuminant ``L`` estimated from the run's band shots,
:func:`~..baselines.training.estimate_illuminant`) give the prior's statistics

``mu = E[t]``,  ``Sigma = E[(t - mu)(t - mu)^T]``,  ``K = E[t t^T] = Sigma + mu mu^T``.

A pixel's spectrum is ``S_p = b_p t`` with an unknown shading scale ``b_p``, so the prior
is taken about the origin with second moment ``K`` (its scale is set by the pixel's RGB).
Combined with the RGB term ``R_p = C_m S_p + n`` of the pixel's image ``m`` (camera matrix
``C_m``, noise ``n ~ N(0, s I)``) it is the Wiener posterior [1]_ [2]_

``m_p = K C_m^T (C_m K C_m^T + s I)^-1 R_p``,
``P_m = K - K C_m^T (C_m K C_m^T + s I)^-1 C_m K``,

the estimate of the RGB-only baseline ``"wiener"`` (same reflectances, same illuminant, same
``s``); combined with eq. 1's band term it is the full posterior, which
:func:`~.prior_pcg.prior_pcg` minimises with the term
``sum_p v_p (S_p - m_p)^T Q (S_p - m_p)`` (:func:`~.spectral_prior.spectral_prior_term`,
source ``"natural"``), ``v_p`` weighed per pixel by the band evidence
(:mod:`.band_evidence`).

References
----------
.. [1] Hardeberg, J. Y., Schmitt, F., Brettel, H. (1999). Multispectral image capture
   using a tunable filter. Proc. SPIE 3963 (Wiener estimation of spectra from camera
   responses).
.. [2] Kay, S. M. (1993). Fundamentals of Statistical Signal Processing: Estimation
   Theory, section 11.6 (the linear Gaussian posterior, eqs. 10.28-10.29).
.. [3] Fast Capture of Spectral Image Series, section 2 ("Hybrid Methods").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spectralize.schemas.errors import ReconstructionError

from ..baselines.training import estimate_illuminant, training_reflectances
from ..baselines.wiener import WIENER_RELATIVE_NOISE, wiener_from_rgb
from ..inputs import ReconstructionInputs

__all__ = ["NaturalStatistics", "natural_statistics", "natural_prior"]


@dataclass(frozen=True)
class NaturalStatistics:
    """Mean, covariance and second moment of sample spectra ``(n_wavelength, n)``.

    Attributes
    ----------
    mean
        ``mu``, ``(n_wavelength,)``.
    covariance
        ``Sigma``, ``(n_wavelength, n_wavelength)``, normalised by ``n`` (maximum
        likelihood), symmetric positive semi-definite.
    second_moment
        ``K = Sigma + mu mu^T``, ``(n_wavelength, n_wavelength)``.
    """

    mean: np.ndarray
    covariance: np.ndarray
    second_moment: np.ndarray


def natural_statistics(spectra: np.ndarray) -> NaturalStatistics:
    """``mu``, ``Sigma`` and ``K`` of sample spectra (see the module docstring).

    Parameters
    ----------
    spectra
        ``(n_wavelength, n_samples)``, e.g. radiances ``diag(L) rho``.

    Returns
    -------
    NaturalStatistics

    Raises
    ------
    ReconstructionError
        If ``spectra`` is not 2-D with at least two samples, or not finite.
    """
    spectra = np.asarray(spectra, dtype=np.float64)
    if spectra.ndim != 2 or spectra.shape[1] < 2:
        raise ReconstructionError.single(
            "spectra", "(n_wavelength, n_samples >= 2)", f"shape {spectra.shape}"
        )
    if not np.isfinite(spectra).all():
        raise ReconstructionError.single(
            "spectra",
            "finite values",
            f"{int(np.isnan(spectra).sum())} NaN and {int(np.isinf(spectra).sum())} inf",
        )
    mean = spectra.mean(axis=1)
    centred = spectra - mean[:, None]
    covariance = centred @ centred.T / spectra.shape[1]
    covariance = 0.5 * (covariance + covariance.T)
    return NaturalStatistics(mean, covariance, covariance + np.outer(mean, mean))


def natural_prior(inputs: ReconstructionInputs) -> tuple[np.ndarray, NaturalStatistics]:
    """The natural prior under the run's illuminant, conditioned on each pixel's RGB.

    Parameters
    ----------
    inputs
        The checked input arrays (their band shots give the illuminant estimate, their
        camera matrix, one per image or shared, the RGB term).

    Returns
    -------
    centre : numpy.ndarray
        The Wiener posterior mean ``m_p`` of every pixel, ``(n_wavelength, n_image,
        height, width)``, float64 (the baseline ``"wiener"``'s estimate).
    statistics : NaturalStatistics
        ``mu``, ``Sigma`` and ``K`` of the lit training radiances.
    """
    reflectances = training_reflectances(inputs.wavelength)
    radiances = estimate_illuminant(inputs, reflectances)[:, None] * reflectances
    statistics = natural_statistics(radiances)
    centre = wiener_from_rgb(inputs, statistics.second_moment, WIENER_RELATIVE_NOISE)
    return centre.reshape(inputs.cube_shape), statistics
