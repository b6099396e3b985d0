"""The 3 x 3 map of one RGB camera's HDR RGB onto another's, through their camera matrices.

The reconstruction (eq. 1) has one camera matrix ``C`` per run: the paired camera's, whose RGB
image each band shot pairs with. An image of another RGB camera ``k`` measures
``R_k = C_k S``; mapped by ``M_k`` it reads as the paired camera would have seen it,
``M_k R_k ~ C_ref S``. ``M_k`` is the least-squares map over the calibration spectra (the
chart's patches and the white reference under the measured illuminant, the spectra the
run's samples are lit by)::

    M_k = argmin_M  sum_s || M C_k s - C_ref s ||^2 = (C_ref G C_k^T) (C_k G C_k^T)^-1,

with ``G = S^T S`` the spectra's second moment. It is exact for cameras of one model (then
``M_k`` is the ratio of their gains) and leaves a metameric residual between models (what
``camera_relative_error`` of each camera measures through ``C_k``).

References
----------
Fast Capture of Spectral Image Series, sec. 3, eq. 1 (the RGB term ``C S``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["rgb_transform"]


def rgb_transform(c_camera: np.ndarray, c_reference: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """``M`` (3, 3) with ``M @ (C_camera s) ~ C_reference s`` over ``spectra`` (n, wavelength).

    Parameters
    ----------
    c_camera, c_reference
        Camera matrices (channel, wavelength) on one wavelength grid.
    spectra
        Spectra the map is fitted over (patch, wavelength), e.g. chart reflectance times
        the illuminant.

    Returns
    -------
    numpy.ndarray
        ``M`` (channel of the reference, channel of the camera), float64.
    """
    a = np.asarray(c_camera, float) @ np.asarray(spectra, float).T  # (3, n): camera's RGB
    b = np.asarray(c_reference, float) @ np.asarray(spectra, float).T  # (3, n): reference's RGB
    gram = a @ a.T
    return np.linalg.solve(gram + 1e-12 * np.trace(gram) * np.eye(3), a @ b.T).T
