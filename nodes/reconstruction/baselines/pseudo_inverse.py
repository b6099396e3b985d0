"""Baseline ``"pseudo-inverse"``: ``S(p) = C^+ R(p)`` (Imai and Berns)."""

from __future__ import annotations

import numpy as np

from ..inputs import ReconstructionInputs

__all__ = ["pseudo_inverse"]


def pseudo_inverse(inputs: ReconstructionInputs) -> np.ndarray:
    """RGB pseudo-inverse, ``S(p) = C^+ R(p)`` (Imai and Berns).

    Parameters
    ----------
    inputs
        The checked input arrays.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``: per pixel the minimum-norm spectrum with
        the measured RGB.

    References
    ----------
    .. [1] Imai and Berns (1998); Fast Capture of Spectral Image Series, section 2.
    """
    rgb = inputs.rgb_pixels()
    if not inputs.per_image_camera:
        return (np.linalg.pinv(inputs.camera_matrix) @ rgb).reshape(inputs.cube_shape)
    rgb = rgb.reshape(3, inputs.n_image, -1)
    per_image = [np.linalg.pinv(inputs.camera_of(m)) @ rgb[:, m] for m in range(inputs.n_image)]
    return np.stack(per_image, axis=1).reshape(inputs.cube_shape)
