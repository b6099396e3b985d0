"""Per-pixel projection of spectra onto the RGB constraint ``C S(p) = R(p)`` (eq. 1, second term).

Shared by the baselines that end in the RGB-consistent subspace (``"filtered-projected"``,
``"guided-projected"``).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, eq. 1.
"""

from __future__ import annotations

import numpy as np

__all__ = ["project_onto_rgb"]


def project_onto_rgb(cube: np.ndarray, camera_matrix: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Smallest per-pixel change of ``cube`` that makes ``C S(p) = R(p)`` exact.

    ``S = B + C^T (C C^T)^-1 (R - C B)``.

    Parameters
    ----------
    cube
        ``(n_wavelength, ...)`` spectra ``B``.
    camera_matrix
        ``C``, ``(3, n_wavelength)``.
    rgb
        ``R``, ``(3, ...)`` with the same trailing shape as ``cube``.

    Returns
    -------
    numpy.ndarray
        Shaped like ``cube``.
    """
    n_wavelength = cube.shape[0]
    flat = cube.reshape(n_wavelength, -1)
    gap = rgb.reshape(3, -1) - camera_matrix @ flat
    correction = camera_matrix.T @ np.linalg.solve(camera_matrix @ camera_matrix.T, gap)
    return (flat + correction).reshape(cube.shape)
