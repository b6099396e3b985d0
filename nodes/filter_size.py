"""Filter size ``s_i`` (eq. 3) to the Gaussian the paper filters with.

The paper sets the Gaussian's standard deviation to ``sigma_i = s_i / 5`` and places filter
centres ``s_i`` from the image borders, so a kernel reaches ``s_i`` (5 sigma) and never leaves
the image. Reconstruction (filter operator, filtered-band baselines) and the low-SNR OECF
extension both filter noisy band images this way; this module is the one place that says how.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Filtering" and "Filter Placement".
"""

from __future__ import annotations

__all__ = ["SIGMA_PER_FILTER_SIZE", "FILTER_TRUNCATE", "filter_sigma", "filter_radius"]

SIGMA_PER_FILTER_SIZE: float = 0.2
"""``sigma_i = s_i / 5`` (paper section 3)."""

FILTER_TRUNCATE: float = 5.0
"""Kernel support in sigmas: ``5 sigma_i = s_i``, the distance of a centre from the border."""


def filter_sigma(filter_size: float) -> float:
    """Standard deviation ``sigma_i = s_i / 5`` [px] of the Gaussian of filter size ``s_i`` [px].

    Parameters
    ----------
    filter_size
        ``s_i`` in pixels (eq. 3).

    Returns
    -------
    float
        ``sigma_i`` in pixels.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, eq. 3 and "Filtering".
    """
    return SIGMA_PER_FILTER_SIZE * float(filter_size)


def filter_radius(filter_size: float, *, truncate: float = FILTER_TRUNCATE) -> float:
    """Kernel radius [px] of a Gaussian of filter size ``s_i`` truncated at ``truncate`` sigmas.

    With the default ``truncate = 5`` the radius is ``s_i`` itself, the paper's support.

    Parameters
    ----------
    filter_size
        ``s_i`` in pixels (eq. 3).
    truncate
        Support in units of ``sigma_i`` (``scipy.ndimage.gaussian_filter``'s ``truncate``).

    Returns
    -------
    float
        Radius in pixels.
    """
    return truncate * filter_sigma(filter_size)
