"""The data model of a capture folder: its file names, manifest rows and ``capture.toml``.

A capture folder is what a gantry's control software writes for ``spectralize ingest``: image
files, ``manifest.csv`` (one :class:`Row` per file), ``capture.toml`` (:class:`Config`) and
the ``calibration/`` tables. :class:`Capture` is a folder that passed every check. The whole
format is described in ``datasets/README.md``, "Capture folders".

Units: nm, s, degree; the illuminant and reflectances are relative (``units = "1"``).

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the gantry and its two kinds of camera).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import Any

import numpy as np

from spectralize.schemas import SpectralizeError

__all__ = [
    "MANIFEST",
    "CONFIG",
    "CALIBRATION",
    "CAPTURE_FORMAT",
    "MANIFEST_COLUMNS",
    "KINDS",
    "ANGLES",
    "ANGLE_RANGE",
    "CaptureError",
    "Row",
    "Config",
    "Capture",
    "capture_file",
    "contained_path",
    "rounded",
]

MANIFEST = "manifest.csv"
CONFIG = "capture.toml"
CALIBRATION = "calibration"
CAPTURE_FORMAT = "spectralize-capture"
"""The value of ``format`` in ``capture.toml`` (optional there)."""

MANIFEST_COLUMNS: tuple[str, ...] = (
    "file",
    "kind",
    "camera",
    "rotation",
    "led",
    "exposure_time_s",
    "wavelength_nm",
    "theta_i",
    "phi_i",
    "theta_o",
    "phi_o",
)
"""The columns of ``manifest.csv``, one row per image file (more columns are ignored)."""

KINDS: tuple[str, ...] = ("rgb", "spectral", "dark", "white_reference", "colour_checker", "registration")
"""The values of the ``kind`` column."""

ANGLES: tuple[str, ...] = ("theta_i", "phi_i", "theta_o", "phi_o")
"""Light and view direction in the sample frame [degree], in :attr:`Row.angles` order."""

ANGLE_RANGE: dict[str, tuple[float, float]] = {
    "theta_i": (0.0, 90.0),
    "theta_o": (0.0, 90.0),
    "phi_i": (0.0, 360.0),
    "phi_o": (0.0, 360.0),
}
"""The range of each angle [degree]: theta from the normal, phi round it."""


class CaptureError(SpectralizeError, ValueError):
    """A capture folder that cannot be ingested; its problems name file and manifest line."""


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
    follow_symlinks: bool = False  # follow symbolic links whose target is inside the folder
    rgb_models: dict[str, str] = field(default_factory=dict)  # camera -> sensor model (rgb.models)
    black_level_dn: dict[str, int] = field(default_factory=dict)  # camera -> black level [DN]
    white_level_dn: dict[str, int] = field(default_factory=dict)  # camera -> white level [DN]
    patch_indices: dict[str, str] = field(default_factory=dict)  # camera -> patch label image
    shared_patch_index: bool = False  # cameras without their own label image use patch_index
    raw: dict[str, Any] = field(default_factory=dict, compare=False)

    def patch_index_of(self, camera: str) -> str:
        """The patch label image of an RGB camera's chart frames (capture folder path).

        ``colour_checker.patch_indices`` names it per camera; the paired camera's default is
        ``colour_checker.patch_index``; another camera's is
        ``calibration/colour_checker_patches_<camera>.png``, or ``patch_index`` when
        ``colour_checker.shared_patch_index = true`` (frames of one view).
        """
        if camera in self.patch_indices:
            return self.patch_indices[camera]
        if camera == self.paired_camera or self.shared_patch_index:
            return self.patch_index
        return f"{CALIBRATION}/colour_checker_patches_{camera}.png"

    def model_of(self, camera: str) -> str | None:
        """The sensor model ``rgb.models`` gives an RGB camera (``None``: not said)."""
        return self.rgb_models.get(camera)


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
    rgb_patch_index: dict[str, np.ndarray] = field(default_factory=dict)  # camera -> (y, x) labels
    led_power: dict[int, float] | None = None  # calibration/led_power.csv: LED -> relative power

    def of(self, kind: str, camera: str | None = None) -> list[Row]:
        """The rows of one kind (and camera), in manifest order."""
        return [r for r in self.rows if r.kind == kind and (camera is None or r.camera == camera)]

    def file(self, row: Row) -> Path:
        """The image file of a row (inside the folder: :func:`capture_file`)."""
        return capture_file(self.path, row.file, follow_symlinks=self.config.follow_symlinks)

    def stat(self, row: Row) -> list[Any]:
        """``[file, size, mtime_ns]``: what identifies the version of a frame's file."""
        st = self.file(row).stat()
        return [row.file, int(st.st_size), int(st.st_mtime_ns)]


def capture_file(root: Path, name: str, *, follow_symlinks: bool = False) -> Path:
    """The path of a file a capture folder names (manifest ``file``, ``patch_index``, tables).

    Every file a manifest or ``capture.toml`` names becomes a path here, and only if it stays
    inside the folder: ingest reads nothing else (a nightly ``serve`` ingests whatever lands
    under its root). Refused: an absolute path, a path that leaves the folder (``..``), a NUL
    character, and a symbolic link (a file or a folder on the way) unless ``capture.toml``
    says ``follow_symlinks = true`` *and* the link's target is inside the folder.

    Raises
    ------
    CaptureError
        With one problem naming ``name`` and why it was refused (:func:`contained_path`).
    """
    path, why = contained_path(root, name, follow_symlinks=follow_symlinks)
    if path is None:
        raise CaptureError.single(name, "a path inside the capture folder", why)
    return path


def contained_path(root: Path, name: str, *, follow_symlinks: bool = False) -> tuple[Path | None, str]:
    """``(path, "")`` for a name that stays inside the capture folder ``root``, else ``(None, why)``.

    The name is taken as a relative POSIX path. Without ``follow_symlinks`` no part of it may
    be a symbolic link (checked with ``lstat``, so what is checked is what is opened); with it,
    the fully resolved path must lie inside the resolved folder.
    """
    if "\x00" in name:
        return None, "a name with a NUL character"
    if not name or name.startswith(("/", "\\")) or PureWindowsPath(name).drive:
        return None, f"an absolute path {name!r}" if name else "an empty name"
    parts = PurePosixPath(name).parts
    if ".." in parts:
        return None, f"a path that leaves the capture folder ({name!r} has '..')"
    path = root.joinpath(*parts)
    if follow_symlinks:
        try:
            target, base = path.resolve(), root.resolve()
        except (OSError, RuntimeError) as error:  # a symlink loop
            return None, f"a path that cannot be resolved ({type(error).__name__}: {error})"
        if not target.is_relative_to(base):
            return None, f"a symbolic link to {str(target)!r}, outside the capture folder"
        return path, ""
    here = root
    for part in parts:
        here = here / part
        if here.is_symlink():
            link = (
                "a symbolic link" if here == path else f"in a symbolically linked folder {here.name!r}"
            )
            return None, f"{link} (not followed: capture.toml has no follow_symlinks = true)"
    return path, ""


def rounded(value: float) -> float:
    """Exposure times and wavelengths compared after rounding (CSV round trips)."""
    return float(f"{value:.9g}")
