"""``spectralize ingest CAPTURE_DIR STORE``: a capture folder into the raw groups of a run store.

:func:`ingest` plans which files are new (those the store does not hold with the same size and
modification time), reads and checks the folder (:func:`~spectralize.datasets.capture.read_capture`:
every problem is listed before anything is written), builds the raw groups
(:mod:`.raw_groups`) and writes those whose fingerprint changed. Writes are atomic per group
and resumable per image, shot or dark exposure time (:meth:`RunStore.write`).

Re-ingesting is incremental. Each group's fingerprint is made from its manifest rows, the
size and modification time of its files and the calibration tables: unchanged groups are
skipped (and so are the flow steps that depend only on them); a group with new frames is
rewritten with its old frames copied from the store and only the new files read.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the measurement run a capture folder holds).
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from spectralize.datasets.capture import Capture, read_capture
from spectralize.store import RunStore

from ..signals import sigterm_as_interrupt
from .decode import PARALLEL_ABOVE, FrameDecoder
from .raw_groups import FILES_ATTR, INGEST_VERSION, RAW_GROUPS, FrameSources, RawGroup, build_raw_groups

__all__ = ["IngestReport", "ingest"]


@dataclass
class IngestReport:
    """What :func:`ingest` did: per group ``"written"`` or ``"up to date"``, frames read."""

    capture: Path
    store: Path
    groups: dict[str, str] = field(default_factory=dict)
    frames_read: int = 0
    frames_copied: int = 0
    seconds: float = 0.0


def _known_files(store: RunStore) -> tuple[dict[str, tuple[int, int]], tuple[int, int] | None]:
    """The plan's input: ``{file: (size, mtime_ns)}`` of every frame in the store, its frame shape."""
    known: dict[str, tuple[int, int]] = {}
    shape = None
    for group in RAW_GROUPS:
        if not store.has(group):
            continue
        for files in (store.record(group, FILES_ATTR) or {}).values():
            known.update({f: (int(s), int(m)) for f, s, m in files})
        if group == "raw/spectral":
            meta = json.loads((store.path / group / "counts" / "zarr.json").read_text())
            shape = tuple(meta["shape"][1:3])
    return known, shape


class _Eta:
    """Progress messages with an estimate of the time left, at most every ``every`` seconds."""

    def __init__(self, say: Callable[[str], None], label: str, total: int, every: float = 2.0):
        self.say, self.label, self.total, self.every = say, label, max(total, 1), every
        self.start = self.last = time.perf_counter()
        self.done = 0

    def __call__(self, message: str = "") -> None:
        self.done += 1
        now = time.perf_counter()
        if now - self.last < self.every and self.done < self.total:
            return
        self.last = now
        rate = (now - self.start) / self.done
        left = rate * (self.total - self.done)
        self.say(
            f"  {self.label}: {self.done}/{self.total} written, "
            f"{now - self.start:.0f} s, about {left:.0f} s left"
        )


def ingest(
    capture_dir: str | os.PathLike[str],
    store_path: str | os.PathLike[str],
    *,
    progress: Callable[[str], None] | None = None,
) -> IngestReport:
    """Ingest a capture folder into a run store (created if missing); incremental.

    Parameters
    ----------
    capture_dir
        The capture folder (``datasets/README.md``, "Capture folders").
    store_path
        The run store; created when missing. Groups whose frames and calibration did not
        change are left as they are.
    progress
        Called with short progress messages (with an estimate of the time left).

    Returns
    -------
    IngestReport

    Raises
    ------
    CaptureError
        Listing every problem of the capture folder; nothing is written then.
    StoreError
        If ``store_path`` exists and is not a run store.
    """
    with sigterm_as_interrupt():  # stopped like Ctrl-C: finished regions are kept, it resumes
        return _ingest(Path(capture_dir), Path(store_path), progress)


def _ingest(capture_dir: Path, store_path: Path, progress: Callable[[str], None] | None) -> IngestReport:
    start = time.perf_counter()
    say = progress or (lambda message: None)
    existing = RunStore.open(store_path) if store_path.exists() else None
    known, shape = _known_files(existing) if existing is not None else ({}, None)
    capture = read_capture(capture_dir, known=known, known_shape=shape, progress=say)
    store = existing or RunStore.create(
        store_path,
        attrs={"capture": {"folder": str(capture_dir.absolute()), "name": capture.config.name}},
    )
    report = IngestReport(capture_dir, store.path)
    with store.lock(f"spectralize ingest {capture_dir}"):
        _write_groups(capture, store, report, say)
    report.seconds = time.perf_counter() - start
    return report


def _write_groups(
    capture: Capture, store: RunStore, report: IngestReport, say: Callable[[str], None]
) -> None:
    """Write every raw group whose fingerprint changed; each write is atomic and resumable.

    The frames of a chunk are decoded on every core (:class:`~.decode.FrameDecoder`) and
    written in order."""
    with FrameDecoder() as decoder:
        groups = build_raw_groups(capture, store, decoder)
        if sum(sources.read for _, sources in groups) >= PARALLEL_ABOVE:
            decoder.start()
        for group, sources in groups:
            _write_group(capture, store, report, say, group, sources)


def _write_group(
    capture: Capture,
    store: RunStore,
    report: IngestReport,
    say: Callable[[str], None],
    group: RawGroup,
    sources: FrameSources,
) -> None:
    """Write one raw group unless the store holds it with the same fingerprint."""
    capture_dir = capture.path
    if store.fingerprint(group.name) == group.fingerprint and not store.verify(group.name):
        report.groups[group.name] = "up to date"
        say(f"{group.name}: up to date")
        return
    dim = group.resumable
    regions = len(group.dataset.chunksizes.get(dim, ())) if dim else 1
    note = f"{sources.read} frame(s) read, {sources.copied} kept from the store"
    say(f"{group.name}: writing ({note})")
    store.write(
        group.name,
        group.dataset,
        fingerprint=group.fingerprint,
        provenance={
            "node": "ingest",
            "version": INGEST_VERSION,
            "capture": str(capture_dir.absolute()),
        },
        resumable_along=dim,
        records={FILES_ATTR: group.files},
        progress=_Eta(say, group.name, regions) if dim else None,
    )
    report.groups[group.name] = "written"
    report.frames_read += sources.read
    report.frames_copied += sources.copied
