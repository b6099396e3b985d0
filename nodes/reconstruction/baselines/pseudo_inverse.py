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
    return (np.linalg.pinv(inputs.camera_matrix) @ rgb).reshape(inputs.cube_shape)
