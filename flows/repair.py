"""Damage found in a run store while a flow runs: recompute what the flow makes, refuse the rest.

Nothing damaged or stale is trusted. How much is verified, and when:

- before a step is skipped as up to date, its input and output groups pass the store's cheap
  check (sizes, times, the checksums of files whose time changed, no damage mark:
  :func:`damaged_groups`);
- every chunk a step (or the report) reads is checked against its CRC-32 as it is read; a
  chunk that fails marks its group damaged (:meth:`RunStore.mark_damaged`,
  :func:`repair_chunk`): a group this flow makes is recomputed, with a warning naming the
  chunk, and so is everything that depends on it; a raw group is an error naming the chunk and
  the capture files its frames came from (:func:`mark_damaged_group`);
- ``verify=True`` (``spectralize run --verify``) first recomputes the checksum of every file
  of every group the flow reads or would skip (:func:`verify_deep`: bit rot that kept the
  times, in groups no step reads this time), with the same outcome per group. It costs one
  read of those groups.
- before the report is written or confirmed up to date, the groups it shows
  (:data:`REPORT_GROUPS`) that this run did not write are checked deeply, smallest first, up to
  :data:`REPORT_VERIFY_BYTES` in all (:func:`verify_report_groups`; larger ones are left to
  ``--verify``, and said so): a report never presents rot that a short read could have found.
  A damaged group found there, or by a chunk the report reads, is recomputed with its
  dependants and the report written again, in the same run (:class:`RecomputeBeforeReport`).

What the checks cost: ``datasets/README.md`` (what verifying costs).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence

from spectralize.engine import PlannedStep
from spectralize.schemas import Problem, StoreError
from spectralize.store import ChecksumError, RunStore

from .run_log import info_logger, warn

__all__ = [
    "REPORT_GROUPS",
    "REPORT_VERIFY_BYTES",
    "RecomputeBeforeReport",
    "checksum_error_of",
    "damaged_groups",
    "damaged_input_error",
    "groups_made_by",
    "mark_damaged_group",
    "repair_chunk",
    "verify_deep",
    "verify_report_groups",
]

REPORT_GROUPS = (
    "spectra",
    "evaluation",
    "truth/spectra",
    "calibration/spectral",
    "calibration/oecf_rgb",
    "calibration/oecf_spectral",
    "registration",
    "dark",
    "raw/rgb",
    "raw/spectral",
    "raw/white_reference",
    "raw/exposure_plan",
)
"""The groups :func:`~spectralize.flows.report.write_run_report` reads (a test holds it to that)."""

REPORT_VERIFY_BYTES = 2_000_000_000
"""At most this many bytes of the report's groups are checked deeply before each report: a
short read next to writing the report (what verifying costs: ``datasets/README.md``); larger
groups are left to ``--verify``."""


def damaged_groups(store: RunStore, groups: Sequence[str]) -> dict[str, list[Problem]]:
    """The groups (of those that exist) that fail the store's cheap check, with why."""
    found = {group: store.verify(group) for group in groups if store.has(group)}
    return {group: problems for group, problems in found.items() if problems}


def damaged_input_error(store: RunStore, node: str, damaged: dict[str, list[Problem]]) -> StoreError:
    """The error of a node whose input groups are damaged: each problem with how to fix it."""
    problems = []
    for group, found in damaged.items():
        made_by = store.provenance(group).get("node")
        hint = (
            f"made by node {made_by!r}: run a flow that includes it to recompute it"
            if made_by and not group.startswith("raw/")
            else "raw data: restore the file from the capture, or import the run again"
        )
        problems += [dataclasses.replace(p, hint=hint) for p in found]
    return StoreError(
        f"node {node!r} cannot run on run store {str(store.path)!r}: input group(s) "
        f"{', '.join(damaged)} are damaged (nothing was read or written)",
        problems,
    )


