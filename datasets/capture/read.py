"""Read and check a whole capture folder: every problem is listed before anything is used.

:func:`read_capture` reads ``capture.toml`` and ``manifest.csv`` (:mod:`.config`,
:mod:`.manifest`), checks the rows (:mod:`.checks`), probes every image file it has not seen
before (:mod:`.images`, in a thread pool: the decoders release the GIL; every header first,
then the pixels of the frames whose header passed, but for the kinds of frame whose values the
caller checks as it decodes them: ingest decodes each frame once) and reads the calibration
tables (:mod:`.calibration`). It raises one :class:`~.model.CaptureError` that lists every
problem with its file and manifest line, or returns a :class:`~.model.Capture`.

References
----------
Fast Capture of Spectral Image Series, sec. 3 and 4 (what a gantry run captures).
"""

from __future__ import annotations

import os
from collections import Counter
from collections.abc import Callable, Collection
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from spectralize.schemas import Problem

from .calibration import read_calibration
from .checks import (
    calibration_bands,
    calibration_cameras,
    check_bands,
    check_frame_shapes,
    check_rows,
    check_structure,
)
from .config import parse_config
from .images import probe
from .manifest import parse_manifest
from .model import CONFIG, MANIFEST, Capture, CaptureError, Config, Row, capture_file, contained_path

__all__ = ["read_capture"]


def read_capture(
    path: str | os.PathLike[str],
    *,
    known: dict[str, tuple[int, int]] | None = None,
    known_shape: tuple[int, int] | None = None,
    progress: Callable[[str], None] | None = None,
    values_checked_later: Collection[str] = (),
) -> Capture:
    """Read and check a capture folder; every problem is collected before raising.

    Parameters
    ----------
    path
        The capture folder.
    known
        ``{file: (size, mtime_ns)}`` of files already ingested and unchanged since: they are
        not decoded again.
    known_shape
        The frame shape of the files in ``known`` (from the store).
    progress
        Called with a short message now and then.
    values_checked_later
        Kinds of frame (``"rgb"``, ``"spectral"``, ``"dark"``) whose pixel values the caller
        checks as it decodes them for writing (ingest, whose workers decode each frame once):
        their headers are checked here, their values only when the folder has another
        problem (so that the error still lists every problem).

    Raises
    ------
    CaptureError
        Listing every problem: a missing or unreadable file, a path outside the folder
        (absolute, ``..``, a symbolic link: :func:`~.model.contained_path`), a frame whose
        header declares more than :data:`~.images.MAX_FRAME_BYTES` or another frame size (not
        decoded), a wrong bit depth or shape, duplicate or contradicting rows, an unknown kind,
        an exposure series with one time, a band shot without a wavelength, calibration tables
        that do not cover the bands.
    """
    root = Path(path)
    say = progress or (lambda message: None)
    if not root.is_dir():
        raise CaptureError.single(str(root), "a capture folder", "no such folder")
    problems: list[Problem] = []
    config = _read_config(root, problems)
    rows = _read_manifest(root, config, problems)
    if config is None:
        raise CaptureError(f"cannot ingest {root}:", problems)
    rows, found = check_rows(rows, config)
    problems += found
    rows, found = _contained(root, rows, config)
    problems += found
    problems += check_structure(rows, config)
    todo = _new_files(root, rows, config, known or {})
    say(f"checking {len(todo)} new or changed file(s) of {len(rows)}")
    headers, frame_shape = _probe_headers(todo, known_shape)
    bands = calibration_bands(rows)
    leds: dict[int, str] = {}
    for row in rows:
        if row.kind in ("rgb", "spectral") and row.led is not None:
            leds.setdefault(row.led, row.where)
    calibration, calibration_problems = read_calibration(
        root, config, bands, frame_shape, calibration_cameras(rows, config), leds
    )
    band_problems = check_bands(rows, bands)
    checked = _probe_values(todo, headers, frame_shape, skip_kinds=set(values_checked_later))
    file_problems = _file_problems(todo, headers, checked, frame_shape)
    if problems or file_problems or calibration_problems or band_problems:
        # a folder with problems: the values of every frame too, so that the error lists all
        checked |= _probe_values(todo, headers, frame_shape, skip_lines=set(checked))
        file_problems = _file_problems(todo, headers, checked, frame_shape)
    say(f"checked {len(todo)} file(s)")
    problems = problems + file_problems + calibration_problems + band_problems
    if problems:
        raise CaptureError(
            f"cannot ingest {root}: {len(problems)} problem(s), nothing was written", problems
        )
    return Capture(
        path=root,
        config=config,
        rows=rows,
        frame_shape=frame_shape,
        bands=bands,
        illuminant=calibration["illuminant"],
        white_reflectance=calibration["white"],
        patches=calibration["patches"],
        patch_index=calibration["patch_index"],
        plan_table=calibration.get("plan"),
        rgb_patch_index=calibration["rgb_patch_index"],
        led_power=calibration.get("led_power"),
    )


