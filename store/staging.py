"""Staged writes of a run store: unique temporary names, resumable regions, atomic renames.

A group is written first as a zarr store of its own in the store's staging directory
(``.<store>.spectralize/staging/``, beside the store, see :func:`~.lock.work_dir`), under a
name unique to the write (:func:`staged_path`: ``<group>.<fingerprint>.<pid>-<random>``), so
it is invisible to ``xarray.open_datatree`` and a writer only ever removes its own. When it is
complete it is renamed into place (:func:`replace_group`): a crash never leaves a half-written
group that looks finished and never destroys the previous result.

Large outputs are written region by region (:func:`write_regions`): every finished region is
flagged in a small array beside the staged group (:func:`flags_path`), and a later writer
with the same fingerprint adopts an abandoned staged group (:func:`adopt_abandoned`, renaming
it to its own name, under the lock) and writes only the regions that were not finished.
Whatever else an earlier writer of the same data left (a copy it was packing, a staged group
no longer resumable) is removed then (:func:`remove_abandoned`): a failed or killed write
leaves nothing that outlives the next write of its group. A write can also stop once every
region is staged, its flags kept (``write_regions(keep_flags=True)``): the next write of the
same data adopts the regions and only packs and commits them, so that a caller can stage
several groups and commit them only when each is staged.
Of a write with more than :data:`JOIN_REGIONS_ABOVE` regions, small consecutive ones (image
sets of tiny frames) are written together, up to :data:`REGION_BYTES`, so that the cost per
region does not dominate a run of thousands of sets. A staged group complete in its regions
is then packed (:func:`pack_staged`): sorted into label order and rewritten in the finished
layout (:func:`~.layout.shard_layout`). The regions are staged outside the group, as ``.npy``
files per region and variable (:func:`stage_region`), so that the staged copy of a full run
is a few hundred files, not one per image and variable, and is read back image by image.
"""

from __future__ import annotations

import hashlib
import math
import os
import shutil
import time
import uuid
from collections.abc import Callable, Hashable, Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
import zarr

from spectralize.schemas import Precision

from .integrity import PARTIAL_SUFFIX
from .layout import label_permutations, rows_per_chunk, shard_layout
from .precision import apply_precision, round_mantissa, round_precision

__all__ = [
    "STAGING",
    "REPLACED",
    "group_stem",
    "staged_path",
    "flags_path",
    "open_flags",
    "regions_path",
    "packed_path",
    "remove_partial_chunks",
    "remove_tree",
    "adopt_abandoned",
    "remove_abandoned",
    "write_regions",
    "plan_regions",
    "stage_region",
    "region_path",
    "pack_staged",
    "REGION_BYTES",
    "replace_group",
    "replaced_group",
]

STAGING = ".staging"  # where stores before the work directory staged their writes
REPLACED = ".replaced-"  # a previous result moved aside while its replacement is renamed in
_CODEC_KEYS = ("compressors", "filters", "serializer")  # a writer's codecs, kept when packed
REGION_BYTES = 64 * 2**20  # consecutive regions are joined up to this size ...
JOIN_REGIONS_ABOVE = 64  # ... when a write has more regions than this


def group_stem(group: str) -> str:
    """A group path as one file name: ``calibration/spectral`` -> ``calibration~spectral``."""
    return group.strip("/").replace("/", "~")


def staged_path(staging: Path, group: str, fingerprint: str) -> tuple[str, Path]:
    """The prefix shared by every write of this data, and this write's own staged path."""
    prefix = f"{group_stem(group)}.{hashlib.sha256(fingerprint.encode()).hexdigest()[:16]}"
    return prefix, staging / f"{prefix}.{os.getpid()}-{uuid.uuid4().hex[:8]}"


def flags_path(staged: Path) -> Path:
    """The flag array of a resumable write: one bool per region, set when it is written."""
    return staged.with_name(f"{staged.name}.done")


def open_flags(staged: Path, regions: int | None = None) -> zarr.Array | None:
    """The flag array of a resumable write, or ``None`` if there is none to resume from.

    A writer killed while it created the flags can leave their directory without its
    metadata (zarr makes the directory before it renames the metadata into place), and a
    staged group without its own directory is not resumable either: both are ``None``, so
    the write starts over rather than failing. With ``regions``, flags of another number of
    regions are ``None`` too.
    """
    at = flags_path(staged)
    if not staged.is_dir() or not (at / "zarr.json").is_file():
        return None
    try:
        flags = zarr.open_array(str(at), mode="r+")
    except (OSError, ValueError, KeyError, zarr.errors.BaseZarrError):
        return None  # metadata a killed writer left unreadable: nothing to resume
    if regions is not None and flags.shape != (regions,):
        return None
    return flags


