"""Warm-start propagation between image sets (paper sec. 4, "To speed up reconstruction").

The spectra recovered for one image set give a much better initialisation for the next:
appearance neighbourhoods between the two sets' RGB data transport the spectra from the
solved set to the new one. Each target pixel takes the mean spectrum of its ``k`` nearest
solved pixels in RGB space, scaled by the ratio of its RGB intensity to theirs, so shading
carries over while the spectral shape comes from the solved set. The flow's tile tasks
(:func:`~spectralize.nodes.reconstruction.tiling.solve_tile`) start every set but the seed
from :func:`warm_start` of a sample of the seed set's pixels.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4, "To speed up reconstruction".
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from scipy.spatial import cKDTree

from spectralize.schemas import ReconstructionError

__all__ = ["transport_spectra", "warm_start"]


def transport_spectra(
    source_rgb: np.ndarray,
    source_spectra: np.ndarray,
    target_rgb: np.ndarray,
    *,
    k: int = 3,
    max_source_pixels: int = 250_000,
    seed: int = 0,
) -> np.ndarray:
    """Spectra for ``target_rgb`` from the ``k`` nearest ``source_rgb`` pixels.

    Parameters
    ----------
    source_rgb
        ``(n, 3)`` RGB of the solved pixels.
    source_spectra
        ``(n, wavelengths)`` their spectra.
    target_rgb
        ``(m, 3)`` RGB of the pixels to initialise.
    k
        Neighbours per target pixel (the paper's appearance neighbourhood size, 3).
    max_source_pixels
        At most this many source pixels (a deterministic random subset) build the tree.
    seed
        Seed of that subset.

    Returns
    -------
    numpy.ndarray
        ``(m, wavelengths)``: mean neighbour spectrum times
        ``sum(target rgb) / mean(sum(neighbour rgb))``.
    """
    source_rgb = np.asarray(source_rgb, float)
    source_spectra = np.asarray(source_spectra, float)
    target_rgb = np.asarray(target_rgb, float)
    if source_rgb.shape[0] != source_spectra.shape[0] or source_rgb.shape[0] == 0:
        raise ReconstructionError(
            f"source_spectra: expected one spectrum per source pixel ({source_rgb.shape[0]}), "
            f"found {source_spectra.shape[0]}"
        )
    if source_rgb.shape[0] > max_source_pixels:
        keep = np.random.default_rng(seed).choice(source_rgb.shape[0], max_source_pixels, replace=False)
        source_rgb, source_spectra = source_rgb[keep], source_spectra[keep]
    k = int(min(k, source_rgb.shape[0]))
    _, index = cKDTree(source_rgb).query(target_rgb, k=k)
    index = np.asarray(index).reshape(target_rgb.shape[0], k)
    spectra = source_spectra[index].mean(axis=1)
    neighbour_level = source_rgb[index].sum(axis=2).mean(axis=1)
    target_level = target_rgb.sum(axis=1)
    ratio = np.divide(
        target_level, neighbour_level, out=np.ones_like(target_level), where=neighbour_level > 0
    )
    return spectra * ratio[:, None]


def warm_start(
    source_rgb: np.ndarray,
    source_spectra: np.ndarray,
    target_rgb: xr.DataArray,
    wavelength: np.ndarray,
    *,
    k: int = 3,
    max_source_pixels: int = 250_000,
) -> xr.DataArray:
    """Initial spectra for an image set (or a tile's window of it) from solved pixels.

    The flow solves the seed set first and keeps a sample of its pixels' RGB and spectra;
    every other set's tile starts from those spectra moved to its own pixels
    (:func:`transport_spectra`), as the ``initial`` of
    :func:`~spectralize.nodes.reconstruction.reconstruct`.

    Parameters
    ----------
    source_rgb, source_spectra
        ``(n, 3)`` RGB and ``(n, wavelengths)`` spectra of the solved pixels.
    target_rgb
        HDR RGB of the pixels to initialise, dims (image, y, x, channel).
    wavelength
        The spectra's wavelengths [nm].
    k, max_source_pixels
        See :func:`transport_spectra`.

    Returns
    -------
    xarray.DataArray
        Initial spectra, dims (image, wavelength, y, x), float64, with the target's
        per-image coordinates.

    Raises
    ------
    ReconstructionError
        For a target that is not (image, y, x, channel), or mismatched sources.
    """
    rgb_dims = ("image", "y", "x", "channel")
    if set(target_rgb.dims) != set(rgb_dims):
        raise ReconstructionError(f"target_rgb: expected dims {rgb_dims}, found {target_rgb.dims}")
    target = target_rgb.transpose(*rgb_dims)
    moved = transport_spectra(
        source_rgb,
        source_spectra,
        target.values.reshape(-1, target.sizes["channel"]),
        k=k,
        max_source_pixels=max_source_pixels,
    )
    cube = moved.reshape(*target.shape[:3], -1)
    return xr.DataArray(
        np.moveaxis(cube, -1, 1),
        dims=("image", "wavelength", "y", "x"),
        coords={
            "wavelength": np.asarray(wavelength),
            **{name: coord for name, coord in target.coords.items() if set(coord.dims) <= {"image"}},
        },
        attrs={"units": "1", "long_name": "spectra transported from a solved image set (warm start)"},
    )