_Todo = tuple[Row, Path, bool, int]  # (row, file, rgb, bit_depth) of a file to check
_Probed = tuple[tuple[int, int] | None, str | None, str | None]  # what :func:`probe` returns


def _probe_headers(
    todo: list[_Todo], known_shape: tuple[int, int] | None
) -> tuple[list[_Probed], tuple[int, int] | None]:
    """Every file's header (nothing decoded), and the run's frame shape: that of the files
    already ingested, else the most common one declared."""
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        headers = list(pool.map(lambda item: probe(*item[1:], decode=False), todo))
    shapes = Counter(shape for shape, expected, _ in headers if expected is None)
    frame_shape = shapes.most_common(1)[0][0] if shapes else None
    return headers, tuple(known_shape) if known_shape is not None else frame_shape


def _probe_values(
    todo: list[_Todo],
    headers: list[_Probed],
    frame_shape: tuple[int, int] | None,
    *,
    skip_kinds: Collection[str] = (),
    skip_lines: Collection[int] = (),
) -> dict[int, _Probed]:
    """``{manifest line: probe}`` of the files whose header passed, decoded to check their
    values (in a thread pool), but for those of ``skip_kinds`` and ``skip_lines``."""
    good = [
        item
        for item, (_, expected, _) in zip(todo, headers, strict=True)
        if expected is None and item[0].kind not in skip_kinds and item[0].line not in skip_lines
    ]
    if not good:
        return {}
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        found = pool.map(lambda item: probe(*item[1:], frame_shape=frame_shape), good)
        return dict(zip((item[0].line for item in good), found, strict=True))


def _file_problems(
    todo: list[_Todo],
    headers: list[_Probed],
    checked: dict[int, _Probed],
    frame_shape: tuple[int, int] | None,
) -> list[Problem]:
    """A problem for each file whose header or values failed (its value check in ``checked``,
    else its header's), then the frames of another shape than the run's."""
    problems, probed = [], []
    for (row, *_), header in zip(todo, headers, strict=True):
        shape, expected, found = checked.get(row.line, header)
        if expected is not None:
            problems.append(Problem(row.where, expected, found))
        else:
            probed.append((row, shape))
    return problems + check_frame_shapes(probed, frame_shape)


def _contained(root: Path, rows: list[Row], config: Config) -> tuple[list[Row], list[Problem]]:
    """The rows whose file stays inside the folder, and a problem for each that does not."""
    kept, problems = [], []
    for row in rows:
        path, why = contained_path(root, row.file, follow_symlinks=config.follow_symlinks)
        if path is None:
            problems.append(Problem(row.where, "a file inside the capture folder", why))
        else:
            kept.append(row)
    return kept, problems


def _read_config(root: Path, problems: list[Problem]) -> Config | None:
    path, why = contained_path(root, CONFIG, follow_symlinks=True)  # its own rule is inside it
    if path is None:
        problems.append(Problem(CONFIG, "a file inside the capture folder", why))
        return None
    if not path.is_file():
        problems.append(
            Problem(CONFIG, "a capture.toml describing cameras and bit depths", "no such file")
        )
        return None
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        problems.append(Problem(CONFIG, "a readable TOML file", f"{type(error).__name__}: {error}"))
        return None
    config, found = parse_config(text, root.name)
    problems += found
    return config


def _read_manifest(root: Path, config: Config | None, problems: list[Problem]) -> list[Row]:
    follow = config is not None and config.follow_symlinks
    path, why = contained_path(root, MANIFEST, follow_symlinks=follow)
    if path is None:
        problems.append(Problem(MANIFEST, "a file inside the capture folder", why))
        return []
    if not path.is_file():
        problems.append(Problem(MANIFEST, "one row per image file", "no such file"))
        return []
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            text = handle.read()
    except (OSError, UnicodeDecodeError) as error:
        problems.append(Problem(MANIFEST, "a readable CSV file", f"{type(error).__name__}: {error}"))
        return []
    rows, found = parse_manifest(text)
    problems += found
    return rows


def _new_files(
    root: Path, rows: list[Row], config: Config, known: dict[str, tuple[int, int]]
) -> list[_Todo]:
    """``(row, file, rgb, bit_depth)`` of every file not in ``known`` (or changed since)."""
    todo = []
    for row in rows:
        file = capture_file(root, row.file, follow_symlinks=config.follow_symlinks)
        try:
            st = file.stat()
            if known.get(row.file) == (int(st.st_size), int(st.st_mtime_ns)):
                continue
        except OSError:
            pass
        rgb = row.camera in config.rgb_cameras
        todo.append((row, file, rgb, config.rgb_bit_depth if rgb else config.spectral_bit_depth))
    return todo
