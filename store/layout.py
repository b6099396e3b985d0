"""How a Dataset is laid out in a run store: chunks zarr can store, text, the view on reading.

Written: dims whose index is not in label order (``image`` of a result computed image set
by image set) are sorted (:func:`label_order`), so plain xarray and
:meth:`~spectralize.store.RunStore.read` see the images in one order; every dask array gets
regular chunks (:func:`regular_chunks`), except along the dim of a resumable write, whose
regions keep their sizes and get on-disk chunks of 1 while they are staged
(:func:`region_encoding`), so that no two regions share a chunk. A finished group is laid out
for a full run (:func:`shard_layout`): small variables (per-image coordinates, bookkeeping)
in one chunk each, large ones in zarr 3 shards of about :data:`SHARD_BYTES` along their
first dim, so files grow with shards, not with images x chunks; a resumable write's group is
packed with the chunks along its region dim that a write in one piece gets
(:func:`rows_per_chunk`), so that it is read like one. Text becomes zarr 3's
specified variable-length ``string`` type (:func:`variable_length_strings`). Read:
:func:`friendly` gives the convenient view of :meth:`~spectralize.store.RunStore.read`.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable, Mapping
from typing import Any

import numpy as np
import xarray as xr

from spectralize.schemas import StoreError

__all__ = [
    "regular_chunks",
    "region_encoding",
    "label_order",
    "label_permutations",
    "shard_layout",
    "rows_per_chunk",
    "variable_length_strings",
    "friendly",
    "SMALL_BYTES",
    "SHARD_BYTES",
    "CHUNK_BYTES",
]

SMALL_BYTES = 16 * 2**20
"""A variable up to this size is one chunk (the per-image coordinates of a full run fit)."""
SHARD_BYTES = 32 * 2**20
"""Aimed-at size of one shard (one file) of a large variable; at least one chunk row."""
CHUNK_BYTES = 2**20
"""Largest chunk (the unit zarr decodes) of a large variable whose dask chunks span many
indices of its first dim, cut along that dim: a task that reads a few images (a batch of
image sets) decodes those, not the whole variable. Uncut, a full run's ``hdr`` of small
frames would be one chunk that every batch of sets decodes whole (docs/benchmarks_notes.md,
full_run)."""


def label_permutations(ds: xr.Dataset) -> dict[str, np.ndarray]:
    """Per dim whose numeric index is not increasing: the positions that sort it."""
    return {
        str(dim): np.argsort(np.asarray(index), kind="stable")
        for dim, index in ds.indexes.items()
        if dim in ds.dims and index.dtype.kind in "iuf" and not index.is_monotonic_increasing
    }


def label_order(ds: xr.Dataset) -> xr.Dataset:
    """``ds`` with every numeric dim index in increasing (label) order."""
    order = label_permutations(ds)
    return ds.isel(order) if order else ds


def shard_layout(
    ds: xr.Dataset, encoding: dict[str, dict[str, Any]], keep: Iterable[Hashable] = ()
) -> xr.Dataset:
    """Chunks and shards on disk for a finished group; returns ``ds`` rechunked to match.

    Variables up to :data:`SMALL_BYTES` (index coordinates aside) become one chunk, unless
    they have a dim of ``keep`` (chunked on request). The others keep their chunks (the
    dask chunks, or ``encoding``'s; dask chunks larger than :data:`CHUNK_BYTES` cut along the
    first dim) inside shards spanning every other dim whole and as many chunk rows of the
    first dim as fit in :data:`SHARD_BYTES`; their dask chunks become the shards, so every
    write task writes whole shards.
    """
    rechunk: dict[Hashable, xr.Variable] = {}
    for name, var in ds.variables.items():
        if name in ds.indexes or var.ndim == 0 or var.dtype.kind in "OTU":
            continue
        enc = encoding.setdefault(str(name), {})
        if "shards" in enc:
            continue
        if var.nbytes <= SMALL_BYTES and not set(var.dims) & set(keep):
            enc["chunks"] = tuple(var.shape)
            if var.chunks is not None:
                rechunk[name] = var.chunk(dict.fromkeys(var.dims, -1))
            continue
        chunks = tuple(
            enc.get("chunks") or (tuple(max(c) for c in var.chunks) if var.chunks else var.shape)
        )
        per_index = math.prod(chunks[1:]) * var.dtype.itemsize
        if "chunks" not in enc:  # not asked for
            chunks = (rows_per_chunk(per_index, chunks[0]), *chunks[1:])
        rest = tuple(math.ceil(n / c) * c for n, c in zip(var.shape[1:], chunks[1:], strict=True))
        row = chunks[0] * math.prod(rest) * var.dtype.itemsize
        first = min(
            max(1, SHARD_BYTES // max(row, 1)) * chunks[0],
            math.ceil(var.shape[0] / chunks[0]) * chunks[0],
        )
        enc["chunks"], enc["shards"] = chunks, (first, *rest)
        rechunk[name] = var.chunk(dict(zip(var.dims, (first, *rest), strict=True)))
    coords = {k: v for k, v in rechunk.items() if k in ds.coords}
    data = {k: v for k, v in rechunk.items() if k not in ds.coords}
    return ds.assign_coords(coords).assign(data)


def rows_per_chunk(row_bytes: int, rows: int) -> int:
    """Indices of a large variable's dim in one stored chunk, where nobody asked for chunks:
    as many as fit in :data:`CHUNK_BYTES` (and in a shard, :data:`SHARD_BYTES`), at least one,
    at most ``rows`` (the dask chunk, or the whole dim).

    ``row_bytes`` is the size of one index of that dim within a chunk (the chunk's extent
    along the other dims). A reader of one index decodes one such chunk; a reader of the
    whole variable decodes as many chunks as fit, not one per index.
    """
    return max(1, min(int(rows), min(CHUNK_BYTES, SHARD_BYTES) // max(int(row_bytes), 1)))


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
    """The staged group's chunks of a resumable write: a lazy variable along the region dim
    (its data staged per region, :func:`~.staging.stage_region`) 1 along that dim and the
    dask chunks elsewhere, which the packed group keeps where asked; a variable in memory
    (written whole when the staged group is created, never by a region) is one chunk."""
    for name, var in ds.variables.items():
        if dim not in var.dims or name in ds.indexes:
            continue
        if var.chunks is None:
            encoding.setdefault(str(name), {}).setdefault("chunks", tuple(var.shape))
            continue
        chunks = var.chunks
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
    """Dims in label order (stores of the first layout kept results in set order), small
    coordinates in memory, pixel index coordinates."""
    ds = label_order(ds)
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
