"""A per-pixel error estimate beside the spectra: where not to trust the reconstruction.

The spread of the reconstructed spectra over each pixel's appearance neighbourhood, coupled
scale-invariantly: ``u(p) = sqrt(mean_n ||S(p) - (b_p / b_n) S(n)||^2 / n_wavelength) /
mean(S)`` over the ``k`` nearest neighbours ``n`` in chromaticity and position
(:func:`~.neighbourhoods.appearance_features`), ``b`` the RGB brightness. Where similar
looking pixels nearby got different spectral shapes the band data did not pin the answer
down (noise, sub-pixel mixtures, highlights); ``u`` is in the units of the benchmark's
nRMSE (the image's mean), higher meaning *less* trustworthy.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3 (appearance neighbourhoods) and
   Fig. 5 (nRMSE).
"""

from __future__ import annotations

import numpy as np

from .neighbourhoods import appearance_features, appearance_neighbours, brightness_ratios

__all__ = ["neighbourhood_spread", "CONFIDENCE_NEIGHBOURS"]

CONFIDENCE_NEIGHBOURS = 6
"""``k`` of the spread (the default solver's own neighbourhood size, so its graph serves)."""


def neighbourhood_spread(
    cube: np.ndarray,
    rgb: np.ndarray,
    *,
    k: int = CONFIDENCE_NEIGHBOURS,
    neighbours: np.ndarray | None = None,
    region: tuple[slice, slice] | None = None,
) -> np.ndarray:
    """Per-pixel error estimate ``(n_image, height, width)`` of a reconstructed cube.

    Parameters
    ----------
    cube
        ``(n_wavelength, n_image, height, width)`` spectra.
    rgb
        ``(n_image, height, width, 3)`` the RGB they were reconstructed from.
    k
        Neighbours per pixel.
    neighbours
        ``(n_pixels, k)`` appearance neighbours in chromaticity and position found before
        (the solver's own graph, :func:`~.operators.build_problem` with
        ``appearance="chromaticity-spatial"``), in (image, y, x) order; None: searched here
        (the search is most of the cost).
    region
        ``(y, x)`` slices: estimate only the pixels of every image inside them (e.g. a
        tile's core, :attr:`~.tiling.TileWindow.inner`), the others are NaN; their
        neighbours are still searched among all pixels, and each image's mean is still the
        whole image's, so the estimates inside are those of a call without ``region``.
        None: every pixel.

    Returns
    -------
    numpy.ndarray
        ``u(p)`` (see the module docstring), float32, >= 0 (NaN outside ``region``).
    """
    cube = np.asarray(cube)
    n_wavelength, n_image, height, width = cube.shape
    pixels = np.moveaxis(np.asarray(rgb, dtype=np.float64), -1, 0).reshape(3, -1)
    chosen = _region_pixels((n_image, height, width), region)
    if neighbours is None:
        features = appearance_features(pixels, (n_image, height, width), space="chromaticity-spatial")
        neighbours = appearance_neighbours(features, k=k, queries=chosen)
        del features
    elif chosen is not None:
        neighbours = np.asarray(neighbours)[chosen]
    ratios = brightness_ratios(pixels, neighbours, pixels=chosen)
    del pixels
    from .kernels import neighbour_spread

    flat = np.ascontiguousarray(cube.reshape(n_wavelength, -1))
    every = np.arange(flat.shape[1]) if chosen is None else chosen
    squared = np.zeros(every.size)
    # one compiled pass per band, accumulated in float64 (no cube-sized temporaries)
    neighbour_spread(
        flat,
        every,
        np.ascontiguousarray(neighbours),
        np.ascontiguousarray(ratios, dtype=np.float64),
        squared,
    )
    if chosen is None:
        spread = np.sqrt(squared / max(neighbours.shape[1], 1)).reshape(n_image, height, width)
    else:
        spread = np.full(n_image * height * width, np.nan)
        spread[chosen] = np.sqrt(squared / max(neighbours.shape[1], 1))
        spread = spread.reshape(n_image, height, width)
    mean = np.array([np.abs(cube[:, m]).mean(dtype=np.float64) for m in range(n_image)])
    return (spread / np.maximum(mean, 1e-30)[:, None, None]).astype(np.float32)


def _region_pixels(shape: tuple[int, int, int], region: tuple[slice, slice] | None) -> np.ndarray | None:
    """Flat (image, y, x) indices of every image's pixels inside ``region`` (None: all)."""
    if region is None:
        return None
    n_image, height, width = shape
    index = np.arange(n_image * height * width).reshape(n_image, height, width)
    return np.ascontiguousarray(index[:, region[0], region[1]].ravel())
