"""Run stores: one zarr v3 directory per measurement run, one xarray Dataset per group.

Writes are atomic at the group level. A group is staged beside the store and renamed
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
    every file of the group (chunks and array metadata) with its size, modification time
    and CRC-32, so that a missing, truncated, edited or bit-flipped chunk is reported instead
    of silently read as fill values or garbage.

Bookkeeping that is not a plain value (provenance, manifest) is stored as a JSON string, so
a group opened with plain xarray can be written to netCDF; :meth:`RunStore.read` decodes it.

Checks, from cheap to deep: :meth:`RunStore.verify` compares sizes and modification times
with the manifest and recomputes the checksum of every file whose time changed (an edit in
place); ``verify(group, deep=True)`` recomputes every checksum; and every chunk that
:meth:`RunStore.read` serves is checked against its checksum as it is read.

One process writes a store at a time: :meth:`RunStore.write` holds the store's lock
(:mod:`.lock`). Staged groups live in the store's work directory beside it
(``.<store>.spectralize/staging/``, see :func:`~.lock.work_dir`) with names unique to the write
(``<group>.<fingerprint>.<pid>-<random>``), as zarr stores of their own, so they are
invisible to ``xarray.open_datatree``; a writer only ever removes its own. Large outputs can
be written region by region (``resumable_along=``): every finished region is flagged, and a
later writer with the same fingerprint adopts an abandoned staged group (renaming it to its
own name, under the lock) and writes only the regions that were not finished.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import time
import uuid
import zlib
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
import zarr
from zarr.storage import LocalStore

from .errors import Problem, SchemaError, StoreError
from .lock import StoreBusyError, StoreLock, work_dir
from .run import GROUP_SCHEMAS, schema_for
from .spec import GroupSchema, validate_dataset

__all__ = [
    "RunStore",
    "compute_fingerprint",
    "FINGERPRINT_ATTR",
    "PROVENANCE_ATTR",
    "SCHEMA_ATTR",
    "MANIFEST_ATTR",
    "ChecksumError",
    "StoreBusyError",
    "StoreLock",
    "work_dir",
]

STORE_FORMAT = "spectralize-run-store"
STORE_FORMAT_VERSION = 1
FINGERPRINT_ATTR = "spectralize_fingerprint"
PROVENANCE_ATTR = "spectralize_provenance"
SCHEMA_ATTR = "spectralize_schema"
MANIFEST_ATTR = "spectralize_manifest"
STAGING = ".staging"  # where stores before the work directory staged their writes
_BOOKKEEPING = (FINGERPRINT_ATTR, PROVENANCE_ATTR, SCHEMA_ATTR, MANIFEST_ATTR)
_JSON_ATTRS = (PROVENANCE_ATTR, MANIFEST_ATTR)
MANIFEST_FORMAT = 2  # {"format": 2, "checksum": "crc32", "files": {rel: [size, mtime_ns, crc]}}
_NO_SPACE = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}
_READ_ONLY = {errno.EROFS, errno.EACCES, errno.EPERM}


class ChecksumError(StoreError):
    """A chunk whose bytes do not match the checksum recorded when its group was committed."""


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


def _is_group_dir(path: Path) -> bool:
    try:
        return json.loads((path / "zarr.json").read_text()).get("node_type") == "group"
    except (OSError, ValueError):
        return False


def _chunk_files(root: Path) -> dict[str, os.stat_result]:
    """Every file of the group at ``root`` but its own ``zarr.json`` (which holds the manifest).

    Nested groups (their own manifests) and zarr's in-flight ``*.partial`` files are left out.
    """
    files: dict[str, os.stat_result] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if not _is_group_dir(here / d)]
        for name in filenames:
            if (here == root and name == "zarr.json") or name.endswith(PARTIAL_SUFFIX):
                continue
            full = here / name
            files[full.relative_to(root).as_posix()] = full.stat()
    return files


def _crc32(path: Path) -> int:
    crc = 0
    with open(path, "rb") as file:
        while block := file.read(1 << 22):
            crc = zlib.crc32(block, crc)
    return crc


def _manifest(value: Any) -> dict[str, tuple[int, int | None, int | None]] | None:
    """The manifest attr as ``{file: (size, mtime_ns, crc32)}`` (old stores: sizes only)."""
    if not value:
        return None
    if isinstance(value, str):
        value = json.loads(value)
    if isinstance(value, dict) and value.get("format") == MANIFEST_FORMAT:
        return {rel: (int(e[0]), int(e[1]), int(e[2])) for rel, e in value["files"].items()}
    return {rel: (int(size), None, None) for rel, size in dict(value).items()}


def _json_attr(value: Any) -> Any:
    if isinstance(value, str):
        try:
            return json.loads(value)
        except ValueError:
            return value
    return value


class _CheckedLocalStore(LocalStore):
    """A local zarr store that checks every whole chunk it serves against its recorded CRC-32.

    ``checksums`` maps store keys (``"hdr/radiance/c/0/0/0/0"``) to checksums; keys it does
    not list are served unchecked.
    """

    def __init__(
        self,
        root: Path | str,
        *,
        read_only: bool = True,
        checksums: Mapping[str, int] | None = None,
    ) -> None:
        super().__init__(root, read_only=read_only)
        self.checksums = dict(checksums or {})

    def with_read_only(self, read_only: bool = False) -> _CheckedLocalStore:
        return type(self)(self.root, read_only=read_only, checksums=self.checksums)

    async def get(self, key: str, prototype: Any = None, byte_range: Any = None) -> Any:
        buffer = await super().get(key, prototype, byte_range)
        expected = self.checksums.get(key)
        if buffer is not None and byte_range is None and expected is not None:
            found = zlib.crc32(buffer.as_numpy_array())
            if found != expected:
                raise ChecksumError(
                    f"chunk {key} of run store {str(self.root)!r} is damaged: its bytes do not "
                    "match the checksum recorded when it was written",
                    [Problem(key, f"CRC-32 {expected:08x}", f"CRC-32 {found:08x}")],
                )
        return buffer


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
    def staging_dir(self) -> Path:
        """Where unfinished writes are staged: ``.<store>.spectralize/staging`` beside the store."""
        return work_dir(self.path) / "staging"

    def _staging_dirs(self) -> list[Path]:
        return [d for d in (self.staging_dir, self.path / STAGING) if d.is_dir()]

    def lock(self, purpose: str = ""):
        """Hold this store's write lock (a context manager; re-entrant within a process).

        Raises :class:`StoreBusyError` at once when another process writes to the store,
        :class:`StoreError` when the store cannot be written (read-only, no permission).
        """
        return StoreLock(self.path).hold(purpose)

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
        return dict(_json_attr(self.group_attrs(group).get(PROVENANCE_ATTR)) or {})

    def size_on_disk(self, group: str) -> int:
        """Bytes the files of a finished group take (0 when there is no such group)."""
        if not self.has(group):
            return 0
        return sum(st.st_size for st in _chunk_files(self._group_path(group)).values())

    # -- reading ---------------------------------------------------------------------------
    def read(
        self,
        group: str,
        *,
        chunks: Mapping[str, int] | None = None,
        verify: bool = True,
        friendly: bool = True,
    ) -> xr.Dataset:
        """Open ``group`` lazily as an :class:`xarray.Dataset` (dask-backed).

        Parameters
        ----------
        group
            Group path, e.g. ``"raw/dark"``.
        chunks
            Dask chunks per dim; by default the chunks the group was written with.
        verify
            Check the group's files against its manifest first (sizes; checksums of files
            changed since) and raise if one is missing, truncated or edited; then check every
            chunk against its checksum as it is read (:class:`ChecksumError`).
        friendly
            Make the dataset convenient to explore: dims whose index is not in label order
            (``image`` of ``spectra`` and ``evaluation``, written image set by image set)
            sorted, per-image and other small coordinates loaded, ``y``/``x`` given pixel
            index coordinates. Nodes read with ``friendly=False``: the data as stored.

        The bookkeeping attrs ``spectralize_provenance`` and ``spectralize_manifest`` are
        JSON text (so the dataset writes with ``to_netcdf``); :meth:`provenance` gives the
        provenance as a dict.
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
        ds = self._open(group, checked=verify, chunks=chunks)
        for attr in _JSON_ATTRS:  # JSON text, as stored: netCDF attrs cannot hold dicts
            if attr in ds.attrs and not isinstance(ds.attrs[attr], str):
                ds.attrs[attr] = _canonical(ds.attrs[attr])
        return _friendly(ds) if friendly else ds

    def _open(
        self, group: str, *, checked: bool = True, chunks: Mapping[str, int] | None = None
    ) -> xr.Dataset:
        checksums: dict[str, int] = {}
        if checked:
            manifest = _manifest(self.group_attrs(group).get(MANIFEST_ATTR)) or {}
            prefix = group.strip("/")
            checksums = {
                f"{prefix}/{rel}": crc for rel, (_, _, crc) in manifest.items() if crc is not None
            }
        return xr.open_zarr(
            _CheckedLocalStore(self.path, read_only=True, checksums=checksums),
            group=group.strip("/"),
            consolidated=False,
            chunks=dict(chunks) if chunks is not None else {},
        )

    def verify(self, group: str, *, deep: bool = False) -> list[Problem]:
        """Compare the files of ``group`` with the manifest written at commit time.

        The cheap check (default) compares sizes and modification times and recomputes the
        checksum of every file whose time changed; ``deep=True`` recomputes every checksum
        (finds bit rot that left the time alone). Groups imported by other means have no
        manifest and always pass.
        """
        manifest = _manifest(self.group_attrs(group).get(MANIFEST_ATTR))
        if not manifest:
            return []
        root = self._group_path(group)
        found = _chunk_files(root)
        problems = []
        for rel, (size, mtime, crc) in sorted(manifest.items()):
            where = f"{group}/{rel}"
            stat = found.get(rel)
            if stat is None:
                problems.append(Problem(where, f"a file of {size} bytes", "a missing file"))
            elif stat.st_size != size:
                problems.append(
                    Problem(where, f"{size} bytes", f"{stat.st_size} bytes (truncated or overwritten)")
                )
            elif crc is not None and (deep or stat.st_mtime_ns != mtime):
                actual = _crc32(root / rel)
                if actual != crc:
                    how = "edited after commit" if stat.st_mtime_ns != mtime else "changed on disk"
                    problems.append(
                        Problem(where, f"content with CRC-32 {crc:08x}", f"CRC-32 {actual:08x} ({how})")
                    )
        if any(crc is not None for _, _, crc in manifest.values()):
            for rel in sorted(set(found) - set(manifest)):
                problems.append(
                    Problem(f"{group}/{rel}", "only the files written at commit", "a file added later")
                )
        return problems

    def validate(
        self, *, deep: bool = False, values: bool = True, required: Sequence[str] = ()
    ) -> list[Problem]:
        """Check every finished group against its manifest and its schema, values included.

        Parameters
        ----------
        deep
            Recompute the checksum of every file (reads all data once) instead of only
            those whose size or time changed.
        values
            Check values on disk against the contract (NaN/inf, declared ranges):
            coordinates and small variables are loaded, large ones reduced with dask.
        required
            Groups that must be there (e.g. the raw groups a flow needs).

        Unfinished writes are not problems; see :meth:`staging_leftovers`.
        """
        problems: list[Problem] = []
        for group in required:
            if not self.has(group):
                problems.append(Problem(group, "a finished group (the flow reads it)", "nothing"))
        for group in self.groups():
            damaged = self.verify(group, deep=deep)
            problems += damaged
            name = self.group_attrs(group).get(SCHEMA_ATTR, group)
            if name not in GROUP_SCHEMAS:
                continue
            try:
                ds = self._open(group, checked=True)
                problems += validate_dataset(
                    ds, GROUP_SCHEMAS[name], group=group, values=values and not damaged
                )
            except ChecksumError as error:
                problems += error.problems
        return problems

    def staging_leftovers(self) -> list[Problem]:
        """Unfinished writes in :attr:`staging_dir` (warnings: a rerun resumes or replaces them,
        ``spectralize clean`` removes them)."""
        return [
            Problem(
                str(entry),
                "no unfinished writes",
                "an unfinished or interrupted write (harmless; a rerun resumes or replaces it, "
                "`spectralize clean` removes it)",
            )
            for staging in self._staging_dirs()
            for entry in sorted(staging.iterdir())
            if entry.name != "zarr.json"
        ]

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
        StoreBusyError
            If another process is writing to the store.
        StoreError
            If the store is read-only, the disk has too little free space for the data
            (uncompressed), or fills up while writing: nothing is committed and this write's
            staged copy is removed.
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
        attrs[PROVENANCE_ATTR] = _canonical(
            {**dict(provenance or {}), "written": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        )
        if schema is not None:
            attrs[SCHEMA_ATTR] = schema.name
        ds = _variable_length_strings(ds.copy(deep=False))
        ds.attrs = attrs
        enc = {name: dict(value) for name, value in (encoding or {}).items()}

        with self.lock():
            self.check_free_space(int(ds.nbytes), group=group)
            staging = self.staging_dir
            prefix = f"{_stem(group)}.{hashlib.sha256(fingerprint.encode()).hexdigest()[:16]}"
            staged_path = staging / f"{prefix}.{os.getpid()}-{uuid.uuid4().hex[:8]}"
            try:
                staging.mkdir(exist_ok=True)
                if resumable_along is None:
                    ds.to_zarr(
                        str(staged_path),
                        mode="w-",
                        consolidated=False,
                        zarr_format=3,
                        encoding=enc or None,
                    )
                else:
                    _region_encoding(ds, resumable_along, enc)
                    self._adopt_abandoned(prefix, staged_path)
                    self._write_regions(
                        ds,
                        staged_path,
                        resumable_along,
                        enc,
                        progress,
                        max(1, int(concurrent_regions)),
                    )
                self._commit(staged_path, target, group)
            except BaseException as error:
                keep = resumable_along is not None and not (
                    isinstance(error, OSError) and error.errno in _NO_SPACE
                )
                if not keep:  # only this write's own staged copy, never another's
                    _remove_tree(staged_path, _flags_path(staged_path))
                if isinstance(error, OSError):
                    raise self._write_error(error, group) from error
                raise
        return fingerprint

    def check_free_space(self, needed: int, *, group: str = "") -> None:
        """Raise :class:`StoreError` if the store's file system has less than ``needed`` bytes free."""
        free = shutil.disk_usage(self.path).free
        if needed > free:
            what = f"group {group!r}" if group else "the next result"
            raise StoreError(
                f"not enough free space in run store {str(self.path)!r} for {what}: it needs up "
                f"to {_mb(needed)} (uncompressed), the file system has {_mb(free)} free",
                [Problem(str(self.path), f"at least {_mb(needed)} free", f"{_mb(free)} free")],
            )

    def _write_error(self, error: OSError, group: str) -> StoreError:
        if error.errno in _NO_SPACE:
            free = shutil.disk_usage(self.path).free
            return StoreError(
                f"disk full while writing group {group!r} to run store {str(self.path)!r} "
                f"({_mb(free)} free now): nothing was committed, the staged copy was removed; "
                "free some space and run again"
            )
        if error.errno in _READ_ONLY:
            return StoreError(
                f"run store {str(self.path)!r} is read-only: cannot write group {group!r} "
                f"({error.strerror})"
            )
        return StoreError(
            f"writing group {group!r} to run store {str(self.path)!r} failed: "
            f"{type(error).__name__}: {error}"
        )

    def _adopt_abandoned(self, prefix: str, staged_path: Path) -> None:
        """Take over the staged copy of an interrupted write of the same data (under the lock,
        so its writer is gone), renaming it to this write's own name."""
        candidates = [d / prefix for d in self._staging_dirs()] + [
            p
            for d in self._staging_dirs()
            for p in d.glob(f"{prefix}.*")
            if not p.name.endswith(".done")
        ]
        resumable = [
            p for p in candidates if p.is_dir() and _flags_path(p).is_dir() and p != staged_path
        ]
        if not resumable:
            return
        latest = max(resumable, key=lambda p: _flags_path(p).stat().st_mtime_ns)
        os.rename(_flags_path(latest), _flags_path(staged_path))
        os.rename(latest, staged_path)

    def _write_regions(
        self,
        ds: xr.Dataset,
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
        flags_path = _flags_path(staged_path)
        flags = None
        if staged_path.exists() and flags_path.exists():
            flags = zarr.open_array(str(flags_path), mode="r+")
            if flags.shape != (len(regions),):
                flags = None
        if flags is None:
            for leftover in (staged_path, flags_path):
                if leftover.exists():
                    shutil.rmtree(leftover)
            ds.to_zarr(
                str(staged_path),
                mode="w",
                consolidated=False,
                zarr_format=3,
                compute=False,
                encoding=encoding or None,
            )
            flags = zarr.create_array(
                str(flags_path), shape=(len(regions),), chunks=(1,), dtype="bool", fill_value=False
            )
        _remove_partial_chunks(staged_path)
        _remove_partial_chunks(flags_path)
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
            piece.to_zarr(str(staged_path), mode="r+", region={dim: region}, consolidated=False)
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
        shutil.rmtree(flags_path)

    def _commit(self, staged_path: Path, target: Path, group: str) -> None:
        files = _chunk_files(staged_path)
        manifest = {
            "format": MANIFEST_FORMAT,
            "checksum": "crc32",
            "files": {
                rel: [stat.st_size, stat.st_mtime_ns, _crc32(staged_path / rel)]
                for rel, stat in sorted(files.items())
            },
        }
        zarr.open_group(str(staged_path), mode="r+").attrs.update({MANIFEST_ATTR: _canonical(manifest)})
        parent = "/".join(group.strip("/").split("/")[:-1])
        if parent:
            zarr.open_group(str(self.path), mode="r+").require_group(parent)
        replaced = None
        if target.exists():
            replaced = self.staging_dir / f"{_stem(group)}.replaced-{uuid.uuid4().hex[:8]}"
            os.rename(target, replaced)
        os.rename(staged_path, target)
        if replaced is not None:
            shutil.rmtree(replaced)

    def _recover_interrupted_replacements(self) -> None:
        """Put back a previous result whose replacement was interrupted between two renames.

        Only when no other process writes (a live writer may be between its two renames)
        and the store is writable; otherwise the next writer does it.
        """
        replaced = [p for d in self._staging_dirs() for p in d.iterdir() if ".replaced-" in p.name]
        if not replaced:
            return
        try:
            with self.lock("recovering an interrupted replacement"):
                for entry in replaced:
                    if not entry.exists():
                        continue
                    if ".replaced-" not in entry.name:
                        continue
                    group = entry.name.split(".replaced-")[0].replace("~", "/")
                    target = self._group_path(group)
                    if target.exists():
                        shutil.rmtree(entry)
                    else:
                        os.rename(entry, target)
        except StoreError:
            return

    def clean(self) -> list[str]:
        """Remove every unfinished write (holding the lock, so none is live).

        Returns the names removed. Raises :class:`StoreBusyError` while a run writes.
        """
        removed: list[str] = []
        with self.lock("spectralize clean"):
            for staging in self._staging_dirs():
                for entry in sorted(staging.iterdir()):
                    if entry.name != "zarr.json":
                        removed.append(entry.name)
                    shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
                staging.rmdir()
        return removed

    def discard_staging(self) -> None:
        """Remove every unfinished write (they would otherwise be resumed)."""
        self.clean()


def _remove_tree(*paths: Path) -> None:
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


def _flags_path(staged_path: Path) -> Path:
    return staged_path.with_name(f"{staged_path.name}.done")


def _mb(size: float) -> str:
    return f"{size / 1e6:,.1f} MB" if size >= 1e6 else f"{size / 1e3:,.1f} kB"


def _friendly(ds: xr.Dataset) -> xr.Dataset:
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
