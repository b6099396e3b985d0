"""Colour-checker patches: the labels of a chart image and the mean of each patch.

References
----------
Fast Capture of Spectral Image Series, section 4 (colour-checker patches, Fig. 4).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import CalibrationError

__all__ = ["patch_means", "eroded_labels"]


def patch_means(
    data: xr.DataArray,
    labels: xr.DataArray | np.ndarray,
    *,
    names: Sequence[str] | None = None,
) -> xr.DataArray:
    """Mean of ``data`` over each labelled patch.

    Parameters
    ----------
    data
        Any array with dims ``y`` and ``x`` (e.g. HDR radiance (y, x, channel) or band
        radiance (wavelength, y, x)).
    labels
        (y, x) integer patch index per pixel; negative values are background.
    names
        Patch names for the ``patch`` coordinate (one per patch index ``0..n-1``).

    Returns
    -------
    xarray.DataArray
        ``(patch, ...)``: the other dims of ``data``.

    Raises
    ------
    CalibrationError
        Labels of another shape than ``data``'s (y, x), a patch without pixels, names of the
        wrong length.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (colour-checker patches).
    """
    lab = np.asarray(labels.values if isinstance(labels, xr.DataArray) else labels)
    shape = (data.sizes.get("y"), data.sizes.get("x"))
    if lab.shape != shape:
        raise CalibrationError(f"patch_means: labels have shape {lab.shape}, data (y, x) {shape}")
    n = int(lab.max()) + 1 if lab.size and lab.max() >= 0 else 0
    if n == 0:
        raise CalibrationError("patch_means: labels contain no patch (all negative)")
    counts = np.bincount(lab[lab >= 0].ravel(), minlength=n)
    if np.any(counts == 0):
        raise CalibrationError(
            f"patch_means: patch(es) {np.flatnonzero(counts == 0).tolist()} have no pixel"
        )
    if names is not None and len(names) != n:
        raise CalibrationError(f"patch_means: {len(names)} names for {n} patches")
    others = [d for d in data.dims if d not in ("y", "x")]
    # the dtype a mean keeps (float32 stays float32, as xarray's mean); summed in float64
    dtype = data.dtype if np.issubdtype(data.dtype, np.floating) else np.dtype(np.float64)
    if data.chunks is not None:  # whole frames per chunk: the sums of a chunk are its patches'
        data = data.chunk({"y": -1, "x": -1})
    out = xr.apply_ufunc(
        _patch_means,
        data,
        kwargs={"labels": lab, "n": n, "dtype": dtype},
        input_core_dims=[["y", "x"]],
        output_core_dims=[["patch"]],
        dask="parallelized",
        output_dtypes=[dtype],
        dask_gufunc_kwargs={"output_sizes": {"patch": n}},
    )
    out = out.transpose("patch", *others)
    return out.assign_coords(patch=list(names) if names is not None else np.arange(n))


def _patch_means(values: np.ndarray, labels: np.ndarray, n: int, dtype: np.dtype) -> np.ndarray:
    """Per patch ``0..n-1`` the mean of ``values`` (..., y, x) over its pixels, NaN skipped
    (NaN where a patch has none): the pixels of a patch taken in raster order and averaged as
    ``mean(skipna=True)`` over (y, x) does (the same sums, in the same precision), with no
    masked copy of the frame per patch."""
    import warnings

    moved = np.moveaxis(values, (-2, -1), (0, 1))  # (y, x, ...): the caller's own layout
    flat = moved.reshape(labels.size, -1)
    order = np.argsort(labels.ravel(), kind="stable")  # raster order within each patch
    ends = np.searchsorted(labels.ravel()[order], np.arange(n + 1) - 0.5)
    out = np.empty((n, flat.shape[1]), dtype=dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a patch of NaN only: NaN
        for k in range(n):
            out[k] = np.nanmean(flat[order[ends[k] : ends[k + 1]]], axis=0)
    return np.moveaxis(out.reshape(n, *moved.shape[2:]), 0, -1)


def eroded_labels(labels: np.ndarray, margin: int) -> np.ndarray:
    """The (y, x) patch labels with ``margin`` pixels removed at every patch border.

    Misregistration and blur mix a patch's border pixels with its neighbours'; a patch too
    small for the full margin is eroded less, so that it keeps pixels. ``margin <= 0``:
    ``labels`` itself. Background stays negative.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (colour-checker patches).
    """
    from scipy import ndimage

    if margin <= 0:
        return labels
    out = np.full_like(labels, -1)
    for k in np.unique(labels[labels >= 0]):
        patch = labels == k
        for iterations in range(margin, -1, -1):  # small patches: erode less, keep pixels
            inner = ndimage.binary_erosion(patch, iterations=iterations) if iterations else patch
            if inner.any():
                break
        out[inner] = k
    return out
