"""How a Dataset is laid out in a run store: chunks zarr can store, text, the view on reading.

Written: every dask array gets regular chunks (:func:`regular_chunks`), except along the dim
of a resumable write, whose regions keep their sizes and get on-disk chunks of 1
(:func:`region_encoding`), so that no two regions share a chunk; text becomes zarr 3's
specified variable-length ``string`` type (:func:`variable_length_strings`). Read:
:func:`friendly` gives the convenient view of :meth:`~spectralize.store.RunStore.read`.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from spectralize.schemas import StoreError

__all__ = ["regular_chunks", "region_encoding", "variable_length_strings", "friendly"]


def regular_chunks(
    ds: xr.Dataset,
    chunks: Mapping[str, int] | None,
    *,
    region_dim: str | None = None,
) -> xr.Dataset:
    """Rechunk so every dask array has chunks zarr can store.

    Without ``region_dim`` all chunks are made regular. With it, the chunks along
    ``region_dim`` are kept as they are (they are the regions of a resumable write, possibly
    of unequal size; on disk that dim gets chunks of 1) and the other dims are made regular.
    """
    if chunks:
        unknown = set(chunks) - set(ds.dims)
        if unknown:
            raise StoreError(
                f"chunks name dims {sorted(unknown)} that the dataset does not have "
                f"(its dims: {sorted(map(str, ds.dims))})"
            )
    sizes: dict[Hashable, int] = {}
    for var in ds.variables.values():
        if var.chunks is None:
            continue
        for dim, dim_chunks in zip(var.dims, var.chunks, strict=True):
            sizes[dim] = max(sizes.get(dim, 0), max(dim_chunks))
    sizes.update(dict(chunks or {}))
    if region_dim is not None:
        sizes.pop(region_dim, None)
        # the regions are the chunks of the largest variable along the dim (e.g. one per
        # image set of a spectral cube); everything else follows its boundaries
        lazy = [v for v in ds.data_vars.values() if v.chunks is not None and region_dim in v.dims]
        if lazy:
            largest = max(lazy, key=lambda v: v.size)
            regions = dict(zip(largest.dims, largest.chunks or (), strict=True))[region_dim]
            ds = ds.chunk({region_dim: regions})
    return ds.chunk(sizes) if sizes else ds


def region_encoding(ds: xr.Dataset, dim: str, encoding: dict[str, dict[str, Any]]) -> None:
    """On-disk chunks of 1 along the region dim, the dask chunks elsewhere."""
    for name, var in ds.variables.items():
        if dim not in var.dims or name in ds.indexes:
            continue
        chunks = var.chunks or tuple((size,) for size in var.shape)
        disk = tuple(1 if d == dim else max(c) for d, c in zip(var.dims, chunks, strict=True))
        encoding.setdefault(str(name), {}).setdefault("chunks", disk)


def variable_length_strings(ds: xr.Dataset) -> xr.Dataset:
    """Store text as zarr 3's specified variable-length ``string`` type.

    numpy's fixed-width ``<U`` arrays would become zarr's ``FixedLengthUTF32``, which has no
    zarr v3 specification (other readers may not open it); read back, text is numpy's
    ``StringDType``.
    """
    fixed = [name for name, var in ds.variables.items() if var.dtype.kind == "U"]
    text = np.dtypes.StringDType()  # stays lazy for dask data, unlike ``object``
    return ds.assign({name: ds[name].astype(text) for name in fixed}) if fixed else ds


def friendly(ds: xr.Dataset) -> xr.Dataset:
    """Dims in label order, small coordinates in memory, pixel index coordinates."""
    for dim in list(ds.indexes):
        index = ds.indexes[dim]
        if dim in ds.dims and index.dtype.kind in "iuf" and not index.is_monotonic_increasing:
            ds = ds.sortby(dim)
    small = {
        name: coord.load()
        for name, coord in ds.coords.items()
        if name not in ds.indexes and coord.chunks is not None and coord.size <= 1_000_000
    }
    if small:
        ds = ds.assign_coords(small)
    pixels = {
        dim: np.arange(ds.sizes[dim]) for dim in ("y", "x") if dim in ds.dims and dim not in ds.coords
    }
    if pixels:
        ds = ds.assign_coords(pixels)
        for dim in pixels:
            ds[dim].attrs.update(units="px", long_name=f"pixel {'row' if dim == 'y' else 'column'}")
    return ds
