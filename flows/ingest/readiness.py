"""Is a capture folder complete? The question ``spectralize serve`` asks before ingesting.

A gantry writes a capture folder over hours; a nightly run ingests it only when every file
its manifest lists is there and nothing changed for a while (:func:`capture_state`).

References
----------
Fast Capture of Spectral Image Series, sec. 3 (a measurement run of the gantry).
"""

from __future__ import annotations

import csv
import os
import time
from dataclasses import dataclass
from pathlib import Path

from spectralize.datasets.capture import CALIBRATION, CONFIG, MANIFEST
from spectralize.datasets.capture.model import contained_path

__all__ = ["CaptureState", "capture_state"]


@dataclass(frozen=True)
class CaptureState:
    """Whether a capture folder can be ingested now, and why not."""

    path: Path
    ready: bool
    reason: str


def capture_state(path: str | os.PathLike[str], *, settle_seconds: float = 300.0) -> CaptureState:
    """A folder is ready when every file its manifest lists exists and none changed lately.

    Parameters
    ----------
    path
        A capture folder.
    settle_seconds
        A folder in which any file (manifest, config, calibration, image) changed within
        this many seconds is still being written.
    """
    root = Path(path)
    manifest = root / MANIFEST
    if not manifest.is_file():
        return CaptureState(root, False, f"no {MANIFEST} yet")
    try:
        with open(manifest, newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            files = [row.get("file", "").strip() for row in reader]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        return CaptureState(root, False, f"{MANIFEST} is not readable yet ({error})")
    # a name outside the folder counts as present: ingest refuses it and says why
    inside = [path for f in files if f and (path := contained_path(root, f, follow_symlinks=True)[0])]
    missing = [str(p.relative_to(root)) for p in inside if not p.is_file()]
    if missing:
        return CaptureState(
            root,
            False,
            f"{len(missing)} of {len(files)} file(s) listed in {MANIFEST} not present yet "
            f"(e.g. {missing[0]})",
        )
    newest = max(
        (p.stat().st_mtime for p in [manifest, root / CONFIG, *inside] if p.exists()),
        default=0.0,
    )
    calibration = root / CALIBRATION
    if calibration.is_dir():
        newest = max([newest, *(p.stat().st_mtime for p in calibration.iterdir() if p.is_file())])
    age = time.time() - newest
    if age < settle_seconds:
        return CaptureState(
            root, False, f"changed {age:.0f} s ago (waiting until files are {settle_seconds:.0f} s old)"
        )
    return CaptureState(root, True, f"{len(files)} file(s), unchanged for {age:.0f} s")
