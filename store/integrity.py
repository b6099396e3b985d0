"""Integrity of a run store's groups: a manifest of every file with its CRC-32, checked on read.

When a group is committed, every file of it (chunks and array metadata, not its own
``zarr.json``, whose consolidated metadata changes as the store grows) is listed with its
size, modification time and CRC-32 (:func:`make_manifest`) in a file beside them,
:data:`MANIFEST_FILE` (:func:`write_manifest`): not in the group's attributes, so the
metadata a reader opens stays small at any image count (stores of the first layout kept it
there; :func:`load_manifest` reads both). :func:`verify_files` compares a group on disk with that
manifest: cheaply (sizes; the checksum of every file whose time changed, an edit in place) or
deeply (every checksum, bit rot that left the time alone). :class:`CheckedLocalStore` checks
every file it serves against its checksum as it is read (a shard read by byte ranges is
checked whole, once per store object), so a missing, truncated,
edited or bit-flipped chunk is reported instead of silently read as fill values or garbage.
"""

from __future__ import annotations

import json
import os
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from zarr.storage import LocalStore

from spectralize.schemas import Problem, StoreError

__all__ = [
    "ChecksumError",
    "CheckedLocalStore",
    "MANIFEST_FORMAT",
    "PARTIAL_SUFFIX",
    "chunk_files",
    "crc32",
    "load_manifest",
    "make_manifest",
    "metadata_files",
    "MANIFEST_FILE",
    "read_manifest",
    "verify_files",
    "write_manifest",
]

MANIFEST_FORMAT = 2  # {"format": 2, "checksum": "crc32", "files": {rel: [size, mtime_ns, crc]}}
MANIFEST_FILE = "spectralize_manifest.json"  # beside a group's zarr.json
PARTIAL_SUFFIX = ".partial"  # zarr's local store writes a chunk to NAME.<uuid>.partial, then renames
READ_BLOCK_BYTES = 4 * 2**20  # a file's checksum is computed on blocks of this size


class ChecksumError(StoreError):
    """A chunk whose bytes do not match the checksum recorded when its group was committed.

    ``key`` is the chunk's store key (``"hdr/radiance/c/0/0/0/0"``): the group it belongs to
    is what a flow recomputes (a derived group) or reports (a raw one).
    """

    key: str = ""


def is_group_dir(path: Path) -> bool:
    """Whether ``path`` is a zarr group (its ``zarr.json`` says so)."""
    try:
        return json.loads((path / "zarr.json").read_text()).get("node_type") == "group"
    except (OSError, ValueError):
        return False


def chunk_files(root: Path) -> dict[str, os.stat_result]:
    """Every file of the group at ``root`` but its own ``zarr.json`` and manifest.

    Nested groups (their own manifests) and zarr's in-flight ``*.partial`` files are left out.
    """
    files: dict[str, os.stat_result] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if not is_group_dir(here / d)]
        for name in filenames:
            if (here == root and name in ("zarr.json", MANIFEST_FILE)) or name.endswith(PARTIAL_SUFFIX):
                continue
            full = here / name
            files[full.relative_to(root).as_posix()] = full.stat()
    return files


def metadata_files(root: Path) -> list[Path]:
    """The metadata of the group at ``root``: every ``zarr.json`` of it and its manifest."""
    found = [root / "zarr.json", root / MANIFEST_FILE]
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = [d for d in dirnames if not is_group_dir(here / d)]
        found += [here / name for name in filenames if name == "zarr.json" and here != root]
    return [p for p in found if p.is_file()]


def crc32(path: Path) -> int:
    """CRC-32 of a file's bytes, read :data:`READ_BLOCK_BYTES` at a time."""
    crc = 0
    with open(path, "rb") as file:
        while block := file.read(READ_BLOCK_BYTES):
            crc = zlib.crc32(block, crc)
    return crc


def make_manifest(root: Path) -> dict[str, Any]:
    """The manifest of the group at ``root``: every file with its size, time and CRC-32."""
    return {
        "format": MANIFEST_FORMAT,
        "checksum": "crc32",
        "files": {
            rel: [stat.st_size, stat.st_mtime_ns, crc32(root / rel)]
            for rel, stat in sorted(chunk_files(root).items())
        },
    }


def write_manifest(root: Path, manifest: dict[str, Any]) -> None:
    """Write ``manifest`` (:func:`make_manifest`) beside the group's ``zarr.json``."""
    (root / MANIFEST_FILE).write_text(json.dumps(manifest, separators=(",", ":")))


def load_manifest(root: Path, attrs: Mapping[str, Any], attr: str) -> dict[str, Any] | None:
    """The manifest of the group at ``root``: its :data:`MANIFEST_FILE`, else the attr ``attr``
    of the first store layout (``None`` for groups imported without one)."""
    try:
        return json.loads((root / MANIFEST_FILE).read_text())
    except FileNotFoundError:
        value = attrs.get(attr)
        return json.loads(value) if isinstance(value, str) else value
    except (OSError, ValueError) as error:
        raise StoreError(f"the manifest of group {str(root)!r} is not readable: {error}") from None


def read_manifest(value: Any) -> dict[str, tuple[int, int | None, int | None]] | None:
    """The manifest attr as ``{file: (size, mtime_ns, crc32)}`` (old stores: sizes only)."""
    if not value:
        return None
    if isinstance(value, str):
        value = json.loads(value)
    if isinstance(value, dict) and value.get("format") == MANIFEST_FORMAT:
        return {rel: (int(e[0]), int(e[1]), int(e[2])) for rel, e in value["files"].items()}
    return {rel: (int(size), None, None) for rel, size in dict(value).items()}


def verify_files(
    root: Path,
    manifest: Mapping[str, tuple[int, int | None, int | None]],
    group: str,
    *,
    deep: bool = False,
) -> list[Problem]:
    """Compare the files of the group ``group`` at ``root`` with its manifest.

    The cheap check compares sizes and modification times and recomputes the checksum of
    every file whose time changed; ``deep=True`` recomputes every checksum. Files added
    after the commit are problems too (manifests with checksums only).
    """
    found = chunk_files(root)
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
            actual = crc32(root / rel)
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


class CheckedLocalStore(LocalStore):
    """A local zarr store that checks every file it serves against its recorded CRC-32.

    ``checksums`` maps store keys (``"hdr/radiance/c/0/0/0/0"``) to checksums; keys it does
    not list are served unchecked. A whole file is checked as it is read; a file read by byte
    ranges (a shard: its index, then its chunks) is read whole and checked at its first read.
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
        self._checked: set[str] = set()

    def with_read_only(self, read_only: bool = False) -> CheckedLocalStore:
        return type(self)(self.root, read_only=read_only, checksums=self.checksums)

    async def get(self, key: str, prototype: Any = None, byte_range: Any = None) -> Any:
        expected = self.checksums.get(key)
        if expected is not None and byte_range is not None and key not in self._checked:
            whole = await super().get(key, prototype)
            if whole is not None:
                self._check(key, whole, expected)
        buffer = await super().get(key, prototype, byte_range)
        if buffer is not None and byte_range is None and expected is not None:
            self._check(key, buffer, expected)
        return buffer

    def _check(self, key: str, buffer: Any, expected: int) -> None:
        found = zlib.crc32(buffer.as_numpy_array())
        if found == expected:
            self._checked.add(key)
            return
        error = ChecksumError(
            f"chunk {key} of run store {str(self.root)!r} is damaged: its bytes do not "
            "match the checksum recorded when it was written",
            [Problem(key, f"CRC-32 {expected:08x}", f"CRC-32 {found:08x}")],
        )
        error.key = key
        raise error