def checksum_error_of(error: BaseException) -> ChecksumError | None:
    """The :class:`ChecksumError` that caused ``error`` (itself, or along its chain)."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        if isinstance(current, ChecksumError):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


def groups_made_by(planned: Sequence[PlannedStep]) -> set[str]:
    """The groups the steps of a flow write."""
    return {group for item in planned for group in item.outputs.values()}


def mark_damaged_group(
    store: RunStore,
    group: str,
    where: str,
    why: str,
    made: set[str],
    *,
    key: str = "",
    cause: BaseException | None = None,
) -> None:
    """Mark a damaged group; a group the flow makes is then recomputed, raw data is an error.

    ``where`` names the damaged chunk or file, ``why`` what is wrong with it, ``key`` the
    chunk's store key (for the capture files of a raw chunk); the error keeps the notes of
    ``cause`` (which node read it).
    """
    store.mark_damaged(group, f"{where}: {why}")
    if group in made:
        warn(f"{group} is damaged ({where}: {why}); recomputing it and the groups that depend on it")
        return
    files: list[str] = []
    if group.startswith("raw/"):
        from spectralize.flows.ingest.raw_groups import capture_files_of_chunk

        files = capture_files_of_chunk(store, key or where)
    source = ""
    if files:
        more = f" and {len(files) - 3} more" if len(files) > 3 else ""
        source = f"; its frames came from capture file(s) {', '.join(files[:3])}{more}"
    folder = (store.attrs.get("capture") or {}).get("folder")
    fix = (
        f"ingest the capture folder again (`spectralize ingest {folder} {store.path}` rewrites "
        "the group from its files)"
        if folder
        else "restore it from its source, or import the run again"
    )
    error = StoreError(
        f"group {group!r} of run store {str(store.path)!r} is damaged and no step of this flow "
        f"can recompute it: {where}: {why}{source}",
        [Problem(where, "the bytes written at commit", why, fix)],
    )
    for note in getattr(cause, "__notes__", ()):
        error.add_note(note)
    raise error from cause


def repair_chunk(store: RunStore, error: ChecksumError, made: set[str], marked: set[str]) -> None:
    """A chunk failed its checksum when read: mark its group damaged (see :func:`mark_damaged_group`).

    Raises the error itself when its group is unknown or was already repaired once in this
    run (a group that is damaged again right after its rewrite is a failing disk, not rot).
    """
    group = store.group_of(error.key) if error.key else None
    if group is None or group in marked:
        raise error
    marked.add(group)
    found = error.problems[0].found if error.problems else "other bytes"
    why = f"its bytes do not match the checksum recorded when it was written ({found})"
    mark_damaged_group(store, group, f"chunk {error.key}", why, made, key=error.key, cause=error)


def verify_deep(store: RunStore, planned: Sequence[PlannedStep], log: Callable[[str], None]) -> None:
    """``--verify``: every checksum of every group the flow reads or writes, before trusting it."""
    groups = sorted({g for item in planned for g in (*item.inputs.values(), *item.outputs.values())})
    made = groups_made_by(planned)
    start, size = time.perf_counter(), 0
    for group in groups:
        if not store.has(group):
            continue
        size += store.size_on_disk(group)
        problems = store.verify(group, deep=True)
        if problems:
            first = problems[0]
            mark_damaged_group(
                store, group, first.where, f"{first.found}, expected {first.expected}", made
            )
    seconds = time.perf_counter() - start
    log(f"verified {len(groups)} group(s), {size / 1e6:,.1f} MB, in {seconds:.2f} s")


class RecomputeBeforeReport(Exception):
    """Groups were marked damaged before the report: run the steps again (they recompute them).

    ``args[0]`` is the :class:`~spectralize.flows.steps.RunReport` of the pass that stopped.
    """


def verify_report_groups(store: RunStore, made: set[str], fresh: set[str]) -> bool:
    """Check the report's groups deeply before the report (see the module's docstring).

    ``fresh``: groups this run wrote (not checked again). Returns ``False`` when a group the
    flow makes was found damaged (it is marked: the steps recompute it); a damaged raw group
    is an error naming the chunk (:func:`mark_damaged_group`).
    """
    groups = sorted((store.size_on_disk(g), g) for g in REPORT_GROUPS if g not in fresh and store.has(g))
    budget, healthy, left = REPORT_VERIFY_BYTES, True, []
    for size, group in groups:
        if size > budget:
            left.append(f"{group} ({size / 1e9:.1f} GB)")
            continue
        budget -= size
        problems = store.verify(group, deep=True)
        if problems:
            first = problems[0]
            mark_damaged_group(
                store, group, first.where, f"{first.found}, expected {first.expected}", made
            )
            healthy = False
    if left:
        info_logger()(
            f"report: not checked deeply before the report (over {REPORT_VERIFY_BYTES / 1e9:g} GB): "
            f"{', '.join(left)}; `spectralize run --verify` checks them"
        )
    return healthy
