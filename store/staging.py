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
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
import uuid
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
import zarr

from .integrity import PARTIAL_SUFFIX

__all__ = [
    "STAGING",
    "REPLACED",
    "group_stem",
    "staged_path",
    "flags_path",
    "remove_partial_chunks",
    "remove_tree",
    "adopt_abandoned",
    "write_regions",
    "replace_group",
    "replaced_group",
]

STAGING = ".staging"  # where stores before the work directory staged their writes
REPLACED = ".replaced-"  # a previous result moved aside while its replacement is renamed in


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
        p for d in staging_dirs for p in d.glob(f"{prefix}.*") if not p.name.endswith(".done")
    ]
    resumable = [p for p in candidates if p.is_dir() and flags_path(p).is_dir() and p != staged]
    if not resumable:
        return
    latest = max(resumable, key=lambda p: flags_path(p).stat().st_mtime_ns)
    os.rename(flags_path(latest), flags_path(staged))
    os.rename(latest, staged)


def write_regions(
    ds: xr.Dataset,
    staged: Path,
    dim: str,
    encoding: dict[str, dict[str, Any]],
    progress: Callable[[str], None] | None,
    concurrent: int,
) -> None:
    """Write ``ds`` to ``staged`` region by region along ``dim``, skipping flagged regions.

    The regions are the dask chunks of ``ds`` along ``dim``; ``concurrent`` of them are
    computed and written at a time. The flag array is removed when every region is written.
    """
    dim_chunks = next(
        (
            dict(zip(v.dims, v.chunks, strict=True))[dim]
            for v in ds.variables.values()
            if v.chunks and dim in v.dims
        ),
        (ds.sizes[dim],),
    )
    bounds = np.cumsum((0,) + tuple(dim_chunks))
    regions = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    flags_at = flags_path(staged)
    flags = None
    if staged.exists() and flags_at.exists():
        flags = zarr.open_array(str(flags_at), mode="r+")
        if flags.shape != (len(regions),):
            flags = None
    if flags is None:
        for leftover in (staged, flags_at):
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
    done = np.asarray(flags[:], dtype=bool)
    along = [name for name, var in ds.variables.items() if dim in var.dims]
    total = len(regions)
    skipped = [i for i in range(total) if done[i]]
    if skipped and progress:
        progress(f"{len(skipped)}/{total} region(s) of {dim} already written, resuming")

    def write_region(index: int) -> int:
        region = regions[index]
        piece = ds[along].isel({dim: region})
        piece = piece.drop_vars([n for n in piece.variables if dim not in piece[n].dims])
        piece.attrs = {}
        piece.to_zarr(str(staged), mode="r+", region={dim: region}, consolidated=False)
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
            if progress:
                progress(f"region {index + 1} of {total} written ({finished}/{total} done)")
    finally:
        if concurrent != 1:
            pool.shutdown(wait=True, cancel_futures=True)
    shutil.rmtree(flags_at)


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
