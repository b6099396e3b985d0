"""Baseline ``"wiener"``: Wiener estimation from RGB with a training-set prior."""

from __future__ import annotations

import numpy as np

from ..inputs import ReconstructionInputs
from .training import estimate_illuminant, training_reflectances

__all__ = ["wiener_estimation", "WIENER_RELATIVE_NOISE"]

WIENER_RELATIVE_NOISE = 1e-4
"""Noise ``s`` of the Wiener estimate relative to the mean RGB signal power ``trace(C K C^T) / 3``."""


def wiener_estimation(
    inputs: ReconstructionInputs, *, relative_noise: float = WIENER_RELATIVE_NOISE
) -> np.ndarray:
    """Wiener estimation (linear regression) from RGB with a training-set prior.

    ``S = K C^T (C K C^T + s I)^-1 R`` with ``K = E[t t^T]`` over the training radiances
    ``t = diag(L) rho`` (colour-science's RAW-to-ACES reflectances ``rho``, illuminant ``L``
    from :func:`~.training.estimate_illuminant`) and
    ``s = relative_noise * trace(C K C^T) / 3``.

    Parameters
    ----------
    inputs
        The checked input arrays.
    relative_noise
        Noise ``s`` relative to the mean RGB signal power.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``.

    References
    ----------
    .. [1] Hardeberg et al. (1999); Fast Capture of Spectral Image Series, section 2.
    """
    reflectances = training_reflectances(inputs.wavelength)
    radiances = estimate_illuminant(inputs, reflectances)[:, None] * reflectances
    second_moment = radiances @ radiances.T / radiances.shape[1]
    c = inputs.camera_matrix
    projected = c @ second_moment @ c.T
    noise = relative_noise * np.trace(projected) / 3
    operator = second_moment @ c.T @ np.linalg.inv(projected + noise * np.eye(3))
    return (operator @ inputs.rgb_pixels()).reshape(inputs.cube_shape)
