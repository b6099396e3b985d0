"""``spectralize ingest CAPTURE_DIR STORE``: a gantry's image files into the raw groups of a run store.

A capture folder (the contract is ``datasets/README.md``, "Capture folders") is

- image files, 16-bit (or 8-bit for cameras of at most 8 bits) TIFF or PNG, monochrome
  (y, x) or RGB (y, x, 3), values right-aligned (at most ``2**bit_depth - 1``);
- ``manifest.csv``: one row per file, columns :data:`MANIFEST_COLUMNS`;
- ``capture.toml``: cameras, bit depths, the exposure plan's constants, the colour chart;
- ``calibration/``: ``illuminant.csv``, ``white_reference.csv``, ``colour_checker.csv`` (or
  a colour-science chart name in ``capture.toml``), the colour checker's patch label image
  and optionally ``exposure_plan.csv``.

:func:`read_capture` checks all of it *before* anything is written, decoding every file it
has not ingested before, and raises one :class:`CaptureError` listing every problem with
its file and manifest line. :func:`ingest` then streams the frames into the groups
``raw/rgb``, ``raw/spectral``, ``raw/dark``, ``raw/white_reference``, ``raw/colour_checker``,
``raw/registration`` and ``raw/exposure_plan``: dask reads one file (one RGB exposure series)
per chunk, so memory is bounded by a chunk, not by the run. Writes are atomic per group and
resumable per image, shot or dark exposure time (:meth:`RunStore.write`).

Re-ingesting is incremental. Each group's fingerprint is made from its manifest rows, the
size and modification time of its files and the calibration tables: unchanged groups are
skipped (and so are the flow steps that depend only on them); a group with new frames is
rewritten with its old frames copied from the store and only the new files read.

Units: nm, s, degree; the illuminant and reflectances are relative (``units = "1"``).
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import time
import tomllib
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import dask
import dask.array as da
import numpy as np
import xarray as xr
import zarr

from spectralize.schemas import Problem, SpectralizeError
from spectralize.schemas.capture import KINDS, MANIFEST_COLUMNS
from spectralize.store import RunStore

__all__ = [
    "MANIFEST",
    "CONFIG",
    "CALIBRATION",
    "MANIFEST_COLUMNS",
    "KINDS",
    "INGEST_VERSION",
    "CaptureError",
    "Capture",
    "IngestReport",
    "read_capture",
    "ingest",
    "capture_state",
]

MANIFEST = "manifest.csv"
CONFIG = "capture.toml"
CALIBRATION = "calibration"
CAPTURE_FORMAT = "spectralize-capture"
#: Bumped when the groups ingest writes change: every group is then rewritten.
INGEST_VERSION = "1"
ANGLES: tuple[str, ...] = ("theta_i", "phi_i", "theta_o", "phi_o")
_ANGLE_RANGE = {
    "theta_i": (0.0, 90.0),
    "theta_o": (0.0, 90.0),
    "phi_i": (0.0, 360.0),
    "phi_o": (0.0, 360.0),
}
_FILES_ATTR = "spectralize_ingest_files"  # per variable: [file, size, mtime_ns] in frame order
_SUFFIXES = (".tif", ".tiff", ".png")


class CaptureError(SpectralizeError, ValueError):
    """A capture folder that cannot be ingested; its problems name file and manifest line."""


# -- reading image files ------------------------------------------------------------------
def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Pixel data of a TIFF (tifffile) or PNG (pypng, 16-bit RGB included) file, as stored."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        import tifffile

        return np.asarray(tifffile.imread(path))
    if suffix == ".png":
        import png

        width, height, rows, info = png.Reader(filename=str(path)).read()
        dtype = np.uint16 if info["bitdepth"] > 8 else np.uint8
        data = np.vstack([np.asarray(row, dtype=dtype) for row in rows])
        planes = int(info["planes"])
        return data.reshape(height, width) if planes == 1 else data.reshape(height, width, planes)
    raise ValueError(f"unknown image format {suffix!r} (use .tif, .tiff or .png)")


# -- the capture's description ------------------------------------------------------------
@dataclass(frozen=True)
class Row:
    """One row of ``manifest.csv`` (``line``: its line number in the file, the header is 1)."""

    line: int
    file: str
    kind: str
    camera: str
    rotation: int | None
    led: int | None
    exposure_time: float | None
    wavelength: float | None
    angles: tuple[float | None, ...]

    @property
    def where(self) -> str:
        return f"{MANIFEST} line {self.line} ({self.file})"


@dataclass(frozen=True)
class Config:
    """What ``capture.toml`` says."""

    name: str
    rgb_cameras: tuple[str, ...]
    rgb_bit_depth: int
    paired_camera: str
    channels: tuple[str, ...]
    spectral_camera: str
    spectral_bit_depth: int
    rotation_step: float
    angle_tolerance: float
    t0: float
    s0: float
    omega: float
    chart: str | None
    patch_index: str
    raw: dict[str, Any] = field(default_factory=dict, compare=False)


@dataclass
class Capture:
    """A checked capture folder: its config, rows, frame shape and calibration tables."""

    path: Path
    config: Config
    rows: list[Row]
    frame_shape: tuple[int, int]
    bands: np.ndarray  # wavelengths of the calibration series [nm]
    illuminant: np.ndarray  # on ``bands``
    white_reflectance: np.ndarray  # on ``bands``
    patches: tuple[list[str], np.ndarray, str]  # names, reflectance (patch, band), chart name
    patch_index: np.ndarray  # (y, x) int16, -1 on the frame
    plan_table: tuple[np.ndarray, np.ndarray, np.ndarray] | None  # wl, time, filter size

    def of(self, kind: str, camera: str | None = None) -> list[Row]:
        return [r for r in self.rows if r.kind == kind and (camera is None or r.camera == camera)]

    def stat(self, row: Row) -> list[Any]:
        """``[file, size, mtime_ns]``: what identifies the version of a frame's file."""
        st = (self.path / row.file).stat()
        return [row.file, int(st.st_size), int(st.st_mtime_ns)]


def _key(value: float) -> float:
    """Exposure times and wavelengths compared after rounding (CSV round trips)."""
    return float(f"{value:.9g}")