def regions_path(staged: Path) -> Path:
    """The regions of a resumable write, beside its staged group: a zarr store per region."""
    return staged.with_name(f"{staged.name}.regions")


def packed_path(staged: Path) -> Path:
    """Where a staged group is packed (:func:`pack_staged`), beside it, before it replaces it."""
    return staged.with_name(f"{staged.name}.packed")


def region_path(staged: Path, index: int) -> Path:
    """Where region ``index`` of a resumable write is staged (:func:`regions_path`)."""
    return regions_path(staged) / f"{index:06d}"


def stage_region(piece: xr.Dataset, root: Path) -> None:
    """Stage a computed region's variables as ``<name>.npy`` files in ``root``, each renamed
    into place when complete (a killed writer leaves only ``.partial`` files).

    A region is staged on its own, not into the staged group: the group's chunks along the
    region dim must divide every region's start, one image when the regions differ in size,
    so thousands of small files in a full run; and ``.npy`` files are read back for packing
    by memory map, image by image in label order, for the cost of a copy (a sharded zarr
    array read by integer index decodes far more than it returns). Text is staged as fixed
    width (the packed zarr array converts it back).
    """
    root.mkdir(parents=True, exist_ok=True)
    for name, var in piece.variables.items():
        values = np.asarray(var.values)
        if values.dtype.kind in "OT":
            values = np.asarray(values.tolist(), dtype=str)
        part = root / f".{name}.npy{PARTIAL_SUFFIX}"
        with open(part, "wb") as file:
            np.save(file, values, allow_pickle=False)
        os.replace(part, root / f"{name}.npy")


def _staged_regions(staged: Path, name: str) -> list[Path] | None:
    """The files of variable ``name`` of every staged region, in region order (``None`` if
    the regions did not stage it)."""
    root = regions_path(staged)
    if not root.is_dir():
        return None
    files = sorted(p / f"{name}.npy" for p in root.iterdir())
    if not files or not files[0].is_file():
        return None
    return files


def remove_partial_chunks(root: Path) -> None:
    """Delete chunk files a killed writer left half-written (they are never read, only clutter)."""
    for leftover in root.rglob(f"*{PARTIAL_SUFFIX}"):
        leftover.unlink(missing_ok=True)


def remove_tree(*paths: Path) -> None:
    """Remove directories that chunk writes still in flight may recreate for a moment.

    When one chunk of a dask-computed write fails, dask raises at once while other threads
    may still be writing their chunks; so remove, wait a little, and remove again.
    """
    for _ in range(50):
        for path in paths:
            shutil.rmtree(path, ignore_errors=True)
        time.sleep(0.05)
        if not any(path.exists() for path in paths):
            return


def adopt_abandoned(staging_dirs: Iterable[Path], prefix: str, staged: Path) -> None:
    """Take over the staged copy of an interrupted write of the same data (under the lock,
    so its writer is gone), renaming it to this write's own name ``staged``."""
    staging_dirs = list(staging_dirs)
    candidates = [d / prefix for d in staging_dirs] + [
        p
        for d in staging_dirs
        for p in d.glob(f"{prefix}.*")
        if not p.name.endswith((".done", ".regions", ".packed"))
    ]
    resumable = [p for p in candidates if p != staged and open_flags(p) is not None]
    if resumable:
        latest = max(resumable, key=lambda p: flags_path(p).stat().st_mtime_ns)
        os.rename(flags_path(latest), flags_path(staged))
        if regions_path(latest).is_dir():
            os.rename(regions_path(latest), regions_path(staged))
        os.rename(latest, staged)
    remove_abandoned(staging_dirs, prefix, staged)


def remove_abandoned(staging_dirs: Iterable[Path], prefix: str, staged: Path | None) -> None:
    """Remove what earlier writers of the same data left in staging (under the lock, so they
    are gone): every entry named after ``prefix`` but this write's own (``staged`` and the
    flags and regions beside it; with ``staged=None`` every one), such as a copy a killed
    writer was packing, or a staged group whose regions were all written (its flags removed)
    and so is never resumed."""
    own = set() if staged is None else {staged, flags_path(staged), regions_path(staged)}
    for directory in staging_dirs:
        for entry in [directory / prefix, *directory.glob(f"{prefix}.*")]:
            if entry in own or not os.path.lexists(entry):
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()


