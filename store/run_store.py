"""Run stores: one zarr v3 directory per measurement run, one xarray Dataset per group.

:class:`RunStore` is the public API (``create``, ``open``, ``groups``, ``read``, ``write``,
``verify``, ``validate``, ``clean``); :func:`open_run` opens one for analysis. Writes are
atomic at the group level (:mod:`.staging`), and every finished group carries in its attrs

``spectralize_fingerprint``
    a hash of (node name, node version, parameters, input fingerprints), see
    :func:`~.fingerprint.compute_fingerprint`: a step whose output already carries the
    fingerprint it would write is up to date (this is what resumes flows);
``spectralize_provenance``
    those ingredients in readable form;
``spectralize_schema``
    the name of the schema the group follows (:mod:`spectralize.schemas`);
and beside its ``zarr.json``, not in its attrs (they would grow with the image count and
be read by every open), the files

``spectralize_manifest.json``
    every file of the group with its size, modification time and CRC-32 (:mod:`.integrity`);
``<record>.json``
    records a writer keeps with the group (``write(records=...)``, :meth:`RunStore.record`),
    such as which capture file each raw frame came from.

Provenance is stored as a JSON string, so a group opened with plain xarray can be written to
netCDF; :meth:`RunStore.provenance` decodes it. Groups are laid out for a full run
(:mod:`.layout`: label order, one chunk per small variable, large ones in zarr 3 shards) and
the store keeps consolidated metadata, so ``xarray.open_zarr(store, group=...)`` and
``xarray.open_datatree(store, engine="zarr")`` open it quickly and see what
:meth:`RunStore.read` sees. Stores of the first layout (format version 1) are read as they
are; their groups' fingerprints differ from this layout's
(:data:`~.fingerprint.STORE_LAYOUT`), so a flow or ingest recomputes them in this layout.

Arrays whose schema declares a precision (the reconstructed cube) are rounded to it and
state it in their attrs (:mod:`.precision`); ``validate`` checks both.

Checks, from cheap to deep: :meth:`RunStore.verify` compares sizes and modification times
with the manifest and recomputes the checksum of every file whose time changed (an edit in
place); ``verify(group, deep=True)`` recomputes every checksum; and every chunk that
:meth:`RunStore.read` serves is checked against its checksum as it is read.

One process writes a store at a time: :meth:`RunStore.write` holds the store's lock
(:mod:`.lock`).
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import socket
import time
import uuid
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, cast

import numpy as np
import xarray as xr
import zarr

from spectralize.schemas import (
    GROUP_SCHEMAS,
    GroupSchema,
    Problem,
    SchemaError,
    StoreError,
    schema_for,
    validate_dataset,
)

from .fingerprint import canonical_json
from .integrity import (
    MANIFEST_FILE,
    CheckedLocalStore,
    ChecksumError,
    chunk_files,
    load_manifest,
    make_manifest,
    read_manifest,
    verify_files,
    write_manifest,
)
from .layout import friendly as friendly_view
from .layout import label_order, region_encoding, regular_chunks, shard_layout, variable_length_strings
from .lock import StoreLock, work_dir
from .precision import apply_precision, declared_precisions, precision_encoding, precision_problems
from .staging import (
    STAGING,
    adopt_abandoned,
    flags_path,
    open_flags,
    pack_staged,
    packed_path,
    regions_path,
    remove_abandoned,
    remove_tree,
    replace_group,
    replaced_group,
    staged_path,
    write_regions,
)

__all__ = [
    "RunStore",
    "open_run",
    "FINGERPRINT_ATTR",
    "PROVENANCE_ATTR",
    "SCHEMA_ATTR",
    "MANIFEST_ATTR",
    "DAMAGED_ATTR",
]

STORE_FORMAT = "spectralize-run-store"
STORE_FORMAT_VERSION = 2  # 2: sharded, label order, manifests beside zarr.json, consolidated
FINGERPRINT_ATTR = "spectralize_fingerprint"
PROVENANCE_ATTR = "spectralize_provenance"
SCHEMA_ATTR = "spectralize_schema"
MANIFEST_ATTR = "spectralize_manifest"
DAMAGED_ATTR = "spectralize_damaged"  # why a group is not to be trusted (set by mark_damaged)
_BOOKKEEPING = (FINGERPRINT_ATTR, PROVENANCE_ATTR, SCHEMA_ATTR, MANIFEST_ATTR, DAMAGED_ATTR)
_JSON_ATTRS = (PROVENANCE_ATTR, MANIFEST_ATTR)  # MANIFEST_ATTR: in stores of the first layout
_NO_SPACE = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}
_READ_ONLY = {errno.EROFS, errno.EACCES, errno.EPERM}


def _json_attr(value: Any) -> Any:
    """A JSON object or list stored as text, decoded; anything else as it is."""
    if isinstance(value, str) and value[:1] in ("{", "["):
        try:
            return json.loads(value)
        except ValueError:
            return value
    return value


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
        meta = {  # plain values: the root writes to netCDF (open_datatree(...).to_netcdf())
            "spectralize_format": STORE_FORMAT,
            "spectralize_format_version": STORE_FORMAT_VERSION,
            **{
                k: canonical_json(v) if isinstance(v, dict | list) else v
                for k, v in (attrs or {}).items()
            },
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
        root = meta.get("attributes") or {}
        tag = root.get("spectralize") or {  # the first layout kept a dict
            "format": root.get("spectralize_format"),
            "version": root.get("spectralize_format_version"),
        }
        if tag.get("format") != STORE_FORMAT:
            raise StoreError(
                f"{str(path)!r} is a zarr store but not a spectralize run store: its root attrs "
                f"lack spectralize_format == {STORE_FORMAT!r}"
            )
        if int(tag.get("version") or 1) > STORE_FORMAT_VERSION:
            raise StoreError(
                f"{str(path)!r} is a run store of format version {tag.get('version')}, newer than "
                f"this spectralize reads ({STORE_FORMAT_VERSION}): upgrade spectralize"
            )
        store = cls(path)
        store._recover_interrupted_replacements()
        return store

    @property
    def format_version(self) -> int:
        """The layout version the store was created with (1: before shards, see the module)."""
        attrs = json.loads((self.path / "zarr.json").read_text()).get("attributes") or {}
        tag = attrs.get("spectralize") or {"version": attrs.get("spectralize_format_version")}
        return int(tag.get("version") or 1)

    def first_layout_note(self) -> str | None:
        """For a store of the first layout: what happens to it (its groups are recomputed)."""
        if self.format_version >= STORE_FORMAT_VERSION:
            return None
        return (
            f"run store {str(self.path)!r} has the first layout (format version "
            f"{self.format_version}: one file per image and chunk, set order, manifests in the "
            f"attrs); it is read as it is, and every group this flow makes is recomputed in "
            f"format {STORE_FORMAT_VERSION} (sharded, label order); run `spectralize ingest` "
            "on its capture folder again to migrate the raw groups too"
        )

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
        """The store's root attrs (values stored as JSON text decoded)."""
        attrs = json.loads((self.path / "zarr.json").read_text()).get("attributes") or {}
        return {k: _json_attr(v) for k, v in attrs.items()}

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

    def manifest(self, group: str) -> dict[str, Any] | None:
        """The manifest written when ``group`` was committed (``None``: imported without one)."""
        return load_manifest(self._group_path(group), self.group_attrs(group), MANIFEST_ATTR)

    def record(self, group: str, name: str, default: Any = None) -> Any:
        """A record kept with ``group`` (``write(records={name: ...})``), else ``default``.

        Stores of the first layout kept records in the group's attrs; they are read too.
        """
        try:
            return json.loads((self._group_path(group) / f"{name}.json").read_text())
        except FileNotFoundError:
            return self.group_attrs(group).get(name, default)

    def size_on_disk(self, group: str) -> int:
        """Bytes the files of a finished group take (0 when there is no such group)."""
        if not self.has(group):
            return 0
        return sum(st.st_size for st in chunk_files(self._group_path(group)).values())

    # -- reading ---------------------------------------------------------------------------
    def read(
        self,
        group: str,
        *,
        chunks: Mapping[str, int] | str | None = None,
        verify: bool = True,
        friendly: bool = True,
        dask: bool = True,
    ) -> xr.Dataset:
        """Open ``group`` lazily as an :class:`xarray.Dataset` (dask-backed).

        Parameters
        ----------
        group
            Group path, e.g. ``"raw/dark"``.
        chunks
            Dask chunks per dim; by default the chunks the group was written with;
            ``"shards"``: whole shards along each sharded variable's first dim (its chunks
            along the others, :meth:`shard_chunks`), for a reader that streams the whole
            group (a full run of small frames: a task per shard of ~1,000 images instead of
            a task per image).
        verify
            Check the group's files against its manifest first (sizes; checksums of files
            changed since) and raise if one is missing, truncated or edited; then check every
            chunk against its checksum as it is read (:class:`ChecksumError`).
        friendly
            Make the dataset convenient to explore: dims whose index is not in label order
            (``image`` of ``spectra`` and ``evaluation``, written image set by image set)
            sorted, per-image and other small coordinates loaded, ``y``/``x`` given pixel
            index coordinates. Nodes read with ``friendly=False``: the data as stored.
        dask
            ``False``: lazily indexed arrays without dask (``chunks`` is then ignored); a
            selection reads only the stored chunks it touches, each still checked. For a
            reader of a few images of a large run: no task per chunk to build.

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
        ds = self._open(group, checked=verify, chunks=chunks, dask=dask)
        for attr in _JSON_ATTRS:  # JSON text, as stored: netCDF attrs cannot hold dicts
            if attr in ds.attrs and not isinstance(ds.attrs[attr], str):
                ds.attrs[attr] = canonical_json(ds.attrs[attr])
        return friendly_view(ds) if friendly else ds

    def shard_chunks(self, group: str) -> dict[str, int]:
        """Dask chunks of whole shards for ``group``: per dim, the largest shard extent of
        a sharded variable whose first dim it is, else the largest chunk along it; dims of
        unsharded variables only are left out (their stored chunks)."""
        found: dict[str, int] = {}
        for meta_path in sorted(self._group_path(group).glob("*/zarr.json")):
            meta = json.loads(meta_path.read_text())
            codecs = meta.get("codecs") or [{}]
            if meta.get("node_type") != "array" or codecs[0].get("name") != "sharding_indexed":
                continue
            shard = meta["chunk_grid"]["configuration"]["chunk_shape"]
            inner = codecs[0]["configuration"]["chunk_shape"]
            for axis, dim in enumerate(meta.get("dimension_names") or []):
                size = int(shard[axis] if axis == 0 else inner[axis])
                found[dim] = max(found.get(dim, 0), size)
        return found

    def _open(
        self,
        group: str,
        *,
        checked: bool = True,
        chunks: Mapping[str, int] | str | None = None,
        dask: bool = True,
    ) -> xr.Dataset:
        checksums: dict[str, int] = {}
        if checked:
            manifest = read_manifest(self.manifest(group)) or {}
            prefix = group.strip("/")
            checksums = {
                f"{prefix}/{rel}": crc for rel, (_, _, crc) in manifest.items() if crc is not None
            }
        meta = self._group_meta(self._group_path(group)) or {}
        if chunks == "shards":
            chunks = self.shard_chunks(group)
        elif isinstance(chunks, str):
            raise StoreError(f"chunks for {group!r}: a mapping of dim sizes or 'shards', got {chunks!r}")
        with warnings.catch_warnings():
            # shards span many of a small variable's one chunk (per-image coordinates)
            warnings.filterwarnings("ignore", "The specified chunks separate", UserWarning)
            return xr.open_zarr(
                CheckedLocalStore(self.path, read_only=True, checksums=checksums),
                group=group.strip("/"),
                consolidated=bool(meta.get("consolidated_metadata")),
                chunks=(dict(chunks) if chunks is not None else {}) if dask else None,
            )

    def verify(self, group: str, *, deep: bool = False) -> list[Problem]:
        """Compare the files of ``group`` with the manifest written at commit time.

        The cheap check (default) compares sizes and modification times and recomputes the
        checksum of every file whose time changed; ``deep=True`` recomputes every checksum
        (finds bit rot that left the time alone). A group marked damaged
        (:meth:`mark_damaged`: a chunk failed its checksum when it was read) fails either
        check until it is written again. Groups imported by other means (no fingerprint) have
        no manifest and always pass; a group with a fingerprint but no manifest fails: it was
        rewritten by other means (xarray keeps a group's attrs, its fingerprint among them, but
        not the manifest beside them), so nothing vouches for its files.
        """
        attrs = self.group_attrs(group)
        problems = []
        if attrs.get(DAMAGED_ATTR):
            problems.append(Problem(group, "an undamaged group", str(attrs[DAMAGED_ATTR])))
        manifest = read_manifest(self.manifest(group))
        if manifest:
            problems += verify_files(self._group_path(group), manifest, group, deep=deep)
        elif FINGERPRINT_ATTR in attrs:
            problems.append(
                Problem(
                    group,
                    f"its checksum manifest ({MANIFEST_FILE}, written with its fingerprint)",
                    "none: it was rewritten by other means (xarray keeps a group's attrs, its "
                    "fingerprint among them, not the manifest beside them), so its fingerprint "
                    "vouches for nothing",
                )
            )
        return problems

    def mark_damaged(self, group: str, reason: str) -> None:
        """Mark ``group`` damaged (``reason``: which chunk failed and how), holding the lock.

        Only the group's own ``zarr.json`` changes (it is not in the manifest); from now on
        :meth:`verify` fails for it, so nothing trusts it as up to date and a flow recomputes
        it, until a write replaces it.
        """
        path = self._group_path(group) / "zarr.json"
        with self.lock(f"mark {group} damaged"):
            meta = json.loads(path.read_text())
            meta.setdefault("attributes", {})[DAMAGED_ATTR] = reason
            temporary = path.with_name(f"zarr.json.{os.getpid()}.tmp")
            temporary.write_text(json.dumps(meta, indent=2))
            os.replace(temporary, path)
            self._consolidate()

    def group_of(self, key: str) -> str | None:
        """The finished group a store key (``"hdr/radiance/c/0/0/0/0"``) belongs to."""
        parts = key.strip("/").split("/")
        for end in range(len(parts) - 1, 0, -1):
            group = "/".join(parts[:end])
            try:
                if self.has(group):
                    return group
            except StoreError:
                continue
        return None

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
            coordinates and small variables are loaded, large ones reduced with dask. Arrays
            stored at a declared precision (:mod:`.precision`) have their codecs checked
            always, and their values checked to carry no more mantissa bits than their attrs
            state: the first and last chunk, or (``deep``) every value.
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
                schema = GROUP_SCHEMAS[name]
                checked = values and not damaged
                problems += validate_dataset(ds, schema, group=group, values=checked)
                problems += precision_problems(
                    self._group_path(group), ds, schema, group, values=checked, deep=deep
                )
            except ChecksumError as error:
                problems += cast(list[Problem], error.problems)  # always Problems
        return problems

    def staging_leftovers(self) -> list[Problem]:
        """Unfinished writes in :attr:`staging_dir`, told apart by whether their writer lives.

        While a process on this host that is alive holds the store's lock (its side file says
        which), the staging is that live run's work in progress; otherwise it is a dead run's
        leftover (harmless: a rerun resumes or replaces it, ``spectralize clean`` removes it).
        """
        holder = StoreLock(self.path).holder()
        live = holder is not None and _alive(holder.pid, holder.host)
        found = (
            f"the work in progress of a live run ({holder.describe()}"
            f"{f', {holder.command}' if holder.command else ''}); leave it"
            if live and holder is not None
            else "an unfinished or interrupted write (harmless; a rerun resumes or replaces it, "
            "`spectralize clean` removes it)"
        )
        return [
            Problem(str(entry), "no unfinished writes", found)
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
        records: Mapping[str, Any] | None = None,
        commit: bool = True,
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
            are the dask chunks of ``ds`` along the dim (they may differ in size; small ones
            are written together), each staged as files of its own
            (:func:`~.staging.stage_region`); finished, the group is packed into shards
            (:mod:`.layout`) with the chunks a write of the data in one piece gets, whatever
            the regions were.
        concurrent_regions
            How many regions are computed and written at the same time (resumable writes).
        progress
            Called with a short message after each region.
        records
            Name -> JSON value kept beside the group as ``<name>.json`` (in its manifest, not
            its attrs): bookkeeping that grows with the data (:meth:`record` reads it).
        commit
            ``False``: stage the write only (a resumable one), every region written and
            flagged but nothing packed or committed, the group not visible. The next write
            of the same data (same group and fingerprint) adopts the staged regions and
            commits them without computing any again; :meth:`discard_staged` removes them.
            So a writer can stage several groups and commit them only once each is staged.

        Raises
        ------
        SchemaError
            If the data does not follow its schema (nothing is written).
        StoreBusyError
            If another process is writing to the store.
        StoreError
            If the store is read-only, the disk has too little free space for the data
            (uncompressed), or fills up while writing: nothing is committed and this write's
            staged copy is removed. Also if ``commit=False`` without ``resumable_along``.
        """
        if not commit and resumable_along is None:
            raise StoreError(
                f"commit=False for group {group!r} needs resumable_along (a dim of the data): "
                "only a write staged region by region is kept staged, found resumable_along=None"
            )
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
        ds = regular_chunks(ds, chunks, region_dim=resumable_along)
        attrs = {k: _netcdf_value(v) for k, v in ds.attrs.items() if k not in _BOOKKEEPING}
        attrs[FINGERPRINT_ATTR] = fingerprint
        attrs[PROVENANCE_ATTR] = canonical_json(
            {**dict(provenance or {}), "written": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        )
        if schema is not None:
            attrs[SCHEMA_ATTR] = schema.name
        ds = netcdf_attrs(variable_length_strings(ds.copy(deep=False)))
        # the precision its schema declares: rounded here, or while a resumable write is
        # packed (every region alike, whoever staged it)
        precisions = declared_precisions(ds, schema)
        ds = apply_precision(ds, precisions, round_values=resumable_along is None)
        if resumable_along is None:
            ds = label_order(ds)  # a resumable write is sorted when it is packed
        ds.attrs = attrs
        enc = precision_encoding(
            precisions, {name: dict(value) for name, value in (encoding or {}).items()}
        )

        with self.lock():
            self.check_free_space(int(ds.nbytes), group=group)
            staging = self.staging_dir
            prefix, staged = staged_path(staging, group, fingerprint)
            try:
                staging.mkdir(exist_ok=True)
                if resumable_along is None:
                    remove_abandoned(self._staging_dirs(), prefix, staged)
                    ds = shard_layout(ds, enc, keep=chunks or ())
                    ds.to_zarr(
                        str(staged),
                        mode="w-",
                        consolidated=False,
                        zarr_format=3,
                        encoding=enc or None,
                    )
                else:
                    region_encoding(ds, resumable_along, enc)
                    adopt_abandoned(self._staging_dirs(), prefix, staged)
                    write_regions(
                        ds,
                        staged,
                        resumable_along,
                        enc,
                        progress,
                        max(1, int(concurrent_regions)),
                        keep_flags=not commit,
                    )
                    if not commit:  # staged and flagged, for the next write of this data
                        return fingerprint
                    pack_staged(
                        staged,
                        keep=chunks or (),
                        dim=resumable_along,
                        codecs=enc,
                        precisions=precisions,
                    )
                self._commit(staged, target, group, records or {})
            except BaseException as error:
                # kept for the next write to resume: the regions of an interrupted resumable
                # write (its flags say which are done); never a copy being packed
                keep = (
                    resumable_along is not None
                    and open_flags(staged) is not None
                    and not (isinstance(error, OSError) and error.errno in _NO_SPACE)
                )
                remove_tree(packed_path(staged))
                if not keep:  # only this write's own staged copy, never another's
                    remove_tree(staged, flags_path(staged), regions_path(staged))
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

    def _commit(self, staged: Path, target: Path, group: str, records: Mapping[str, Any]) -> None:
        for name, value in records.items():
            if name == MANIFEST_FILE.removesuffix(".json") or "/" in name or name.startswith("."):
                raise StoreError(f"invalid record name {name!r} for group {group!r}")
            (staged / f"{name}.json").write_text(json.dumps(value, separators=(",", ":")))
        with warnings.catch_warnings():  # the records and manifest are not zarr
            warnings.simplefilter("ignore")
            zarr.consolidate_metadata(str(staged))
        write_manifest(staged, make_manifest(staged))
        parent = "/".join(group.strip("/").split("/")[:-1])
        if parent:
            zarr.open_group(str(self.path), mode="r+").require_group(parent)
        replace_group(staged, target, self.staging_dir, group)
        self._consolidate()

    def _consolidate(self) -> None:
        """Consolidated metadata at the root (every group's arrays and attrs in one file).

        Warnings about what others put in the store (files that are not zarr, text of types
        without a zarr 3 specification) are not this writer's to raise.
        """
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            zarr.consolidate_metadata(str(self.path))

    def _recover_interrupted_replacements(self) -> None:
        """Put back a previous result whose replacement was interrupted between two renames.

        Only when no other process writes (a live writer may be between its two renames)
        and the store is writable; otherwise the next writer does it.
        """
        replaced = [
            p for d in self._staging_dirs() for p in d.iterdir() if replaced_group(p) is not None
        ]
        if not replaced:
            return
        try:
            with self.lock("recovering an interrupted replacement"):
                for entry in replaced:
                    group = replaced_group(entry)
                    if group is None or not entry.exists():
                        continue
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

    def discard_staged(self, group: str, fingerprint: str) -> None:
        """Remove every staged copy of ``group`` with ``fingerprint`` (holding the lock).

        What a write with ``commit=False`` left staged, and anything an interrupted write of
        the same data left; other groups' and other data's unfinished writes are kept.

        Parameters
        ----------
        group
            The group path the data was staged for.
        fingerprint
            The fingerprint it was staged with (see :meth:`write`).

        Raises
        ------
        StoreBusyError
            If another process is writing to the store.
        """
        with self.lock():
            prefix, _ = staged_path(self.staging_dir, group, fingerprint)
            remove_abandoned(self._staging_dirs(), prefix, None)


def _netcdf_value(value: Any) -> Any:
    """An attr value netCDF can hold: booleans as 0 / 1 (``if attrs[...]`` reads the same)."""
    if isinstance(value, bool | np.bool_):
        return int(value)
    if isinstance(value, list | tuple) and value and all(isinstance(v, bool) for v in value):
        return [int(v) for v in value]
    return value


def netcdf_attrs(ds: xr.Dataset) -> xr.Dataset:
    """``ds`` with every variable's boolean attrs as 0 / 1 (netCDF has no boolean type)."""
    for var in ds.variables.values():
        var.attrs = {k: _netcdf_value(v) for k, v in var.attrs.items()}
    return ds


def _alive(pid: int | None, host: str) -> bool:
    """Whether the process ``pid`` of ``host`` lives (another host's: assumed alive)."""
    if pid is None:
        return False
    if host != socket.gethostname():
        return True
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


def _mb(size: float) -> str:
    return f"{size / 1e6:,.1f} MB" if size >= 1e6 else f"{size / 1e3:,.1f} kB"


def open_run(path: str | os.PathLike[str]) -> RunStore:
    """Open a run store for analysis.

    A run's groups read as lazy xarray Datasets (dask-backed, chunked as stored), with the
    units and long names of the run's schema in their attrs; ``open_run("run.zarr")
    .read("spectra")`` is the reconstructed cube (image, wavelength, y, x).

    Parameters
    ----------
    path
        The run store's directory (``spectralize ingest`` or ``spectralize run`` made it).

    Returns
    -------
    RunStore
        The store, checked to be a spectralize run store of a format this version reads.

    Raises
    ------
    StoreError
        If ``path`` is not a run store, or one of a newer format.

    Examples
    --------
    A store with one small group, written and read back:

    >>> import numpy as np, xarray as xr
    >>> store = RunStore.create("example.zarr")
    >>> level = xr.DataArray(np.arange(6.0).reshape(2, 3), dims=("y", "x"),
    ...                      attrs={"units": "1", "long_name": "relative radiance"})
    >>> fingerprint = store.write("notes", xr.Dataset({"level": level}))
    >>> run = open_run("example.zarr")
    >>> run.groups()
    ['notes']
    >>> notes = run.read("notes")
    >>> notes.level.attrs["units"], float(notes.level.sum())
    ('1', 15.0)

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series (the run's data: sec. 4 and 5).
    """
    return RunStore.open(path)
