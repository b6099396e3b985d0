"""Baseline ``"mallett2019"``: colour-science's Mallett and Yuksel (2019) basis."""

from __future__ import annotations

import numpy as np

from ..inputs import ReconstructionInputs
from .training import estimate_illuminant, training_reflectances

__all__ = ["mallett2019_basis"]


def mallett2019_basis(inputs: ReconstructionInputs) -> np.ndarray:
    """colour-science's Mallett and Yuksel (2019) basis, fitted to the camera RGB.

    The three sRGB basis reflectances of ``colour.recovery`` lit by the estimated illuminant
    span the spectra; per pixel the three coefficients reproduce ``R(p)`` exactly. (The
    library's ``RGB_to_sd_Mallett2019`` takes sRGB reflectance; here the camera matrix
    replaces the sRGB observer so that any camera's HDR radiance can be used.)

    Parameters
    ----------
    inputs
        The checked input arrays.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``, reproducing ``C S(p) = R(p)``.

    References
    ----------
    .. [1] Mallett and Yuksel (2019).
    """
    import colour

    basis_sds = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    grid = np.asarray(basis_sds.wavelengths, dtype=np.float64)
    basis = np.stack(
        [np.interp(inputs.wavelength, grid, basis_sds.values[:, j]) for j in range(3)], axis=1
    )  # (n_wavelength, 3)
    reflectances = training_reflectances(inputs.wavelength)
    lit = estimate_illuminant(inputs, reflectances)[:, None] * basis
    if not inputs.per_image_camera:
        coefficients = np.linalg.solve(inputs.camera_matrix @ lit, inputs.rgb_pixels())
        return (lit @ coefficients).reshape(inputs.cube_shape)
    rgb = inputs.rgb_pixels().reshape(3, inputs.n_image, -1)
    per_image = [
        lit @ np.linalg.solve(inputs.camera_of(m) @ lit, rgb[:, m]) for m in range(inputs.n_image)
    ]
    return np.stack(per_image, axis=1).reshape(inputs.cube_shape)
