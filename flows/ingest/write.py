"""``spectralize ingest CAPTURE_DIR STORE``: a capture folder into the raw groups of a run store.

:func:`ingest` plans which files are new (those the store does not hold with the same size and
modification time), reads and checks the folder (:func:`~spectralize.datasets.capture.read_capture`:
every problem is listed before anything is written), builds the raw groups
(:mod:`.raw_groups`) and writes those whose fingerprint changed. Writes are atomic per group
and resumable per image, shot or dark exposure time (:meth:`RunStore.write`).

Each frame is decoded once, on every core (:mod:`.decode`). The folder's check reads the
headers of the RGB, band and dark frames, not their pixels: their values are checked as they
are decoded for writing. So that still nothing is written from a folder with a problem, the
groups of those frames are first staged, region by region, and committed only once every
one of them is staged (:func:`_stage_checked`); a frame whose values fail stops the ingest
before any group is committed, and the folder is then checked whole, so that the error lists
every problem as before (a store this ingest created is removed again).

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
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from spectralize.datasets.capture import Capture, CaptureError, read_capture
from spectralize.schemas import StoreError
from spectralize.store import RunStore
from spectralize.store.lock import work_dir

from ..signals import sigterm_as_interrupt
from .decode import PARALLEL_ABOVE, FrameDecoder
from .raw_groups import FILES_ATTR, INGEST_VERSION, RAW_GROUPS, FrameSources, RawGroup, build_raw_groups

__all__ = ["IngestReport", "ingest", "VALUES_CHECKED_WHILE_STAGED"]

VALUES_CHECKED_WHILE_STAGED: tuple[str, ...] = ("rgb", "spectral", "dark")
"""Kinds of frame whose values ingest checks as it decodes them (their groups are resumable:
staged region by region before any group is committed); the others' are checked with the
folder (:func:`~spectralize.datasets.capture.read_capture`)."""


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
    capture = read_capture(
        capture_dir,
        known=known,
        known_shape=shape,
        progress=say,
        values_checked_later=VALUES_CHECKED_WHILE_STAGED,
    )
    store = existing or RunStore.create(
        store_path,
        attrs={"capture": {"folder": str(capture_dir.absolute()), "name": capture.config.name}},
    )
    report = IngestReport(capture_dir, store.path)
    try:
        with store.lock(f"spectralize ingest {capture_dir}"):
            _write_groups(capture, store, report, say)
    except _FrameProblem as problem:  # nothing was committed
        if existing is None:  # the store this ingest created, empty: removed again
            shutil.rmtree(work_dir(store_path), ignore_errors=True)
            shutil.rmtree(store_path, ignore_errors=True)
        # the folder checked whole (every frame's values): the error lists every problem
        read_capture(capture_dir, known=known, known_shape=shape, progress=say)
        raise problem.error from None
    report.seconds = time.perf_counter() - start
    return report


class _FrameProblem(Exception):
    """A frame whose values failed while its group was staged (``error``): nothing committed."""

    def __init__(self, error: CaptureError) -> None:
        super().__init__(str(error))
        self.error = error


def _write_groups(
    capture: Capture, store: RunStore, report: IngestReport, say: Callable[[str], None]
) -> None:
    """Write every raw group whose fingerprint changed; each write is atomic and resumable.

    The frames of a chunk are decoded on every core (:class:`~.decode.FrameDecoder`) and
    written in order; the groups whose frames' values are checked as they are decoded are
    staged first, every one of them, then committed (see the module)."""
    with FrameDecoder() as decoder:
        groups = build_raw_groups(capture, store, decoder)
        if sum(sources.read for _, sources in groups) >= PARALLEL_ABOVE:
            decoder.start()
        staged = _stage_checked(capture, store, say, groups)
        try:
            for group, sources in groups:
                _write_group(capture, store, report, say, group, sources)
                staged.discard(group.name)
        except StoreError:  # a failed write (disk full ...) leaves nothing staged behind
            _discard_staged(store, [g for g, _ in groups if g.name in staged])
            raise


def _needs_writing(store: RunStore, group: RawGroup) -> bool:
    return store.fingerprint(group.name) != group.fingerprint or bool(store.verify(group.name))


def _stage_checked(
    capture: Capture,
    store: RunStore,
    say: Callable[[str], None],
    groups: list[tuple[RawGroup, FrameSources]],
) -> set[str]:
    """Stage (not commit) every group to write that decodes frames whose values are checked
    as they are decoded (:data:`VALUES_CHECKED_WHILE_STAGED`); the names of those staged.

    Each is written with ``commit=False`` (:meth:`RunStore.write`): its regions stay staged
    and flagged, and its write in :func:`_write_group` adopts and commits them.

    Raises
    ------
    _FrameProblem
        For the first frame whose values fail (nothing committed, nothing left staged).
    """
    staged: set[str] = set()
    for group, sources in groups:
        if group.resumable is None or not sources.read or not _needs_writing(store, group):
            continue
        regions = len(group.dataset.chunksizes.get(group.resumable, ()))
        say(f"{group.name}: decoding and checking {sources.read} frame(s)")
        try:
            _write(store, group, capture, _Eta(say, group.name, regions), commit=False)
        except CaptureError as error:  # a refused folder leaves nothing staged
            _discard_staged(store, [g for g, _ in groups if g.name in staged or g is group])
            raise _FrameProblem(error) from error
        staged.add(group.name)
    return staged


def _discard_staged(store: RunStore, groups: list[RawGroup]) -> None:
    """Remove what this ingest staged of ``groups`` (:meth:`RunStore.discard_staged`)."""
    for group in groups:
        store.discard_staged(group.name, group.fingerprint)


def _write(
    store: RunStore,
    group: RawGroup,
    capture: Capture,
    progress: Callable[[str], None] | None,
    *,
    commit: bool = True,
) -> None:
    """:meth:`RunStore.write` of a raw group, with its fingerprint, provenance and files
    (``commit=False``: staged only, see :func:`_stage_checked`)."""
    store.write(
        group.name,
        group.dataset,
        fingerprint=group.fingerprint,
        provenance={
            "node": "ingest",
            "version": INGEST_VERSION,
            "capture": str(capture.path.absolute()),
        },
        resumable_along=group.resumable,
        records={FILES_ATTR: group.files},
        progress=progress,
        commit=commit,
    )


def _write_group(
    capture: Capture,
    store: RunStore,
    report: IngestReport,
    say: Callable[[str], None],
    group: RawGroup,
    sources: FrameSources,
) -> None:
    """Write one raw group unless the store holds it with the same fingerprint."""
    if group.name in report.groups:  # written already
        return
    if not _needs_writing(store, group):
        report.groups[group.name] = "up to date"
        say(f"{group.name}: up to date")
        return
    dim = group.resumable
    regions = len(group.dataset.chunksizes.get(dim, ())) if dim else 1
    note = f"{sources.read} frame(s) read, {sources.copied} kept from the store"
    say(f"{group.name}: writing ({note})")
    _write(store, group, capture, _Eta(say, group.name, regions) if dim else None)
    _written(report, group, sources)


def _written(report: IngestReport, group: RawGroup, sources: FrameSources) -> None:
    report.groups[group.name] = "written"
    report.frames_read += sources.read
    report.frames_copied += sources.copied
