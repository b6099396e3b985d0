"""Run stores: one zarr v3 directory per measurement run, one xarray Dataset per group.

Writes are atomic at the group level. A group is written under ``.staging/`` and renamed
into place when complete, so a crash never leaves a half-written group that looks finished
and never destroys the previous result. Every finished group carries in its attrs

``spectralize_fingerprint``
    a hash of (node name, node version, parameters, input fingerprints): a step whose output
    already carries the fingerprint it would write is up to date (this is what resumes flows);
``spectralize_provenance``
    those ingredients in readable form;
``spectralize_schema``
    the name of the schema the group follows;
``spectralize_manifest``
    the chunk files written and their sizes, so that a missing or truncated chunk is reported
    instead of silently read as fill values.

Large outputs can be written region by region (``resumable_along=``): the staged group is
named after its fingerprint and every finished region is flagged, so a rerun after a crash
writes only the regions that were not finished.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import time
import uuid
from collections.abc import Callable, Mapping
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
import zarr

from .errors import Problem, SchemaError, StoreError
from .run import GROUP_SCHEMAS, schema_for
from .spec import GroupSchema, validate_dataset

__all__ = [
    "RunStore",
    "compute_fingerprint",
    "FINGERPRINT_ATTR",
    "PROVENANCE_ATTR",
    "SCHEMA_ATTR",
    "MANIFEST_ATTR",
]

STORE_FORMAT = "spectralize-run-store"
STORE_FORMAT_VERSION = 1
FINGERPRINT_ATTR = "spectralize_fingerprint"
PROVENANCE_ATTR = "spectralize_provenance"
SCHEMA_ATTR = "spectralize_schema"
MANIFEST_ATTR = "spectralize_manifest"
STAGING = ".staging"
_BOOKKEEPING = (FINGERPRINT_ATTR, PROVENANCE_ATTR, SCHEMA_ATTR, MANIFEST_ATTR)


def _canonical(value: Any) -> str:
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def compute_fingerprint(
    node: str, version: str, parameters: Mapping[str, Any], inputs: Mapping[str, str]
) -> str:
    """Fingerprint of one node run: sha256 of its name, version, parameters and inputs.

    Parameters
    ----------
    node, version
        The node's declared name and version.
    parameters
        JSON-serialisable parameter values.
    inputs
        Input group name -> that group's fingerprint.
    """
    payload = {"node": node, "version": version, "parameters": dict(parameters), "inputs": dict(inputs)}
    return hashlib.sha256(_canonical(payload).encode()).hexdigest()


def _stem(group: str) -> str:
    return group.strip("/").replace("/", "~")


def _regular_chunks(
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
    sizes: dict[str, int] = {}
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
            regions = dict(zip(largest.dims, largest.chunks, strict=True))[region_dim]
            ds = ds.chunk({region_dim: regions})
    return ds.chunk(sizes) if sizes else ds


def _region_encoding(ds: xr.Dataset, dim: str, encoding: dict[str, dict[str, Any]]) -> None:
    """On-disk chunks of 1 along the region dim, the dask chunks elsewhere."""
    for name, var in ds.variables.items():
        if dim not in var.dims or name in ds.indexes:
            continue
        chunks = var.chunks or tuple((size,) for size in var.shape)
        disk = tuple(1 if d == dim else max(c) for d, c in zip(var.dims, chunks, strict=True))
        encoding.setdefault(str(name), {}).setdefault("chunks", disk)


PARTIAL_SUFFIX = ".partial"  # zarr's local store writes a chunk to NAME.<uuid>.partial, then renames


def _remove_partial_chunks(root: Path) -> None:
    """Delete chunk files a killed writer left half-written (they are never read, only clutter)."""
    for leftover in root.rglob(f"*{PARTIAL_SUFFIX}"):
        leftover.unlink(missing_ok=True)


def _variable_length_strings(ds: xr.Dataset) -> xr.Dataset:
    """Store text as zarr 3's specified variable-length ``string`` type.

    numpy's fixed-width ``<U`` arrays would become zarr's ``FixedLengthUTF32``, which has no
    zarr v3 specification (other readers may not open it); read back, text is numpy's
    ``StringDType``.
    """
    fixed = [name for name, var in ds.variables.items() if var.dtype.kind == "U"]
    text = np.dtypes.StringDType()  # stays lazy for dask data, unlike ``object``
    return ds.assign({name: ds[name].astype(text) for name in fixed}) if fixed else ds


def _chunk_files(root: Path) -> dict[str, int]:
    files: dict[str, int] = {}
    for dirpath, _, filenames in os.walk(root):
        for name in filenames:
            if name == "zarr.json" or name.endswith(PARTIAL_SUFFIX):
                continue
            full = Path(dirpath) / name
            files[full.relative_to(root).as_posix()] = full.stat().st_size
    return files


class RunStore:
    """A measurement run on disk: a zarr v3 directory whose groups are xarray Datasets.

    Use :meth:`create` for a new run and :meth:`open` for an existing one.

    Examples
    --------
    >>> store = RunStore.create("run.zarr")                        # doctest: +SKIP
    >>> store.write("raw/dark", raw_dark, chunks={"frame": 16})    # doctest: +SKIP
    >>> store.read("raw/dark").frames                              # doctest: +SKIP
    """

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path).absolute()

    def __repr__(self) -> str:
        return f"RunStore({str(self.path)!r})"

    # -- opening ---------------------------------------------------------------------------
    @classmethod
    def create(
        cls,
        path: str | os.PathLike[str],
        *,
        attrs: Mapping[str, Any] | None = None,
        exist_ok: bool = False,
    ) -> RunStore:
        """Create an empty run store at ``path`` (or open it if ``exist_ok`` and it is one)."""
        path = Path(path)
        if path.exists():
            if exist_ok:
                return cls.open(path)
            raise StoreError(f"cannot create run store {str(path)!r}: the path already exists")
        meta = {
            "spectralize": {"format": STORE_FORMAT, "version": STORE_FORMAT_VERSION},
            **dict(attrs or {}),
        }
        zarr.open_group(str(path), mode="w-", zarr_format=3, attributes=meta)
        return cls(path)

    @classmethod
    def open(cls, path: str | os.PathLike[str]) -> RunStore:
        """Open an existing run store.

        Raises
        ------
        StoreError
            If ``path`` does not exist, is not a zarr v3 group, or was not made as a run store.
        """
        path = Path(path)
        meta_file = path / "zarr.json"
        if not path.is_dir():
            raise StoreError(f"{str(path)!r} is not a run store: no such directory")
        if not meta_file.is_file():
            raise StoreError(
                f"{str(path)!r} is not a zarr v3 store: it has no zarr.json "
                "(create one with `RunStore.create` or `spectralize run simulate`)"
            )
        try:
            meta = json.loads(meta_file.read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise StoreError(f"{str(meta_file)!r} is not readable zarr metadata: {error}") from None
        if meta.get("zarr_format") != 3 or meta.get("node_type") != "group":
            raise StoreError(
                f"{str(path)!r} is not a zarr v3 group: zarr.json has zarr_format="
                f"{meta.get('zarr_format')!r}, node_type={meta.get('node_type')!r}"
            )
        tag = (meta.get("attributes") or {}).get("spectralize", {})
        if tag.get("format") != STORE_FORMAT:
            raise StoreError(
                f"{str(path)!r} is a zarr store but not a spectralize run store: its root attrs "
                f"lack spectralize.format == {STORE_FORMAT!r}"
            )
        store = cls(path)
        store._recover_interrupted_replacements()
        return store

    @property
    def attrs(self) -> dict[str, Any]:
        """The store's root attrs."""
        return dict(json.loads((self.path / "zarr.json").read_text()).get("attributes") or {})

    # -- listing ---------------------------------------------------------------------------
    def _group_path(self, group: str) -> Path:
        parts = group.strip("/").split("/")
        if not group.strip("/") or any(p in ("", ".", "..") or p.startswith(".") for p in parts):
            raise StoreError(f"invalid group name {group!r}: use names like 'raw/dark' or 'hdr'")
        return self.path.joinpath(*parts)

    @staticmethod
    def _group_meta(path: Path) -> dict[str, Any] | None:
        try:
            meta = json.loads((path / "zarr.json").read_text())
        except (OSError, json.JSONDecodeError):
            return None
        return meta if meta.get("node_type") == "group" else None

    def groups(self) -> list[str]:
        """Finished groups: those holding arrays, sorted; containers and staging excluded."""
        found = []
        for dirpath, dirnames, filenames in os.walk(self.path):
            dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
            here = Path(dirpath)
            if here == self.path or "zarr.json" not in filenames:
                continue
            if self._group_meta(here) is None:
                dirnames[:] = []  # an array: nothing below it is a group
                continue
            if self._is_finished(here):
                found.append(here.relative_to(self.path).as_posix())
        return sorted(found)

    def _is_finished(self, path: Path) -> bool:
        meta = self._group_meta(path)
        if meta is None:
            return False
        if FINGERPRINT_ATTR in (meta.get("attributes") or {}):
            return True
        for child in path.iterdir():
            try:
                if json.loads((child / "zarr.json").read_text()).get("node_type") == "array":
                    return True
            except (OSError, json.JSONDecodeError):
                continue
        return False

    def has(self, group: str) -> bool:
        """Whether ``group`` is a finished group of this store."""
        return self._is_finished(self._group_path(group))

    def group_attrs(self, group: str) -> dict[str, Any]:
        """The attrs of ``group`` (without reading any data)."""
        meta = self._group_meta(self._group_path(group))
        if meta is None:
            raise StoreError(f"{self.path.name} has no group {group!r}; it has: {self.groups()}")
        return dict(meta.get("attributes") or {})

    def fingerprint(self, group: str) -> str | None:
        """The fingerprint of a finished group, ``None`` if there is no such group.

        Groups written by spectralize carry theirs. A group imported by other means gets a
        content fingerprint from the names, sizes and modification times of its files, so
        replacing raw data in place re-runs everything downstream.
        """
        if not self.has(group):
            return None
        attrs = self.group_attrs(group)
        if FINGERPRINT_ATTR in attrs:
            return str(attrs[FINGERPRINT_ATTR])
        root = self._group_path(group)
        digest = hashlib.sha256()
        for dirpath, dirnames, filenames in sorted(os.walk(root)):
            dirnames.sort()
            for name in sorted(filenames):
                stat = (Path(dirpath) / name).stat()
                rel = (Path(dirpath) / name).relative_to(root).as_posix()
                digest.update(f"{rel}:{stat.st_size}:{stat.st_mtime_ns};".encode())
        return "content:" + digest.hexdigest()

    def provenance(self, group: str) -> dict[str, Any]:
        """How ``group`` was made: node, version, parameters, inputs, time."""
        return dict(self.group_attrs(group).get(PROVENANCE_ATTR) or {})

    # -- reading ---------------------------------------------------------------------------
    def read(
        self,
        group: str,
        *,
        chunks: Mapping[str, int] | None = None,
        verify: bool = True,
    ) -> xr.Dataset:
        """Open ``group`` lazily as an :class:`xarray.Dataset` (dask-backed).

        Parameters
        ----------
        group
            Group path, e.g. ``"raw/dark"``.
        chunks
            Dask chunks per dim; by default the chunks the group was written with.
        verify
            Check the chunk manifest first and raise if a chunk file is missing or changed.
        """
        if not self.has(group):
            raise StoreError(
                f"{self.path.name} has no finished group {group!r}; it has: {self.groups()}"
            )
        if verify:
            problems = self.verify(group)
            if problems:
                raise StoreError(
                    f"group {group!r} of {self.path.name} is damaged and was not read:\n"
                    + "\n".join(f"  - {p}" for p in problems)
                )
        return xr.open_zarr(
            str(self.path),
            group=group.strip("/"),
            consolidated=False,
            chunks=dict(chunks) if chunks is not None else {},
        )

    def verify(self, group: str) -> list[Problem]:
        """Compare the chunk files of ``group`` with the manifest written at commit time."""
        manifest = self.group_attrs(group).get(MANIFEST_ATTR)
        if not manifest:
            return []
        found = _chunk_files(self._group_path(group))
        problems = []
        for rel, size in sorted(manifest.items()):
            if rel not in found:
                problems.append(
                    Problem(f"{group}/{rel}", f"a chunk file of {size} bytes", "a missing file")
                )
            elif found[rel] != size:
                problems.append(
                    Problem(
                        f"{group}/{rel}",
                        f"{size} bytes",
                        f"{found[rel]} bytes (truncated or overwritten)",
                    )
                )
        return problems

    def validate(self) -> list[Problem]:
        """Check every finished group against its schema and its manifest."""
        problems: list[Problem] = []
        for group in self.groups():
            problems += self.verify(group)
            attrs = self.group_attrs(group)
            name = attrs.get(SCHEMA_ATTR, group)
            if name not in GROUP_SCHEMAS:
                continue
            ds = xr.open_zarr(str(self.path), group=group, consolidated=False)
            problems += validate_dataset(ds, GROUP_SCHEMAS[name], group=group)
        staging = self.path / STAGING
        if staging.is_dir():
            for leftover in sorted(p.name for p in staging.iterdir() if p.name != "zarr.json"):
                problems.append(
                    Problem(
                        f"{STAGING}/{leftover}",
                        "no unfinished writes",
                        "an unfinished or interrupted write (harmless; a rerun resumes or replaces it)",
                    )
                )
        return problems

    # -- writing ---------------------------------------------------------------------------
    def write(
        self,
        group: str,
        ds: xr.Dataset,
        *,
        schema: GroupSchema | str | None = None,
        fingerprint: str | None = None,
        provenance: Mapping[str, Any] | None = None,
        chunks: Mapping[str, int] | None = None,
        encoding: Mapping[str, Mapping[str, Any]] | None = None,
        resumable_along: str | None = None,
        concurrent_regions: int = 1,
        progress: Callable[[str], None] | None = None,
    ) -> str:
        """Write ``ds`` as ``group``, atomically, and return its fingerprint.

        Parameters
        ----------
        group
            Target group path.
        ds
            Data; dask-backed data is streamed chunk by chunk.
        schema
            Contract the data must follow (default: the registered schema named like the
            group, if any). It is checked *before* anything is written.
        fingerprint, provenance
            Identity of the node run that made the data (see :func:`compute_fingerprint`).
            Without one, a random fingerprint is used (the data has no reproducible recipe).
        chunks
            Explicit chunk size per dim on disk (default: the dask chunks of ``ds``).
        encoding
            Per-variable zarr encoding (zarr 3 keys, e.g. ``{"compressors": (codec,)}``).
        resumable_along
            Write region by region along this dim, flagging each finished region, so an
            interrupted write with the same fingerprint resumes where it stopped. The regions
            are the dask chunks of ``ds`` along the dim (they may differ in size); on disk
            the dim is chunked by 1, so no two regions share a chunk.
        concurrent_regions
            How many regions are computed and written at the same time (resumable writes).
        progress
            Called with a short message after each region.

        Raises
        ------
        SchemaError
            If the data does not follow its schema (nothing is written).
        """
        target = self._group_path(group)
        if isinstance(schema, str):
            schema = schema_for(schema)
        elif schema is None:
            schema = GROUP_SCHEMAS.get(group.strip("/"))
        if schema is not None:
            problems = validate_dataset(ds, schema, group=group)
            if problems:
                raise SchemaError(
                    f"refusing to write group {group!r}: it breaks schema {schema.name!r}", problems
                )
        if resumable_along is not None and resumable_along not in ds.dims:
            raise StoreError(
                f"resumable_along={resumable_along!r} is not a dim of the data "
                f"for {group!r} (dims: {sorted(map(str, ds.dims))})"
            )
        fingerprint = fingerprint or f"unrecorded:{uuid.uuid4().hex}"
        ds = _regular_chunks(ds, chunks, region_dim=resumable_along)
        attrs = {k: v for k, v in ds.attrs.items() if k not in _BOOKKEEPING}
        attrs[FINGERPRINT_ATTR] = fingerprint
        attrs[PROVENANCE_ATTR] = {
            **dict(provenance or {}),
            "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        if schema is not None:
            attrs[SCHEMA_ATTR] = schema.name
        ds = _variable_length_strings(ds.copy(deep=False))
        ds.attrs = attrs

        root = zarr.open_group(str(self.path), mode="r+")
        root.require_group(STAGING)
        staged_name = f"{_stem(group)}.{hashlib.sha256(fingerprint.encode()).hexdigest()[:16]}"
        staged = f"{STAGING}/{staged_name}"
        staged_path = self.path / STAGING / staged_name
        enc = {name: dict(value) for name, value in (encoding or {}).items()}
        if resumable_along is None:
            if staged_path.exists():
                shutil.rmtree(staged_path)  # leftover of an interrupted attempt
            ds.to_zarr(
                str(self.path),
                group=staged,
                mode="w",
                consolidated=False,
                zarr_format=3,
                encoding=enc or None,
            )
        else:
            _region_encoding(ds, resumable_along, enc)
            self._write_regions(
                ds, staged, staged_path, resumable_along, enc, progress, max(1, int(concurrent_regions))
            )
        self._commit(staged_path, target, group)
        return fingerprint

    def _write_regions(
        self,
        ds: xr.Dataset,
        staged: str,
        staged_path: Path,
        dim: str,
        encoding: dict[str, dict[str, Any]],
        progress: Callable[[str], None] | None,
        concurrent: int,
    ) -> None:
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
        flags_path = f"{STAGING}/{staged_path.name}.done"
        flags = None
        if staged_path.exists() and (self.path / flags_path).exists():
            flags = zarr.open_array(str(self.path), path=flags_path, mode="r+")
            if flags.shape != (len(regions),):
                flags = None
        if flags is None:
            for leftover in (staged_path, self.path / flags_path):
                if leftover.exists():
                    shutil.rmtree(leftover)
            ds.to_zarr(
                str(self.path),
                group=staged,
                mode="w",
                consolidated=False,
                zarr_format=3,
                compute=False,
                encoding=encoding or None,
            )
            flags = zarr.create_array(
                str(self.path),
                name=flags_path,
                shape=(len(regions),),
                chunks=(1,),
                dtype="bool",
                fill_value=False,
            )
        _remove_partial_chunks(staged_path)
        _remove_partial_chunks(self.path / flags_path)
        done = flags[:]
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
            piece.to_zarr(
                str(self.path), group=staged, mode="r+", region={dim: region}, consolidated=False
            )
            flags[index] = True  # its own chunk of the flag array: no two writers share one
            return index

        todo = [i for i in range(total) if not done[i]]
        finished = len(skipped)
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
        shutil.rmtree(self.path / flags_path)

    def _commit(self, staged_path: Path, target: Path, group: str) -> None:
        manifest = _chunk_files(staged_path)
        zarr.open_group(str(staged_path), mode="r+").attrs.update({MANIFEST_ATTR: manifest})
        parent = "/".join(group.strip("/").split("/")[:-1])
        if parent:
            zarr.open_group(str(self.path), mode="r+").require_group(parent)
        replaced = None
        if target.exists():
            replaced = self.path / STAGING / f"{_stem(group)}.replaced-{uuid.uuid4().hex[:8]}"
            os.rename(target, replaced)
        os.rename(staged_path, target)
        if replaced is not None:
            shutil.rmtree(replaced)

    def _recover_interrupted_replacements(self) -> None:
        """Put back a previous result whose replacement was interrupted between two renames."""
        staging = self.path / STAGING
        if not staging.is_dir():
            return
        for entry in staging.iterdir():
            if ".replaced-" not in entry.name:
                continue
            group = entry.name.split(".replaced-")[0].replace("~", "/")
            target = self._group_path(group)
            if target.exists():
                shutil.rmtree(entry)
            else:
                os.rename(entry, target)

    def discard_staging(self) -> None:
        """Remove every unfinished write (they would otherwise be resumed)."""
        staging = self.path / STAGING
        if staging.is_dir():
            for entry in staging.iterdir():
                if entry.name != "zarr.json":
                    shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