def write_regions(
    ds: xr.Dataset,
    staged: Path,
    dim: str,
    encoding: dict[str, dict[str, Any]],
    progress: Callable[[str], None] | None,
    concurrent: int,
    *,
    keep_flags: bool = False,
) -> None:
    """Write ``ds`` to ``staged`` region by region along ``dim``, skipping flagged regions.

    The regions are the dask chunks of ``ds`` along ``dim`` (when there are more than
    :data:`JOIN_REGIONS_ABOVE`, consecutive ones joined up to :data:`REGION_BYTES`);
    ``concurrent`` of them are computed and written at a time. The flag array is removed
    when every region is written, unless ``keep_flags``: a write that only stages its
    regions leaves them flagged, so that the next write of the same data adopts them
    (:func:`adopt_abandoned`) and commits them without writing any again.
    """
    regions = plan_regions(ds, dim)
    flags_at = flags_path(staged)
    flags = open_flags(staged, len(regions))
    if flags is None:
        for leftover in (staged, flags_at, regions_path(staged)):
            if leftover.exists():
                shutil.rmtree(leftover)
        ds.to_zarr(
            str(staged),
            mode="w",
            consolidated=False,
            zarr_format=3,
            compute=False,
            encoding=encoding or None,
        )
        flags = zarr.create_array(
            str(flags_at), shape=(len(regions),), chunks=(1,), dtype="bool", fill_value=False
        )
    remove_partial_chunks(staged)
    remove_partial_chunks(flags_at)
    if regions_path(staged).is_dir():
        remove_partial_chunks(regions_path(staged))
    done = np.asarray(flags[:], dtype=bool)
    # variables in memory were written whole with the staged group (``to_zarr`` above): a
    # region writes the lazy ones only (so a full run's per-image coordinates are one chunk,
    # not one file per image, and no two regions write the same chunk)
    along = [name for name, var in ds.variables.items() if dim in var.dims and var.chunks is not None]
    total = len(regions)
    skipped = [i for i in range(total) if done[i]]
    # the messages also count along dim (a region can be a batch of image sets)
    size, counted = ds.sizes[dim], sum(regions[i].stop - regions[i].start for i in skipped)
    if skipped and progress:
        progress(
            f"{len(skipped)}/{total} region(s) of {dim} already written "
            f"({counted}/{size} along {dim}), resuming"
        )

    def write_region(index: int) -> int:
        region = regions[index]
        piece = ds[along].isel({dim: region})
        piece = piece.drop_vars(
            [n for n in piece.variables if dim not in piece[n].dims or piece[n].chunks is None]
        )
        piece.attrs = {}
        if piece.variables:
            stage_region(piece.compute(), region_path(staged, index))
        flags[index] = True  # its own chunk of the flag array: no two writers share one
        return index

    todo = [i for i in range(total) if not done[i]]
    finished = len(skipped)
    results: Iterator[int]
    if concurrent == 1:
        results = map(write_region, todo)
    else:
        pool = ThreadPoolExecutor(max_workers=concurrent)
        results = (f.result() for f in as_completed(pool.submit(write_region, i) for i in todo))
    try:
        for index in results:
            finished += 1
            counted += regions[index].stop - regions[index].start
            if progress:
                progress(
                    f"region {index + 1} of {total} written "
                    f"({finished}/{total} done, {counted}/{size} along {dim})"
                )
    finally:
        if concurrent != 1:
            pool.shutdown(wait=True, cancel_futures=True)
    if not keep_flags:
        shutil.rmtree(flags_at)


def _dim_chunks(ds: xr.Dataset, dim: str) -> tuple[int, ...]:
    """The dask chunks of ``ds`` along ``dim`` (one chunk if it has none)."""
    return next(
        (
            dict(zip(v.dims, v.chunks, strict=True))[dim]
            for v in ds.variables.values()
            if v.chunks and dim in v.dims
        ),
        (ds.sizes[dim],),
    )