def _parse_config(path: Path, problems: list[Problem]) -> Config | None:
    where = CONFIG
    if not path.is_file():
        problems.append(
            Problem(where, "a capture.toml describing cameras and bit depths", "no such file")
        )
        return None
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
        problems.append(Problem(where, "a readable TOML file", f"{type(error).__name__}: {error}"))
        return None
    before = len(problems)
    if raw.get("format", CAPTURE_FORMAT) != CAPTURE_FORMAT:
        problems.append(Problem(f"{where}: format", repr(CAPTURE_FORMAT), repr(raw.get("format"))))

    def section(name: str) -> dict[str, Any]:
        value = raw.get(name, {})
        if not isinstance(value, dict):
            problems.append(Problem(f"{where}: [{name}]", "a table", repr(value)))
            return {}
        return value

    def get(table: dict, sect: str, key: str, kind: type | tuple, default: Any = ...) -> Any:
        label = f"{where}: {sect + '.' if sect else ''}{key}"
        if key not in table:
            if default is ...:
                problems.append(Problem(label, f"a {getattr(kind, '__name__', 'value')}", "nothing"))
            return None if default is ... else default
        value = table[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or isinstance(value, bool):
            problems.append(Problem(label, f"a {getattr(kind, '__name__', kind)}", repr(value)))
            return None
        return value

    def depth(table: dict, sect: str) -> int | None:
        value = get(table, sect, "bit_depth", int)
        if value is not None and not 8 <= value <= 16:
            problems.append(Problem(f"{where}: {sect}.bit_depth", "8..16", repr(value)))
            return None
        return value

    rgb, spectral, plan, checker = (
        section("rgb"),
        section("spectral"),
        section("exposure_plan"),
        section("colour_checker"),
    )
    cameras = get(rgb, "rgb", "cameras", list)
    if cameras is not None and (not cameras or not all(isinstance(c, str) and c for c in cameras)):
        problems.append(Problem(f"{where}: rgb.cameras", "a list of camera names", repr(cameras)))
        cameras = None
    if cameras is not None and len(set(cameras)) != len(cameras):
        problems.append(Problem(f"{where}: rgb.cameras", "distinct names", repr(cameras)))
    paired = get(rgb, "rgb", "paired_camera", str)
    if paired is not None and cameras is not None and paired not in cameras:
        problems.append(Problem(f"{where}: rgb.paired_camera", f"one of {cameras}", repr(paired)))
    channels = get(rgb, "rgb", "channels", list, ["R", "G", "B"])
    spectral_camera = get(spectral, "spectral", "camera", str)
    if spectral_camera is not None and cameras is not None and spectral_camera in cameras:
        problems.append(
            Problem(
                f"{where}: spectral.camera", "a name that is not an RGB camera's", repr(spectral_camera)
            )
        )
    values = {
        "rgb_depth": depth(rgb, "rgb"),
        "spectral_depth": depth(spectral, "spectral"),
        "rotation_step": get(raw, "", "rotation_step_deg", float),
        "tolerance": get(raw, "", "angle_tolerance_deg", float, 0.5),
        "t0": get(plan, "exposure_plan", "t0", float),
        "s0": get(plan, "exposure_plan", "s0", float),
        "omega": get(plan, "exposure_plan", "omega", float),
    }
    for key in ("t0", "s0", "omega", "rotation_step"):
        if values[key] is not None and not values[key] > 0:
            problems.append(Problem(f"{where}: {key}", "a positive number", repr(values[key])))
    chart = get(checker, "colour_checker", "chart", str, None)
    patch_index = get(
        checker, "colour_checker", "patch_index", str, f"{CALIBRATION}/colour_checker_patches.png"
    )
    if len(problems) > before:
        return None
    return Config(
        name=str(raw.get("name", path.parent.name)),
        rgb_cameras=tuple(cameras),
        rgb_bit_depth=values["rgb_depth"],
        paired_camera=paired,
        channels=tuple(str(c) for c in channels),
        spectral_camera=spectral_camera,
        spectral_bit_depth=values["spectral_depth"],
        rotation_step=values["rotation_step"],
        angle_tolerance=values["tolerance"],
        t0=values["t0"],
        s0=values["s0"],
        omega=values["omega"],
        chart=chart,
        patch_index=patch_index,
        raw=raw,
    )


def _parse_manifest(path: Path, problems: list[Problem]) -> list[Row]:
    if not path.is_file():
        problems.append(Problem(MANIFEST, "one row per image file", "no such file"))
        return []
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            table = list(csv.reader(handle))
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        problems.append(Problem(MANIFEST, "a readable CSV file", f"{type(error).__name__}: {error}"))
        return []
    if not table:
        problems.append(
            Problem(MANIFEST, f"a header with {', '.join(MANIFEST_COLUMNS)}", "an empty file")
        )
        return []
    header = [h.strip() for h in table[0]]
    missing = [c for c in MANIFEST_COLUMNS if c not in header]
    if missing:
        problems.append(
            Problem(f"{MANIFEST} line 1", f"the columns {', '.join(MANIFEST_COLUMNS)}", f"no {missing}")
        )
        return []
    index = {name: header.index(name) for name in MANIFEST_COLUMNS}
    rows = []
    for line, cells in enumerate(table[1:], start=2):
        if not any(c.strip() for c in cells):
            continue
        cells = cells + [""] * (len(header) - len(cells))
        value = {name: cells[i].strip() for name, i in index.items()}
        where = f"{MANIFEST} line {line} ({value['file'] or 'no file'})"
        bad = len(problems)

        def number(name: str, kind: type = float, value=value, where=where) -> Any:
            text = value[name]
            if not text:
                return None
            try:
                number = float(text)
            except ValueError:
                problems.append(Problem(f"{where}: {name}", f"a {kind.__name__} or nothing", repr(text)))
                return None
            if not math.isfinite(number) or (kind is int and number != int(number)):
                problems.append(Problem(f"{where}: {name}", f"a finite {kind.__name__}", repr(text)))
                return None
            return int(number) if kind is int else number

        row = Row(
            line=line,
            file=value["file"],
            kind=value["kind"],
            camera=value["camera"],
            rotation=number("rotation", int),
            led=number("led", int),
            exposure_time=number("exposure_time_s"),
            wavelength=number("wavelength_nm"),
            angles=tuple(number(a) for a in ANGLES),
        )
        if not row.file:
            problems.append(Problem(where, "a file name", "an empty cell"))
        if row.kind not in KINDS:
            problems.append(Problem(f"{where}: kind", f"one of {', '.join(KINDS)}", repr(row.kind)))
        if len(problems) == bad:
            rows.append(row)
    return rows


def _check_rows(rows: list[Row], config: Config, problems: list[Problem]) -> list[Row]:
    """Per-row rules by kind and camera; rows that break one are dropped (and reported)."""
    kept = []
    for row in rows:
        bad = len(problems)
        rgb_camera = row.camera in config.rgb_cameras
        mono = row.camera == config.spectral_camera
        if not (rgb_camera or mono):
            problems.append(
                Problem(
                    f"{row.where}: camera",
                    f"an RGB camera {list(config.rgb_cameras)} or the spectral camera "
                    f"{config.spectral_camera!r} of capture.toml",
                    repr(row.camera),
                )
            )
        elif row.kind in ("rgb",) and not rgb_camera:
            problems.append(
                Problem(f"{row.where}: camera", "an RGB camera for kind rgb", repr(row.camera))
            )
        elif row.kind in ("spectral", "dark") and not mono:
            problems.append(
                Problem(
                    f"{row.where}: camera", f"the spectral camera for kind {row.kind}", repr(row.camera)
                )
            )
        elif row.kind in ("white_reference", "colour_checker", "registration") and rgb_camera:
            if row.camera != config.paired_camera:
                problems.append(
                    Problem(
                        f"{row.where}: camera",
                        f"the paired RGB camera {config.paired_camera!r} or the spectral camera",
                        repr(row.camera),
                    )
                )
        if row.exposure_time is None or not row.exposure_time > 0:
            problems.append(
                Problem(f"{row.where}: exposure_time_s", "a positive time [s]", repr(row.exposure_time))
            )
        band = mono and row.kind in ("spectral", "white_reference", "colour_checker", "registration")
        if band and row.wavelength is None:
            what = "a band shot" if row.kind == "spectral" else "a spectral calibration shot"
            problems.append(
                Problem(f"{row.where}: wavelength_nm", f"the filter's wavelength for {what}", "nothing")
            )
        elif not band and row.wavelength is not None:
            problems.append(
                Problem(
                    f"{row.where}: wavelength_nm",
                    "nothing (only band shots and spectral calibration shots have one)",
                    repr(row.wavelength),
                )
            )
        elif row.wavelength is not None and not 300 <= row.wavelength <= 1100:
            problems.append(Problem(f"{row.where}: wavelength_nm", "300..1100 nm", repr(row.wavelength)))
        if row.kind in ("rgb", "spectral", "registration") and row.rotation is None:
            problems.append(Problem(f"{row.where}: rotation", "a rotation stage position", "nothing"))
        if row.kind in ("rgb", "spectral"):
            if row.led is None:
                problems.append(Problem(f"{row.where}: led", "the index of the LED", "nothing"))
            for name, angle in zip(ANGLES, row.angles, strict=True):
                lo, hi = _ANGLE_RANGE[name]
                if angle is None or not lo <= angle <= hi:
                    problems.append(
                        Problem(
                            f"{row.where}: {name}", f"an angle in {lo:g}..{hi:g} degree", repr(angle)
                        )
                    )
        if Path(row.file).suffix.lower() not in _SUFFIXES:
            problems.append(Problem(f"{row.where}: file", "a .tif, .tiff or .png file", repr(row.file)))
        if len(problems) == bad:
            kept.append(row)
    return kept


def _frame_key(row: Row) -> tuple:
    """What a row measures: two rows with one key are duplicates (dark: every file counts)."""
    t = _key(row.exposure_time)
    wl = None if row.wavelength is None else _key(row.wavelength)
    if row.kind == "rgb":
        return (row.kind, row.camera, row.rotation, row.led, t)
    if row.kind == "spectral":
        return (row.kind, row.rotation, row.led, wl)
    if row.kind == "dark":
        return (row.kind, row.file)
    if row.kind == "registration":
        return (row.kind, row.camera, row.rotation)
    return (row.kind, row.camera, wl, t)


def _check_structure(rows: list[Row], config: Config, problems: list[Problem]) -> None:
    """Duplicates, contradictions and the shape of every exposure series."""
    seen_file: dict[str, Row] = {}
    seen_key: dict[tuple, Row] = {}
    for row in rows:
        if row.file in seen_file:
            problems.append(
                Problem(
                    row.where, "each file listed once", f"a duplicate of line {seen_file[row.file].line}"
                )
            )
            continue
        seen_file[row.file] = row
        key = _frame_key(row)
        if key in seen_key:
            problems.append(
                Problem(
                    row.where,
                    "one file per frame",
                    f"the same {row.kind} frame as line {seen_key[key].line} ({seen_key[key].file})",
                )
            )
        seen_key[key] = row
    # RGB images: one series each, equal lengths, consistent angles, at least two times
    images: dict[tuple, list[Row]] = defaultdict(list)
    for row in rows:
        if row.kind == "rgb":
            images[(row.camera, row.rotation, row.led)].append(row)
    lengths = Counter(len(series) for series in images.values())
    common = lengths.most_common(1)[0][0] if lengths else 0
    for (camera, rotation, led), series in images.items():
        label = f"RGB image camera={camera} rotation={rotation} led={led}"
        lines = ", ".join(str(r.line) for r in series)
        if len({_key(r.exposure_time) for r in series}) < 2:
            problems.append(
                Problem(
                    f"{label} ({MANIFEST} lines {lines})",
                    "an exposure series of at least two exposure times",
                    f"one time ({series[0].exposure_time:g} s)",
                )
            )
        elif len(series) != common:
            problems.append(
                Problem(
                    f"{label} ({MANIFEST} lines {lines})",
                    f"{common} exposures, like the other images",
                    f"{len(series)} exposures",
                )
            )
        first = series[0]
        for row in series[1:]:
            for name, a, b in zip(ANGLES, first.angles, row.angles, strict=True):
                if abs(a - b) > 1e-6:
                    problems.append(
                        Problem(
                            f"{row.where}: {name}",
                            f"{a:g} as on line {first.line} (the same image)",
                            f"{b:g} (contradicting rows)",
                        )
                    )
    # band shots: each pairs with an RGB image of the paired camera seen from the same angles
    paired = [(k, s[0]) for k, s in images.items() if k[0] == config.paired_camera]
    for row in rows:
        if row.kind != "spectral":
            continue
        if _pair(row, paired, config.angle_tolerance) is None:
            problems.append(
                Problem(
                    f"{row.where}",
                    f"an RGB image of the paired camera {config.paired_camera!r} with the same "
                    f"angles (within {config.angle_tolerance:g} degree)",
                    "none: " + ", ".join(f"{n}={a:g}" for n, a in zip(ANGLES, row.angles, strict=True)),
                )
            )
    # dark: equal frame counts per exposure time
    dark = Counter(_key(r.exposure_time) for r in rows if r.kind == "dark")
    if not dark:
        problems.append(Problem(MANIFEST, "dark frames (kind dark) of the spectral camera", "none"))
    elif len(set(dark.values())) > 1:
        counts = ", ".join(f"{t:g} s: {n}" for t, n in sorted(dark.items()))
        problems.append(
            Problem(f"{MANIFEST}: dark", "the same number of frames per exposure time", counts)
        )
    elif min(dark.values()) < 2:
        problems.append(Problem(f"{MANIFEST}: dark", "at least 2 frames per exposure time", "1"))
    # calibration targets: an RGB series and a band series per wavelength, one set of times
    for kind in ("white_reference", "colour_checker"):
        rgb = [r for r in rows if r.kind == kind and r.camera == config.paired_camera]
        mono = [r for r in rows if r.kind == kind and r.camera == config.spectral_camera]
        if len({_key(r.exposure_time) for r in rgb}) < 2:
            problems.append(
                Problem(
                    f"{MANIFEST}: {kind} (camera {config.paired_camera})",
                    "an exposure series of at least two exposure times",
                    f"{len(rgb)} frame(s)" if len(rgb) < 2 else "one time",
                )
            )
        times: dict[float, set[float]] = defaultdict(set)
        for r in mono:
            times[_key(r.wavelength)].add(_key(r.exposure_time))
        if not times:
            problems.append(
                Problem(
                    f"{MANIFEST}: {kind} (camera {config.spectral_camera})",
                    "band exposure series",
                    "none",
                )
            )
            continue
        reference = max(times.values(), key=len)
        for wl, ts in sorted(times.items()):
            if len(ts) < 2:
                problems.append(
                    Problem(
                        f"{MANIFEST}: {kind} at {wl:g} nm",
                        "an exposure series of at least two exposure times",
                        "one time",
                    )
                )
            elif ts != reference:
                problems.append(
                    Problem(
                        f"{MANIFEST}: {kind} at {wl:g} nm",
                        f"the exposure times of the other bands {sorted(reference)}",
                        f"{sorted(ts)}",
                    )
                )
    # registration: one rgb and one band shot per rotation, one time per camera
    reg = [r for r in rows if r.kind == "registration"]
    for camera in (config.paired_camera, config.spectral_camera):
        mine = [r for r in reg if r.camera == camera]
        if not mine:
            problems.append(
                Problem(
                    f"{MANIFEST}: registration", f"one shot per rotation of camera {camera!r}", "none"
                )
            )
            continue
        for name, values in (
            ("exposure_time_s", {_key(r.exposure_time) for r in mine}),
            (
                "wavelength_nm",
                {r.wavelength for r in mine} if camera == config.spectral_camera else {None},
            ),
        ):
            if len(values) > 1:
                problems.append(
                    Problem(
                        f"{MANIFEST}: registration, camera {camera}: {name}",
                        "one value for all rotations",
                        f"{sorted(values)} (contradicting rows)",
                    )
                )
    rotations = [
        {r.rotation for r in reg if r.camera == c}
        for c in (config.paired_camera, config.spectral_camera)
    ]
    if all(rotations) and rotations[0] != rotations[1]:
        problems.append(
            Problem(
                f"{MANIFEST}: registration",
                "RGB and spectral shots at the same rotations",
                f"{sorted(rotations[0])} and {sorted(rotations[1])}",
            )
        )
    for kind in ("rgb", "spectral"):
        if not any(r.kind == kind for r in rows):
            problems.append(Problem(MANIFEST, f"frames of kind {kind}", "none"))


def _pair(row: Row, paired: list[tuple[tuple, Row]], tolerance: float) -> tuple | None:
    def distance(a: float, b: float, periodic: bool) -> float:
        d = abs(a - b)
        return min(d, 360.0 - d) if periodic else d

    for key, image in paired:
        if all(
            distance(a, b, name.startswith("phi")) <= tolerance
            for name, a, b in zip(ANGLES, row.angles, image.angles, strict=True)
        ):
            return key
    return None


def _probe(
    path: Path, rgb: bool, bit_depth: int
) -> tuple[tuple[int, int] | None, str | None, str | None]:
    """(frame shape, what was expected, what was found) of one file; decodes the pixels."""
    if not path.is_file():
        return None, "an image file", "no such file"
    try:
        data = read_image(path)
    except Exception as error:  # any decoder error: the file is unreadable
        return None, "a readable TIFF or PNG file", f"{type(error).__name__}: {error}".strip()[:200]
    want = (3,) if rgb else ()
    if data.ndim != 2 + len(want) or data.shape[2:] != want:
        kind = "an RGB image (y, x, 3)" if rgb else "a monochrome image (y, x)"
        return None, kind, f"shape {data.shape}"
    allowed = (np.uint16, np.uint8) if bit_depth <= 8 else (np.uint16,)
    if data.dtype not in allowed:
        bits = "8- or 16-bit" if bit_depth <= 8 else "16-bit"
        return None, f"{bits} unsigned integer pixels ({bit_depth}-bit camera)", f"{data.dtype}"
    top = int(data.max()) if data.size else 0
    if top > 2**bit_depth - 1:
        return (
            None,
            f"values up to {2**bit_depth - 1} (a {bit_depth}-bit camera, right-aligned)",
            f"a value of {top}",
        )
    return (int(data.shape[0]), int(data.shape[1])), None, None


def _read_table(
    path: Path, columns: Sequence[str], problems: list[Problem], *, text: Sequence[str] = ()
) -> dict[str, list] | None:
    where = path.relative_to(path.parent.parent).as_posix()
    if not path.is_file():
        return None
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            table = [row for row in csv.reader(handle) if any(c.strip() for c in row)]
    except (OSError, UnicodeDecodeError, csv.Error) as error:
        problems.append(Problem(where, "a readable CSV file", f"{type(error).__name__}: {error}"))
        return None
    header = [h.strip() for h in table[0]] if table else []
    if not table or any(c not in header for c in columns):
        problems.append(Problem(f"{where} line 1", f"the columns {', '.join(columns)}", f"{header}"))
        return None
    out: dict[str, list] = {c: [] for c in columns}
    for line, cells in enumerate(table[1:], start=2):
        for c in columns:
            cell = cells[header.index(c)].strip() if header.index(c) < len(cells) else ""
            if c in text:
                out[c].append(cell)
                continue
            try:
                out[c].append(float(cell))
            except ValueError:
                problems.append(Problem(f"{where} line {line}: {c}", "a number", repr(cell)))
                return None
    if not table[1:]:
        problems.append(Problem(where, "at least one row", "none"))
        return None
    return out


def _on_bands(
    where: str, wavelength: np.ndarray, values: np.ndarray, bands: np.ndarray, problems: list[Problem]
) -> np.ndarray | None:
    order = np.argsort(wavelength)
    wavelength, values = wavelength[order], values[order]
    if np.unique(wavelength).size != wavelength.size:
        problems.append(Problem(where, "each wavelength once", "duplicate wavelengths"))
        return None
    outside = bands[(bands < wavelength[0] - 1e-6) | (bands > wavelength[-1] + 1e-6)]
    if outside.size:
        problems.append(
            Problem(
                where,
                f"values covering every band ({bands.min():g}..{bands.max():g} nm)",
                f"{wavelength[0]:g}..{wavelength[-1]:g} nm (missing {outside.tolist()})",
            )
        )
        return None
    return np.interp(bands, wavelength, values)


def _read_calibration(
    root: Path,
    config: Config,
    bands: np.ndarray,
    frame_shape: tuple[int, int] | None,
    problems: list[Problem],
) -> dict[str, Any]:
    folder = root / CALIBRATION
    out: dict[str, Any] = {}
    light = _read_table(folder / "illuminant.csv", ("wavelength_nm", "value"), problems)
    if light is None and not (folder / "illuminant.csv").is_file():
        problems.append(
            Problem(f"{CALIBRATION}/illuminant.csv", "the measured LED spectrum", "no such file")
        )
    white = _read_table(folder / "white_reference.csv", ("wavelength_nm", "reflectance"), problems)
    if white is None and not (folder / "white_reference.csv").is_file():
        problems.append(
            Problem(
                f"{CALIBRATION}/white_reference.csv",
                "the white target's certified reflectance",
                "no such file",
            )
        )
    for key, table, column in (("illuminant", light, "value"), ("white", white, "reflectance")):
        if table is not None:
            wl, v = np.asarray(table["wavelength_nm"]), np.asarray(table[column])
            if (v < 0).any() or (key == "white" and (v > 1).any()):
                problems.append(
                    Problem(
                        f"{CALIBRATION}/{key if key == 'illuminant' else 'white_reference'}.csv",
                        "values >= 0" + (" and <= 1" if key == "white" else ""),
                        f"{v.min():g}..{v.max():g}",
                    )
                )
            if bands.size:
                out[key] = _on_bands(f"{CALIBRATION}/{key}", wl, v, bands, problems)
    # the colour checker: a table or a chart of colour-science
    checker = folder / "colour_checker.csv"
    if checker.is_file():
        table = _read_table(
            checker, ("patch", "wavelength_nm", "reflectance"), problems, text=("patch",)
        )
        if table is not None:
            names = list(dict.fromkeys(table["patch"]))
            rows = []
            for name in names:
                pick = [i for i, p in enumerate(table["patch"]) if p == name]
                wl = np.asarray(table["wavelength_nm"])[pick]
                rf = np.asarray(table["reflectance"])[pick]
                rows.append(
                    _on_bands(
                        f"{CALIBRATION}/colour_checker.csv patch {name!r}", wl, rf, bands, problems
                    )
                )
            if all(r is not None for r in rows) and bands.size:
                out["patches"] = (names, np.stack(rows), config.chart or "colour_checker.csv")
    elif config.chart:
        import colour

        charts = colour.SDS_COLOURCHECKERS
        if config.chart not in charts:
            problems.append(
                Problem(
                    f"{CONFIG}: colour_checker.chart", f"one of {sorted(charts)}", repr(config.chart)
                )
            )
        elif bands.size:
            sds = charts[config.chart]
            names = list(sds)
            rows = [np.interp(bands, sds[n].wavelengths, sds[n].values) for n in names]
            out["patches"] = (names, np.clip(np.stack(rows), 0, 1), config.chart)
    else:
        problems.append(
            Problem(
                f"{CALIBRATION}/colour_checker.csv",
                "the patches' reflectance, or colour_checker.chart in capture.toml",
                "neither",
            )
        )
    labels = root / config.patch_index
    if not labels.is_file():
        problems.append(
            Problem(config.patch_index, "the colour checker's patch label image", "no such file")
        )
    else:
        try:
            index = read_image(labels)
        except Exception as error:
            problems.append(
                Problem(
                    config.patch_index, "a readable TIFF or PNG file", f"{type(error).__name__}: {error}"
                )
            )
        else:
            n_patches = len(out["patches"][0]) if "patches" in out else None
            if index.ndim != 2 or (frame_shape is not None and index.shape != frame_shape):
                problems.append(
                    Problem(
                        config.patch_index,
                        f"a monochrome image of the frames' shape {frame_shape}",
                        f"shape {index.shape}",
                    )
                )
            elif n_patches is not None and int(index.max()) > n_patches:
                problems.append(
                    Problem(
                        config.patch_index,
                        f"labels 0 (frame) .. {n_patches} (patches)",
                        f"a label {int(index.max())}",
                    )
                )
            else:
                out["patch_index"] = index.astype(np.int16) - 1
    plan = folder / "exposure_plan.csv"
    if plan.is_file():
        table = _read_table(plan, ("wavelength_nm", "exposure_time_s", "filter_size_px"), problems)
        if table is not None:
            out["plan"] = tuple(
                np.asarray(table[c]) for c in ("wavelength_nm", "exposure_time_s", "filter_size_px")
            )
    return out


def read_capture(
    path: str | os.PathLike[str],
    *,
    known: dict[str, tuple[int, int]] | None = None,
    known_shape: tuple[int, int] | None = None,
    progress: Callable[[str], None] | None = None,
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

    Raises
    ------
    CaptureError
        Listing every problem: a missing or unreadable file, a wrong bit depth or shape,
        duplicate or contradicting rows, an unknown kind, an exposure series with one time,
        a band shot without a wavelength, calibration tables that do not cover the bands.
    """
    root = Path(path)
    say = progress or (lambda message: None)
    if not root.is_dir():
        raise CaptureError.single(str(root), "a capture folder", "no such folder")
    problems: list[Problem] = []
    config = _parse_config(root / CONFIG, problems)
    rows = _parse_manifest(root / MANIFEST, problems)
    if config is None:
        raise CaptureError(f"cannot ingest {root}:", problems)
    rows = _check_rows(rows, config, problems)
    _check_structure(rows, config, problems)
    # decode every file not ingested before (thread pool: decoders release the GIL)
    known = known or {}
    todo = []
    for row in rows:
        file = root / row.file
        try:
            st = file.stat()
            if known.get(row.file) == (int(st.st_size), int(st.st_mtime_ns)):
                continue
        except OSError:
            pass
        rgb = row.camera in config.rgb_cameras
        todo.append((row, file, rgb, config.rgb_bit_depth if rgb else config.spectral_bit_depth))
    say(f"checking {len(todo)} new or changed file(s) of {len(rows)}")
    shapes: Counter[tuple[int, int]] = Counter()
    probed = []
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        results = pool.map(lambda item: _probe(*item[1:]), todo)
        for (row, *_), (shape, expected, found) in zip(todo, results, strict=True):
            if expected is not None:
                problems.append(Problem(row.where, expected, found))
            else:
                shapes[shape] += 1
                probed.append((row, shape))
    say(f"checked {len(todo)} file(s)")
    frame_shape = shapes.most_common(1)[0][0] if shapes else None
    frame_shape = tuple(known_shape) if known_shape is not None else frame_shape
    for row, shape in probed:
        if shape != frame_shape:
            problems.append(
                Problem(
                    row.where,
                    f"frames of {frame_shape[0]} x {frame_shape[1]} px like the others",
                    f"{shape[0]} x {shape[1]} px",
                )
            )
    bands = np.unique(
        [_key(r.wavelength) for r in rows if r.kind in ("white_reference",) and r.wavelength is not None]
    )
    calibration = _read_calibration(root, config, np.asarray(bands, dtype=float), frame_shape, problems)
    band_shots = {_key(r.wavelength) for r in rows if r.kind == "spectral"}
    missing = sorted(band_shots - set(bands.tolist()))
    if missing and bands.size:
        problems.append(
            Problem(
                f"{MANIFEST}: white_reference",
                "a calibration series at every wavelength of the band shots",
                f"none at {missing} nm",
            )
        )
    checker_bands = sorted(
        {_key(r.wavelength) for r in rows if r.kind == "colour_checker" and r.wavelength}
    )
    if bands.size and checker_bands and checker_bands != bands.tolist():
        problems.append(
            Problem(
                f"{MANIFEST}: colour_checker",
                f"the white reference's bands {bands.tolist()}",
                f"{checker_bands}",
            )
        )
    if problems:
        raise CaptureError(
            f"cannot ingest {root}: {len(problems)} problem(s), nothing was written", problems
        )
    return Capture(
        path=root,
        config=config,
        rows=rows,
        frame_shape=frame_shape,
        bands=np.asarray(bands, dtype=float),
        illuminant=calibration["illuminant"],
        white_reflectance=calibration["white"],
        patches=calibration["patches"],
        patch_index=calibration["patch_index"],
        plan_table=calibration.get("plan"),
    )


# -- the raw groups -----------------------------------------------------------------------
@dataclass
class _Group:
    name: str
    dataset: xr.Dataset
    files: dict[str, list[list[Any]]]  # variable -> [file, size, mtime_ns] per frame, C order
    resumable: str | None = None
    fingerprint: str = ""


def _load(source: tuple, frame: tuple[int, ...]) -> np.ndarray:
    """One frame, from its file or (already ingested) from the store; shape ``(1,)*k + frame``."""
    if source[0] == "file":
        data = read_image(source[1])
    else:
        _, store, array, index = source
        data = np.asarray(zarr.open_array(store, path=array, mode="r")[index])
    if data.shape != frame:
        raise CaptureError.single(str(source[1]), f"a frame of shape {frame}", f"shape {data.shape}")
    return data.astype(np.uint16, copy=False)


class _Sources:
    """Where each frame comes from: the store's previous version of the group, or its file."""

    def __init__(self, capture: Capture, store: RunStore, group: str):
        self.capture = capture
        self.read = 0
        self.copied = 0
        self.previous: dict[str, dict[tuple, tuple]] = {}
        if store.has(group):
            attrs = store.group_attrs(group)
            for var, files in (attrs.get(_FILES_ATTR) or {}).items():
                meta = json.loads((store.path / group / var / "zarr.json").read_text())
                frame = 3 if group == "raw/rgb" or var == "rgb_counts" else 2  # (y, x[, channel])
                grid = tuple(meta["shape"][: len(meta["shape"]) - frame])
                self.previous[var] = {
                    tuple(entry): (str(store.path), f"{group}/{var}", np.unravel_index(k, grid))
                    for k, entry in enumerate(files)
                }

    def frames(self, var: str, rows: list[Row], frame: tuple[int, ...]) -> tuple[list[da.Array], list]:
        arrays, files = [], []
        for row in rows:
            stat = self.capture.stat(row)
            old = self.previous.get(var, {}).get(tuple(stat))
            if old is not None:
                source = ("store", old[0], old[1], tuple(int(i) for i in old[2]))
                self.copied += 1
            else:
                source = ("file", str(self.capture.path / row.file))
                self.read += 1
            arrays.append(da.from_delayed(dask.delayed(_load)(source, frame), frame, dtype=np.uint16))
            files.append(stat)
        return arrays, files


#: Target size of one dask chunk (and one resumable region): memory is bounded by a few.
CHUNK_BYTES = 64 * 2**20


def _grid(arrays: list[da.Array], shape: tuple[int, ...]) -> da.Array:
    """Frames (C order) stacked onto a grid of ``shape``, chunked to about :data:`CHUNK_BYTES`.

    The last grid dims are filled first: e.g. an RGB image's exposure series is one chunk
    (when it fits), and as many images as fit share it.
    """
    stacked = _stack(arrays, shape)
    budget = max(1, CHUNK_BYTES // max(1, int(np.prod(stacked.shape[len(shape) :])) * 2))
    chunks = {}
    for axis in reversed(range(len(shape))):
        chunks[axis] = int(min(shape[axis], max(1, budget)))
        budget //= max(1, shape[axis])
    return stacked.rechunk(chunks)


def _stack(arrays: list[da.Array], shape: tuple[int, ...]) -> da.Array:
    if len(shape) == 1:
        return da.stack(arrays)
    step = int(np.prod(shape[1:]))
    return da.stack([_stack(arrays[i * step : (i + 1) * step], shape[1:]) for i in range(shape[0])])


def _attrs_counts(bits: int, long_name: str) -> dict[str, Any]:
    return {"units": "DN", "long_name": long_name, "bit_depth": int(bits)}


def _source_attrs(capture: Capture, title: str) -> dict[str, Any]:
    return {
        "title": title,
        "source": f"capture folder {capture.path.name!r} ({capture.config.name}), "
        "ingested by spectralize.flows.ingest",
        "capture_folder": str(capture.path.absolute()),
    }


def _rgb_group(capture: Capture, sources: _Sources) -> _Group:
    config = capture.config
    y, x = capture.frame_shape
    series: dict[tuple, list[Row]] = defaultdict(list)
    for row in capture.of("rgb"):
        series[(row.rotation, row.led, config.rgb_cameras.index(row.camera))].append(row)
    keys = sorted(series)
    ordered = [sorted(series[k], key=lambda r: r.exposure_time) for k in keys]
    n_img, n_exp = len(keys), len(ordered[0])
    arrays, files = sources.frames(
        "counts", [r for s in ordered for r in s], (y, x, len(config.channels))
    )
    counts = _grid(arrays, (n_img, n_exp))
    first = [s[0] for s in ordered]
    coords: dict[str, Any] = {
        "image": ("image", np.arange(n_img), {"units": "1", "long_name": "image label"}),
        "channel": ("channel", np.asarray(config.channels), {"long_name": "channel"}),
        "exposure_time": (
            ("image", "exposure"),
            np.array([[r.exposure_time for r in s] for s in ordered]),
            {"units": "s", "long_name": "exposure time"},
        ),
        "camera": (
            "image",
            np.array([k[2] for k in keys], np.int64),
            {"units": "1", "long_name": "RGB camera index (capture.toml rgb.cameras)"},
        ),
        "rotation": (
            "image",
            np.array([k[0] for k in keys], np.int64),
            {"units": "1", "long_name": "rotation stage position"},
        ),
        "led": (
            "image",
            np.array([k[1] for k in keys], np.int64),
            {"units": "1", "long_name": "index of the LED"},
        ),
    }
    for i, name in enumerate(ANGLES):
        coords[name] = (
            "image",
            np.array([r.angles[i] for r in first]),
            {"units": "degree", "long_name": _ANGLE_NAMES[name]},
        )
    ds = xr.Dataset(
        {
            "counts": (
                ("image", "exposure", "y", "x", "channel"),
                counts,
                _attrs_counts(config.rgb_bit_depth, "raw RGB counts"),
            )
        },
        coords=coords,
        attrs=_source_attrs(capture, "LDR exposure series of the RGB cameras")
        | {"bit_depth": config.rgb_bit_depth, "camera": "rgb", "camera_names": list(config.rgb_cameras)},
    )
    return _Group("raw/rgb", ds, {"counts": files}, resumable="image")


_ANGLE_NAMES = {
    "theta_i": "polar angle of the light direction (sample frame)",
    "phi_i": "azimuth of the light direction (sample frame)",
    "theta_o": "polar angle of the view direction (sample frame)",
    "phi_o": "azimuth of the view direction (sample frame)",
}


def _filter_sizes(capture: Capture, wavelength: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Filter size per band: ``exposure_plan.csv``, else eq. 2 and 3 solved for ``s_i(t_i)``.

    With ``t_i = (t0 / (Q_i L_i))**omega`` and ``s_i = s0 / (Q_i L_i t_i)``:
    ``s_i = (s0 / t0) * t_i**(1 / omega - 1)``.
    """
    c = capture.config
    sizes = (c.s0 / c.t0) * np.asarray(times, dtype=float) ** (1.0 / c.omega - 1.0)
    if capture.plan_table is not None:
        table = {_key(w): s for w, s in zip(capture.plan_table[0], capture.plan_table[2], strict=True)}
        sizes = np.array([table.get(_key(w), s) for w, s in zip(wavelength, sizes, strict=True)])
    return sizes


def _spectral_group(capture: Capture, sources: _Sources, image_of: dict[tuple, int]) -> _Group:
    config = capture.config
    y, x = capture.frame_shape
    rows = sorted(capture.of("spectral"), key=lambda r: (r.rotation, r.led, r.wavelength))
    arrays, files = sources.frames("counts", rows, (y, x))
    paired = [
        ((config.paired_camera, r.rotation, r.led), r)
        for r in capture.of("rgb")
        if r.camera == config.paired_camera
    ]
    pairs = [_pair(r, paired, config.angle_tolerance) for r in rows]
    wavelength = np.array([r.wavelength for r in rows])
    times = np.array([r.exposure_time for r in rows])
    coords: dict[str, Any] = {
        "shot": ("shot", np.arange(len(rows)), {"units": "1", "long_name": "shot index"}),
        "wavelength": (
            "shot",
            wavelength,
            {"units": "nm", "long_name": "centre wavelength of the filter band"},
        ),
        "exposure_time": ("shot", times, {"units": "s", "long_name": "exposure time"}),
        "image": (
            "shot",
            np.array([image_of[(p[1], p[2], config.rgb_cameras.index(p[0]))] for p in pairs], np.int64),
            {"units": "1", "long_name": "label of the raw/rgb image this shot pairs with (same angles)"},
        ),
        "rotation": (
            "shot",
            np.array([r.rotation for r in rows], np.int64),
            {"units": "1", "long_name": "rotation stage position"},
        ),
        "led": (
            "shot",
            np.array([r.led for r in rows], np.int64),
            {"units": "1", "long_name": "index of the LED"},
        ),
        "filter_size": (
            "shot",
            _filter_sizes(capture, wavelength, times),
            {"units": "px", "long_name": "Gaussian filter size s_i (eq. 3)"},
        ),
    }
    for i, name in enumerate(ANGLES):
        coords[name] = (
            "shot",
            np.array([r.angles[i] for r in rows]),
            {"units": "degree", "long_name": _ANGLE_NAMES[name]},
        )
    ds = xr.Dataset(
        {
            "counts": (
                ("shot", "y", "x"),
                _grid(arrays, (len(rows),)),
                _attrs_counts(config.spectral_bit_depth, "raw band counts"),
            )
        },
        coords=coords,
        attrs=_source_attrs(capture, "band-filtered frames of the spectral camera")
        | {"bit_depth": config.spectral_bit_depth, "camera": config.spectral_camera},
    )
    return _Group("raw/spectral", ds, {"counts": files}, resumable="shot")


def _dark_group(capture: Capture, sources: _Sources) -> _Group:
    config = capture.config
    y, x = capture.frame_shape
    by_time: dict[float, list[Row]] = defaultdict(list)
    for row in capture.of("dark"):
        by_time[_key(row.exposure_time)].append(row)
    times = sorted(by_time)
    ordered = [sorted(by_time[t], key=lambda r: r.file) for t in times]
    arrays, files = sources.frames("frames", [r for s in ordered for r in s], (y, x))
    frames = _grid(arrays, (len(times), len(ordered[0])))
    ds = xr.Dataset(
        {
            "frames": (
                ("exposure_time", "frame", "y", "x"),
                frames,
                _attrs_counts(
                    config.spectral_bit_depth, "raw dark frames of the spectral camera (closed shutter)"
                ),
            )
        },
        coords={
            "exposure_time": (
                "exposure_time",
                np.array([s[0].exposure_time for s in ordered]),
                {"units": "s", "long_name": "exposure time"},
            )
        },
        attrs=_source_attrs(capture, "dark frames of the spectral camera")
        | {"camera": config.spectral_camera, "bit_depth": config.spectral_bit_depth},
    )
    return _Group("raw/dark", ds, {"frames": files}, resumable="exposure_time")


def _target_group(capture: Capture, sources: _Sources, kind: str) -> _Group:
    config = capture.config
    y, x = capture.frame_shape
    rgb_rows = sorted(capture.of(kind, config.paired_camera), key=lambda r: r.exposure_time)
    band_rows = capture.of(kind, config.spectral_camera)
    times = sorted({_key(r.exposure_time) for r in band_rows})
    grid = {(_key(r.wavelength), _key(r.exposure_time)): r for r in band_rows}
    ordered = [grid[(_key(w), t)] for w in capture.bands for t in times]
    rgb_arrays, rgb_files = sources.frames("rgb_counts", rgb_rows, (y, x, len(config.channels)))
    band_arrays, band_files = sources.frames("spectral_counts", ordered, (y, x))
    ds = xr.Dataset(
        {
            "rgb_counts": (
                ("rgb_exposure", "y", "x", "channel"),
                _grid(rgb_arrays, (len(rgb_rows),)),
                _attrs_counts(
                    config.rgb_bit_depth,
                    f"raw RGB counts of the paired RGB camera {config.paired_camera}",
                ),
            ),
            "spectral_counts": (
                ("wavelength", "spectral_exposure", "y", "x"),
                _grid(band_arrays, (capture.bands.size, len(times))),
                _attrs_counts(config.spectral_bit_depth, "raw band counts of the spectral camera"),
            ),
            "illuminant": (
                "wavelength",
                capture.illuminant,
                {
                    "units": "1",
                    "long_name": "measured relative spectral radiance of the LEDs (illuminant.csv)",
                },
            ),
        },
        coords={
            "wavelength": (
                "wavelength",
                capture.bands,
                {"units": "nm", "long_name": "centre wavelength of the filter band"},
            ),
            "channel": ("channel", np.asarray(config.channels), {"long_name": "channel"}),
            "rgb_exposure_time": (
                "rgb_exposure",
                np.array([r.exposure_time for r in rgb_rows]),
                {"units": "s", "long_name": "exposure time of the RGB series"},
            ),
            "spectral_exposure_time": (
                "spectral_exposure",
                np.array([grid[(_key(capture.bands[0]), t)].exposure_time for t in times]),
                {"units": "s", "long_name": "exposure time of the band series"},
            ),
        },
        attrs=_source_attrs(capture, f"{kind.replace('_', ' ')} under the LEDs")
        | {
            "rgb_bit_depth": config.rgb_bit_depth,
            "spectral_bit_depth": config.spectral_bit_depth,
            "rgb_camera": config.rgb_cameras.index(config.paired_camera),
        },
    )
    if kind == "white_reference":
        ds["target_reflectance"] = (
            "wavelength",
            np.clip(capture.white_reflectance, 0.0, 1.0),
            {
                "units": "1",
                "long_name": "certified reflectance of the white target (white_reference.csv)",
            },
        )
    else:
        names, reflectance, chart = capture.patches
        ds["patch_reflectance"] = (
            ("patch", "wavelength"),
            np.clip(reflectance, 0.0, 1.0),
            {"units": "1", "long_name": "published reflectance of the chart patches"},
        )
        ds = ds.assign_coords(
            patch=("patch", np.arange(len(names)), {"units": "1", "long_name": "patch index"}),
            patch_name=("patch", np.asarray(names)),
        )
        ds["patch_index"] = (
            ("y", "x"),
            capture.patch_index,
            {"units": "1", "long_name": "patch under each RGB pixel (-1: frame)"},
        )
        ds.attrs["chart"] = chart
    return _Group(f"raw/{kind}", ds, {"rgb_counts": rgb_files, "spectral_counts": band_files})


def _registration_group(capture: Capture, sources: _Sources) -> _Group:
    config = capture.config
    y, x = capture.frame_shape
    rgb_rows = sorted(capture.of("registration", config.paired_camera), key=lambda r: r.rotation)
    mono_rows = sorted(capture.of("registration", config.spectral_camera), key=lambda r: r.rotation)
    rgb_arrays, rgb_files = sources.frames("rgb_counts", rgb_rows, (y, x, len(config.channels)))
    mono_arrays, mono_files = sources.frames("spectral_counts", mono_rows, (y, x))
    rotation = np.array([r.rotation for r in rgb_rows], np.int64)
    ds = xr.Dataset(
        {
            "rgb_counts": (
                ("rotation", "y", "x", "channel"),
                _grid(rgb_arrays, (len(rgb_rows),)),
                _attrs_counts(config.rgb_bit_depth, f"RGB camera {config.paired_camera}"),
            ),
            "spectral_counts": (
                ("rotation", "y", "x"),
                _grid(mono_arrays, (len(mono_rows),)),
                _attrs_counts(config.spectral_bit_depth, "spectral camera"),
            ),
        },
        coords={
            "rotation": ("rotation", rotation, {"units": "1", "long_name": "rotation stage position"}),
            "rotation_angle": (
                "rotation",
                (rotation * config.rotation_step) % 360.0,
                {"units": "degree", "long_name": "rotation of the sample"},
            ),
            "channel": ("channel", np.asarray(config.channels), {"long_name": "channel"}),
            "rgb_exposure_time": (
                (),
                float(rgb_rows[0].exposure_time),
                {"units": "s", "long_name": "exposure time of the RGB shots"},
            ),
            "spectral_exposure_time": (
                (),
                float(mono_rows[0].exposure_time),
                {"units": "s", "long_name": "exposure time of the spectral shots"},
            ),
            "spectral_wavelength": (
                (),
                float(mono_rows[0].wavelength),
                {"units": "nm", "long_name": "filter band of the spectral shots"},
            ),
        },
        attrs=_source_attrs(capture, "long-exposure registration shots per rotation")
        | {
            "rgb_camera": config.rgb_cameras.index(config.paired_camera),
            "rgb_bit_depth": config.rgb_bit_depth,
            "spectral_bit_depth": config.spectral_bit_depth,
        },
    )
    return _Group("raw/registration", ds, {"rgb_counts": rgb_files, "spectral_counts": mono_files})


def _plan_group(capture: Capture, rgb: xr.Dataset, spectral: xr.Dataset) -> _Group:
    c = capture.config
    if capture.plan_table is not None:
        wavelength, times, sizes = (np.asarray(v, dtype=float) for v in capture.plan_table)
        order = np.argsort(wavelength)
        wavelength, times, sizes = wavelength[order], times[order], sizes[order]
    else:
        shots = spectral[["exposure_time"]].to_dataframe().groupby(spectral["wavelength"].values).first()
        wavelength = np.asarray(shots.index, dtype=float)
        times = np.asarray(shots["exposure_time"], dtype=float)
        sizes = _filter_sizes(capture, wavelength, times)
    ds = xr.Dataset(
        {
            "exposure_time": ("wavelength", times, {"units": "s", "long_name": "exposure time (eq. 2)"}),
            "filter_size": (
                "wavelength",
                sizes,
                {"units": "px", "long_name": "filter size s_i (eq. 3)"},
            ),
            "filter_sigma": ("wavelength", sizes / 5.0, {"units": "px", "long_name": "s_i / 5"}),
            "spectral_capture_time": (
                (),
                float(spectral["exposure_time"].sum()),
                {"units": "s", "long_name": "total spectral exposure"},
            ),
            "rgb_capture_time": (
                (),
                float(rgb["exposure_time"].sum()),
                {"units": "s", "long_name": "total RGB exposure"},
            ),
        },
        coords={
            "wavelength": (
                "wavelength",
                wavelength,
                {"units": "nm", "long_name": "centre wavelength of the filter band"},
            )
        },
        attrs=_source_attrs(capture, "the exposure plan (eq. 2, 3) the band shots followed")
        | {
            "t0": c.t0,
            "s0": c.s0,
            "omega": c.omega,
            "filter_sizes_from": "calibration/exposure_plan.csv"
            if capture.plan_table is not None
            else "eq. 2 and 3 with t0, s0, omega of capture.toml",
        },
    )
    return _Group("raw/exposure_plan", ds, {})


def _fingerprint(group: _Group) -> str:
    """Of the group's description: coords, small variables, attrs and its files' versions."""
    ds = group.dataset
    payload = {
        "ingest": INGEST_VERSION,
        "group": group.name,
        "attrs": {k: v for k, v in ds.attrs.items() if k != "capture_folder"},
        "coords": {k: np.asarray(v.values).tolist() for k, v in ds.coords.items()},
        "small": {k: np.asarray(v.values).tolist() for k, v in ds.data_vars.items() if v.chunks is None},
        "files": group.files,
    }
    text = json.dumps(payload, sort_keys=True, default=str)
    return "ingest:" + hashlib.sha256(text.encode()).hexdigest()


# -- ingesting ----------------------------------------------------------------------------
RAW_GROUPS: tuple[str, ...] = (
    "raw/rgb",
    "raw/spectral",
    "raw/dark",
    "raw/white_reference",
    "raw/colour_checker",
    "raw/registration",
    "raw/exposure_plan",
)


@dataclass
class IngestReport:
    """What :func:`ingest` did: per group ``"written"`` or ``"up to date"``, frames read."""

    capture: Path
    store: Path
    groups: dict[str, str] = field(default_factory=dict)
    frames_read: int = 0
    frames_copied: int = 0
    seconds: float = 0.0

    @property
    def changed(self) -> bool:
        return any(status == "written" for status in self.groups.values())


def _known_files(store: RunStore) -> tuple[dict[str, tuple[int, int]], tuple[int, int] | None]:
    known: dict[str, tuple[int, int]] = {}
    shape = None
    for group in RAW_GROUPS:
        if not store.has(group):
            continue
        attrs = store.group_attrs(group)
        for files in (attrs.get(_FILES_ATTR) or {}).values():
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
    start = time.perf_counter()
    say = progress or (lambda message: None)
    capture_dir, store_path = Path(capture_dir), Path(store_path)
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
    capture_dir = capture.path
    groups: list[_Group] = []
    for name in RAW_GROUPS:
        sources = _Sources(capture, store, name)
        if name == "raw/rgb":
            group = _rgb_group(capture, sources)
            rgb = group.dataset
            image_of = {
                (int(r), int(led), int(cam)): int(i)
                for i, r, led, cam in zip(
                    rgb["image"].values,
                    rgb["rotation"].values,
                    rgb["led"].values,
                    rgb["camera"].values,
                    strict=True,
                )
            }
        elif name == "raw/spectral":
            group = _spectral_group(capture, sources, image_of)
            spectral = group.dataset
        elif name == "raw/dark":
            group = _dark_group(capture, sources)
        elif name in ("raw/white_reference", "raw/colour_checker"):
            group = _target_group(capture, sources, name.split("/")[1])
        elif name == "raw/registration":
            group = _registration_group(capture, sources)
        else:
            group = _plan_group(capture, rgb, spectral)
        group.fingerprint = _fingerprint(group)
        group.dataset.attrs[_FILES_ATTR] = group.files
        groups.append((group, sources))
    for group, sources in groups:
        if store.fingerprint(group.name) == group.fingerprint:
            report.groups[group.name] = "up to date"
            say(f"{group.name}: up to date")
            continue
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
            progress=_Eta(say, group.name, regions) if dim else None,
        )
        report.groups[group.name] = "written"
        report.frames_read += sources.read
        report.frames_copied += sources.copied


# -- is a capture folder complete? (nightly runs) -----------------------------------------
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
    missing = [f for f in files if f and not (root / f).is_file()]
    if missing:
        return CaptureState(
            root,
            False,
            f"{len(missing)} of {len(files)} file(s) listed in {MANIFEST} not present yet "
            f"(e.g. {missing[0]})",
        )
    newest = max(
        (
            p.stat().st_mtime
            for p in [manifest, root / CONFIG, *(root / f for f in files if f)]
            if p.exists()
        ),
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
