"""Statistics of the per-pixel metric maps (paper sec. 5, Figures 5-7).

Per map and image: mean, median, 95th and 99th percentile (:func:`map_statistics`, NaN
ignored); the per-image nRMSE histogram (:func:`nrmse_histogram`, Figure 7 is its sum over
the images with and without band shots); and the statistics over all pixels of subsets of
images (:func:`subset_statistics`: all / with band shots / without), with the fraction of
pixels whose nRMSE is below a threshold (0.03, the level Figure 7 discusses).

References
----------
Fast Capture of Spectral Image Series, sec. 5 ("Sparsely Measured Spectral Bands") and
Figures 5, 6 and 7.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import Problem, SchemaError

from .cubes import string_labels
from .pixel_metrics import METRICS

__all__ = ["STATISTICS", "DEFAULT_THRESHOLD", "map_statistics", "nrmse_histogram", "subset_statistics"]

#: The statistics of every map, in the order of the ``statistic`` dim.
STATISTICS: tuple[str, ...] = ("mean", "median", "p95", "p99")

#: nRMSE level below which a pixel counts as well reconstructed (Figure 7: "~0.03").
DEFAULT_THRESHOLD: float = 0.03


def _statistics_numpy(values: np.ndarray, n_core: int) -> np.ndarray:
    """(..., core...) -> (..., 4): nanmean, nanmedian, nan p95, nan p99 over the core axes."""
    lead = values.shape[: values.ndim - n_core]
    flat = np.asarray(values, dtype=np.float64).reshape(*lead, -1)
    out = np.full((*lead, len(STATISTICS)), np.nan)
    if flat.shape[-1] == 0:
        return out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN images give NaN
        out[..., 0] = np.nanmean(flat, axis=-1)
        out[..., 1:] = np.moveaxis(np.nanquantile(flat, [0.5, 0.95, 0.99], axis=-1), 0, -1)
    return out


def map_statistics(error_map: xr.DataArray, *, dims: Sequence[str] = ("y", "x")) -> xr.DataArray:
    """Mean, median, 95th and 99th percentile of a map over ``dims``, NaN ignored.

    Parameters
    ----------
    error_map
        A metric map, e.g. ``nrmse`` (image, y, x).
    dims
        Dims reduced (default: per image). The map is rechunked to one chunk along them.

    Returns
    -------
    xarray.DataArray
        float64 (remaining dims..., statistic) with ``statistic`` = :data:`STATISTICS`, in
        the units of the map; NaN where no finite value is found.

    Raises
    ------
    SchemaError
        If ``error_map`` lacks one of ``dims``.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 (per-image accuracy of Figures 5 and 6).
    """
    dims = list(dims)
    missing = [d for d in dims if d not in error_map.dims]
    if missing:
        raise SchemaError(
            "cannot summarise the map:",
            [Problem(str(error_map.name), f"dims including {missing}", f"dims {error_map.dims}")],
        )
    if error_map.chunks is not None:
        error_map = error_map.chunk({d: -1 for d in dims})
    stats = xr.apply_ufunc(
        _statistics_numpy,
        error_map,
        kwargs={"n_core": len(dims)},
        input_core_dims=[dims],
        output_core_dims=[["statistic"]],
        dask="parallelized",
        output_dtypes=[np.float64],
        dask_gufunc_kwargs={"output_sizes": {"statistic": len(STATISTICS)}},
    ).assign_coords(statistic=string_labels(STATISTICS))
    stats.attrs = {
        "units": error_map.attrs.get("units", "1"),
        "long_name": f"statistics of {error_map.attrs.get('long_name', error_map.name)}",
    }
    return stats


def _histogram_numpy(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    lead = values.shape[:-2]
    flat = values.reshape(-1, values.shape[-2] * values.shape[-1])
    counts = np.stack([np.histogram(row[np.isfinite(row)], bins=edges)[0] for row in flat])
    return counts.reshape(*lead, len(edges) - 1).astype(np.int64)


def nrmse_histogram(nrmse: xr.DataArray, edges: np.ndarray) -> xr.DataArray:
    """Per-image histogram (image, nrmse_bin) int64 of the finite nRMSE values in ``edges``."""
    source = nrmse.chunk({"y": -1, "x": -1}) if nrmse.chunks is not None else nrmse
    return xr.apply_ufunc(
        _histogram_numpy,
        source,
        kwargs={"edges": edges},
        input_core_dims=[["y", "x"]],
        output_core_dims=[["nrmse_bin"]],
        dask="parallelized",
        output_dtypes=[np.int64],
        dask_gufunc_kwargs={"output_sizes": {"nrmse_bin": edges.size - 1}},
    )


def subset_statistics(
    maps: dict[str, xr.DataArray], masks: dict[str, np.ndarray], threshold: float
) -> xr.Dataset:
    """Statistics of every map over all pixels of each subset of images (``masks``: subset
    name -> image mask), the fraction of finite pixels with nRMSE below ``threshold`` and
    the number of finite pixels, over a ``subset`` dim."""
    per_metric: dict[str, list[xr.DataArray]] = {name: [] for name in maps}
    fractions, counts = [], []
    for mask in masks.values():
        index = np.flatnonzero(mask)
        for name, error_map in maps.items():
            if index.size == 0:
                stats = xr.DataArray(np.full(len(STATISTICS), np.nan), dims=("statistic",))
            else:
                stats = map_statistics(error_map.isel(image=index), dims=("image", "y", "x"))
            per_metric[name].append(stats.drop_vars("statistic", errors="ignore"))
        if index.size == 0:
            fractions.append(xr.DataArray(np.nan))
            counts.append(xr.DataArray(np.int64(0)))
        else:
            nrmse = maps["nrmse"].isel(image=index)
            finite = nrmse.notnull().sum().astype(np.int64)
            below = (nrmse < threshold).sum()
            fractions.append(below / finite.where(finite > 0))
            counts.append(finite)
    subset = list(masks)
    out = xr.Dataset()
    for name, items in per_metric.items():
        units, long_name = METRICS[name]
        out[f"{name}_subset_statistics"] = xr.concat(items, dim="subset").assign_attrs(
            units=maps[name].attrs.get("units", units),
            long_name=f"statistics of the {long_name} over all pixels of the subset",
        )
    out["nrmse_subset_fraction_below"] = (
        xr.concat(fractions, dim="subset")
        .astype(np.float64)
        .assign_attrs(
            units="1",
            threshold=threshold,
            long_name=f"fraction of finite pixels with nRMSE < {threshold:g}",
        )
    )
    out["subset_pixel_count"] = xr.concat(counts, dim="subset").assign_attrs(
        units="1", long_name="number of pixels with a finite nRMSE"
    )
    return out.assign_coords(subset=string_labels(subset), statistic=string_labels(STATISTICS))