def plan_regions(ds: xr.Dataset, dim: str) -> list[slice]:
    """The regions of a resumable write of ``ds`` along ``dim`` (:func:`write_regions`): its
    dask chunks along the dim, joined up to :data:`REGION_BYTES` when there are more than
    :data:`JOIN_REGIONS_ABOVE`."""
    dim_chunks = _dim_chunks(ds, dim)
    per_index = sum(v.nbytes // max(v.sizes[dim], 1) for v in ds.variables.values() if dim in v.dims)
    joined = len(dim_chunks) > JOIN_REGIONS_ABOVE
    return join_regions(dim_chunks, REGION_BYTES // max(per_index, 1) if joined else 0)


def join_regions(sizes: Iterable[int], most: int) -> list[slice]:
    """Slices of consecutive chunks of ``sizes``, each chunk whole, joined up to ``most`` indices."""
    regions: list[slice] = []
    start = end = 0
    for size in sizes:
        if end > start and end + size - start > most:
            regions.append(slice(start, end))
            start = end
        end += int(size)
    if end > start:
        regions.append(slice(start, end))
    return regions


def pack_staged(
    staged: Path,
    keep: Iterable[str] = (),
    dim: str | None = None,
    *,
    codecs: Mapping[str, Mapping[str, Any]] | None = None,
    precisions: Mapping[str, Precision] | None = None,
) -> None:
    """Rewrite a staged group complete in its regions in the finished layout, in label order.

    The lazily computed variables along ``dim`` are read from the staged regions' files
    (:func:`stage_region`), the others from the staged group. The packed copy (beside it,
    then renamed over it) has every dim whose index was not increasing sorted and the chunks
    and shards of :func:`~.layout.shard_layout` (the staged chunks kept along the dims of
    ``keep``, which the writer chunked on request; along the region dim ``dim``, the chunks a
    write of the whole data in one piece gets, :func:`_packed_chunks`, many indices each,
    whatever the regions were), the codecs the writer asked for per variable (``codecs``: its
    ``compressors``, ``filters``, ``serializer``), and the variables of ``precisions``
    rounded to their mantissa bits (:func:`~.precision.round_mantissa`) and stating it in
    their attrs: every region alike, whichever write staged it. The arrays are copied shard
    by shard, never all in memory.
    """
    source = xr.open_zarr(str(staged), consolidated=False, chunks={})
    order = label_permutations(source)
    template = source.isel(order) if order else source
    for var in template.variables.values():
        for key in ("chunks", "preferred_chunks", "shards"):
            var.encoding.pop(key, None)
    encoding: dict[str, dict[str, Any]] = {}
    packed_chunks: dict[Hashable, xr.Variable] = {}
    for name, var in template.variables.items():
        asked = {k: v for k, v in (codecs or {}).get(str(name), {}).items() if k in _CODEC_KEYS}
        if asked and name not in template.indexes:
            encoding[str(name)] = dict(asked)
        if dim is not None and dim in var.dims and name not in template.indexes and var.chunks:
            chunks = _packed_chunks(var, dim)
            encoding.setdefault(str(name), {})["chunks"] = chunks
            packed_chunks[name] = var.chunk(dict(zip(var.dims, chunks, strict=True)))
    # the template's dask chunks (which only lay out the packed copy) match its stored ones
    template = template.assign_coords(
        {k: v for k, v in packed_chunks.items() if k in template.coords}
    ).assign({k: v for k, v in packed_chunks.items() if k not in template.coords})
    template = shard_layout(
        apply_precision(template, precisions or {}, round_values=False), encoding, keep=keep
    )
    precisions = dict(precisions or {})
    packed = packed_path(staged)
    shutil.rmtree(packed, ignore_errors=True)
    template.to_zarr(
        str(packed), mode="w-", consolidated=False, zarr_format=3, compute=False, encoding=encoding
    )
    for name, var in source.variables.items():
        if name in source.indexes:
            continue
        dst = zarr.open_array(str(packed / str(name)), mode="r+")
        pieces = _staged_regions(staged, str(name)) if dim in var.dims else None
        if pieces is None:
            src: Any = zarr.open_array(str(staged / str(name)), mode="r")
        else:
            src = _Joined(pieces, var.dims.index(dim))
        if var.ndim == 0:
            scalar = precisions.get(str(name))
            dst[...] = src[...] if scalar is None else round_mantissa(src[...], scalar.keepbits)
            continue
        precision = precisions.get(str(name))
        axis = None if precision is None or precision.along is None else var.dims.index(precision.along)
        step = (dst.shards or dst.chunks)[0]
        first = order.get(str(var.dims[0]))
        rest = tuple(order.get(str(d), slice(None)) for d in var.dims[1:])
        for start in range(0, var.shape[0], step):
            rows = slice(start, min(start + step, var.shape[0]))
            pick = first[rows] if first is not None else rows
            block = src.oindex[(pick, *rest)]
            dst[rows] = block if precision is None else round_precision(block, precision.keepbits, axis)
    shutil.rmtree(staged)
    os.rename(packed, staged)
    shutil.rmtree(regions_path(staged), ignore_errors=True)


def _packed_chunks(var: xr.Variable, dim: str) -> tuple[int, ...]:
    """The stored chunks of a staged variable once packed: its staged chunks along every dim
    but the region dim ``dim``, and along ``dim`` as many indices as a write of the whole
    variable in one piece gets (:func:`~.layout.rows_per_chunk`).

    The regions are staged in chunks of one index (no two regions of unequal size share a
    chunk), but the finished group is read as a whole: kept, they would make a reader's
    dask array one task per image of the run and a sample of the run decode one chunk per
    image; packed like a write in one piece, a reader of one image decodes the one chunk
    that holds it, a few images' worth for small frames and one image of a large frame.
    """
    chunks = [max(c) for c in var.chunks or [(n,) for n in var.shape]]
    axis = var.dims.index(dim)
    row = math.prod(chunks[:axis] + chunks[axis + 1 :]) * var.dtype.itemsize
    chunks[axis] = rows_per_chunk(row, var.shape[axis])
    return tuple(chunks)


def replace_group(staged: Path, target: Path, staging: Path, group: str) -> None:
    """Rename the complete staged group to ``target``; a previous result there is first moved
    aside into ``staging`` and removed only once the new one is in place."""
    replaced = None
    if target.exists():
        replaced = staging / f"{group_stem(group)}{REPLACED}{uuid.uuid4().hex[:8]}"
        os.rename(target, replaced)
    os.rename(staged, target)
    if replaced is not None:
        shutil.rmtree(replaced)


def replaced_group(entry: Path) -> str | None:
    """The group a previous result moved aside by :func:`replace_group` belongs to, else ``None``."""
    if REPLACED not in entry.name:
        return None
    return entry.name.split(REPLACED)[0].replace("~", "/")


class _Joined:
    """The staged regions' ``.npy`` files of a variable joined along ``axis``, read by
    orthogonal index (``.oindex[...]``, as a zarr array is): each region's file is mapped
    only while what it holds is copied out (a mapping kept open would keep every page read
    resident, the whole variable by the end of a pack)."""

    def __init__(self, files: list[Path], axis: int) -> None:
        self.files, self.axis = files, axis
        maps = [self._map(i) for i in range(len(files))]  # headers only: nothing read yet
        self.ndim = maps[0].ndim
        self.starts = np.cumsum([0] + [m.shape[axis] for m in maps])
        self.dtype = np.result_type(*(m.dtype for m in maps))  # text: the widest region's

    def _map(self, region: int) -> np.ndarray:
        return np.load(self.files[region], mmap_mode="r", allow_pickle=False)

    @property
    def oindex(self) -> _Joined:
        return self

    def __getitem__(self, key: tuple[Any, ...]) -> np.ndarray:
        key = tuple(key) + (slice(None),) * (self.ndim - len(key))
        along = np.arange(int(self.starts[-1]))[key[self.axis]]  # indices asked along the axis
        which = np.searchsorted(self.starts, along, side="right") - 1
        out = None
        for region in np.unique(which):
            mine = np.flatnonzero(which == region)
            part = np.take(self._map(region), along[mine] - self.starts[region], axis=self.axis)
            for axis, index in enumerate(key):  # the other dims, one at a time (orthogonal)
                if axis != self.axis and not (isinstance(index, slice) and index == slice(None)):
                    part = part[(slice(None),) * axis + (index,)]
            if out is None:
                shape = list(part.shape)
                shape[self.axis] = len(along)
                out = np.empty(shape, dtype=self.dtype)
            out[(slice(None),) * self.axis + (mine,)] = part
        if out is None:  # nothing asked along the axis
            return np.take(self._map(0), along, axis=self.axis)
        return out
