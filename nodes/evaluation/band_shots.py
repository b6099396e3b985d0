"""Which images have band shots: Figure 7 separates the images with and without them.

References
----------
Fast Capture of Spectral Image Series, sec. 5 "Sparsely Measured Spectral Bands" and Figure 7.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import Problem, SchemaError

__all__ = ["band_shot_images", "has_band_shots", "image_index"]


def band_shot_images(shots: xr.Dataset, images: xr.DataArray | Sequence[int] | int) -> xr.DataArray:
    """Which images have at least one band shot (Figure 7 separates the two kinds).

    Parameters
    ----------
    shots
        Group ``raw/spectral`` or ``bands``: a per-shot ``image`` (shot) index of the RGB
        image each band-filtered frame pairs with.
    images
        The images to classify: a number of images (indices ``0..n-1``), their index values,
        or the ``image`` coordinate of a cube.

    Returns
    -------
    xarray.DataArray
        ``has_band_shots`` (image) bool.

    Raises
    ------
    SchemaError
        If ``shots`` has no integer ``image`` over a ``shot`` dim.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 "Sparsely Measured Spectral Bands" and
    Figure 7.
    """
    found = shots.get("image") if isinstance(shots, xr.Dataset) else None
    if found is None or found.dims != ("shot",) or found.dtype.kind not in "iu":
        what = "nothing" if found is None else f"dims {found.dims} dtype {found.dtype}"
        raise SchemaError(
            "cannot tell which images have band shots:",
            [
                Problem(
                    "shots:image",
                    "an integer coordinate 'image' (shot) naming the RGB image "
                    "each shot pairs with (groups raw/spectral, bands)",
                    what,
                )
            ],
        )
    if isinstance(images, int | np.integer):
        index = np.arange(int(images))
    else:
        index = np.asarray(images.values if isinstance(images, xr.DataArray) else images)
    return has_band_shots(shots, index)


def has_band_shots(shots: xr.Dataset, images: np.ndarray) -> xr.DataArray:
    """``has_band_shots`` (image) of the image labels ``images`` (unchecked ``shots``)."""
    has = np.isin(images, np.unique(np.asarray(shots["image"].values)))
    return xr.DataArray(
        has,
        dims=("image",),
        name="has_band_shots",
        attrs={"long_name": "image has at least one band shot", "units": "1"},
    )


def image_index(cube: xr.DataArray) -> np.ndarray:
    """The image labels of a cube (its positions when it has no ``image`` coordinate)."""
    if "image" in cube.coords and cube["image"].dims == ("image",):
        return np.asarray(cube["image"].values)
    return np.arange(cube.sizes["image"])
