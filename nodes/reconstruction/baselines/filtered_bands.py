"""Baselines ``"filtered-bands"`` and ``"filtered-projected"``: the paper's Gaussian filter alone.

Every band image is filtered by its own Gaussian (``sigma_i = s_i / 5``, truncated at
``5 sigma_i = s_i``, :mod:`spectralize.nodes.filter_size`); ``"filtered-projected"`` then
projects it per pixel onto ``C S = R``. The latter is the initial guess of the
``"block-jacobi-pcg"`` solver.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Filtering".
"""

from __future__ import annotations

import numpy as np

from spectralize.nodes.filter_size import FILTER_TRUNCATE, filter_sigma

from ..inputs import ReconstructionInputs
from .projection import project_onto_rgb

__all__ = ["filtered_bands", "filtered_bands_projected"]


def _blur(plane: np.ndarray, filter_size: float) -> np.ndarray:
    """The paper's Gaussian of filter size ``s_i`` over the whole image (reflecting borders)."""
    from scipy import ndimage

    return ndimage.gaussian_filter(
        plane, sigma=filter_sigma(filter_size), mode="reflect", truncate=FILTER_TRUNCATE
    )


def filtered_bands(inputs: ReconstructionInputs) -> np.ndarray:
    """Every band image filtered by its own Gaussian (``sigma = s_i / 5``) alone.

    Shots of the same band and image are averaged. An image without a shot of band ``b``
    gets ``w_b^T R(p)``, where ``w_b`` is the least-squares fit of the filtered band to the
    equally filtered RGB over the images that have the band.

    Parameters
    ----------
    inputs
        The checked input arrays.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filtering".
    """
    cube = np.zeros(inputs.cube_shape)
    counts = np.zeros(inputs.cube_shape[:2])
    for i in range(len(inputs.band)):
        cube[inputs.band[i], inputs.image[i]] += _blur(inputs.band_data[i], inputs.filter_size[i])
        counts[inputs.band[i], inputs.image[i]] += 1
    have = counts > 0
    cube[have] /= counts[have][:, None, None]
    for b in np.flatnonzero(~have.all(axis=1)):
        images = np.flatnonzero(have[b])
        size = float(np.mean(inputs.filter_size[inputs.band == b]))
        design = np.concatenate(
            [
                np.stack([_blur(inputs.rgb[m, ..., c], size) for c in range(3)], axis=-1).reshape(-1, 3)
                for m in images
            ]
        )
        response = cube[b, images].reshape(-1)
        weights, *_ = np.linalg.lstsq(design, response, rcond=None)
        for m in np.flatnonzero(~have[b]):
            cube[b, m] = inputs.rgb[m] @ weights
    return cube


def filtered_bands_projected(inputs: ReconstructionInputs) -> np.ndarray:
    """:func:`filtered_bands` projected per pixel onto ``C S(p) = R(p)``.

    Parameters
    ----------
    inputs
        The checked input arrays.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filtering" and eq. 1.
    """
    rgb = np.moveaxis(inputs.rgb, -1, 0)  # (3, n_image, height, width)
    return project_onto_rgb(filtered_bands(inputs), inputs.camera_matrix, rgb, overwrite=True)
