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
from pathlib import Path
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
        """The rows of one kind (and camera), in manifest order."""
        return [r for r in self.rows if r.kind == kind and (camera is None or r.camera == camera)]

    def file(self, row: Row) -> Path:
        """The image file of a row."""
        return capture_file(self.path, row.file)

    def stat(self, row: Row) -> list[Any]:
        """``[file, size, mtime_ns]``: what identifies the version of a frame's file."""
        st = self.file(row).stat()
        return [row.file, int(st.st_size), int(st.st_mtime_ns)]


def capture_file(root: Path, name: str) -> Path:
    """The path of a file a capture folder names (manifest ``file``, ``patch_index``).

    Every file a manifest or ``capture.toml`` names is resolved here, relative to the folder.
    """
    return root / name


def rounded(value: float) -> float:
    """Exposure times and wavelengths compared after rounding (CSV round trips)."""
    return float(f"{value:.9g}")
