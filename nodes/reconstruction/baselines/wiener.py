"""Baseline ``"wiener"``: Wiener estimation from RGB with a training-set prior."""

from __future__ import annotations

import numpy as np

from ..inputs import ReconstructionInputs
from .training import estimate_illuminant, training_reflectances

__all__ = ["wiener_estimation", "wiener_from_rgb", "WIENER_RELATIVE_NOISE"]

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
    return wiener_from_rgb(inputs, second_moment, relative_noise)


def wiener_from_rgb(
    inputs: ReconstructionInputs, second_moment: np.ndarray, relative_noise: float
) -> np.ndarray:
    """``K C^T (C K C^T + s I)^-1 R`` for every pixel (per image with its own ``C_m`` where
    :attr:`~..inputs.ReconstructionInputs.camera_matrix` has one per image), as a cube
    ``(n_wavelength, n_image, height, width)``; ``s = relative_noise * trace(C K C^T) / 3``.
    """

    def operator(c: np.ndarray) -> np.ndarray:
        projected = c @ second_moment @ c.T
        noise = relative_noise * np.trace(projected) / 3
        return second_moment @ c.T @ np.linalg.inv(projected + noise * np.eye(3))

    if not inputs.per_image_camera:
        return (operator(inputs.camera_matrix) @ inputs.rgb_pixels()).reshape(inputs.cube_shape)
    rgb = inputs.rgb_pixels().reshape(3, inputs.n_image, -1)
    cube = np.stack([operator(inputs.camera_of(m)) @ rgb[:, m] for m in range(inputs.n_image)], axis=1)
    return cube.reshape(inputs.cube_shape)
