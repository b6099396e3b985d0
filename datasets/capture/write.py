"""Writers of the capture-folder format: image files, ``manifest.csv``, ``capture.toml``, tables.

The inverse of the parsers (:mod:`.images`, :mod:`.manifest`, :mod:`.config`,
:mod:`.calibration`), used by the simulator's sample (:mod:`.sample`) and by tests that build
or alter a capture folder. Output is deterministic: the same values give the same bytes.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (what a gantry run leaves on disk).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import png
import tifffile

from .model import MANIFEST_COLUMNS

__all__ = ["write_png", "write_tiff", "write_manifest", "write_table", "write_config"]


def write_png(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a 16-bit PNG: (y, x) greyscale or (y, x, 3) RGB, values as they are (no scaling)."""
    image = np.asarray(image, dtype=np.uint16)
    height, width = image.shape[:2]
    planes = 1 if image.ndim == 2 else image.shape[2]
    writer = png.Writer(width, height, greyscale=planes == 1, bitdepth=16)
    with open(path, "wb") as out:
        writer.write(out, image.reshape(height, width * planes))


def write_tiff(path: str | os.PathLike[str], image: np.ndarray) -> None:
    """Write a 16-bit TIFF: (y, x) greyscale or (y, x, 3) RGB."""
    image = np.asarray(image, dtype=np.uint16)
    photometric = "minisblack" if image.ndim == 2 else "rgb"
    tifffile.imwrite(path, image, photometric=photometric, metadata=None)


def write_manifest(path: str | os.PathLike[str], rows: Iterable[Mapping[str, Any]]) -> None:
    """Write ``manifest.csv`` with :data:`~.model.MANIFEST_COLUMNS` (missing values as empty cells)."""
    with open(path, "w", newline="", encoding="utf-8") as out:
        writer = csv.DictWriter(out, fieldnames=MANIFEST_COLUMNS, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({key: _cell(row.get(key)) for key in MANIFEST_COLUMNS})


def write_table(path: str | os.PathLike[str], header: Sequence[str], rows: Iterable[Sequence]) -> None:
    """Write a calibration table (``calibration/*.csv``): a header row, then one row per entry."""
    with open(path, "w", newline="", encoding="utf-8") as out:
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(header)
        for row in rows:
            writer.writerow([_cell(v) for v in row])


def write_config(
    path: str | os.PathLike[str],
    values: Mapping[str, Any],
    sections: Mapping[str, Mapping[str, Any]],
    *,
    comments: Sequence[str] = (),
) -> None:
    """Write ``capture.toml``: comment lines, top-level ``values``, then one table per section."""
    lines = [f"# {comment}" for comment in comments]
    lines += [f"{key} = {_toml_value(value)}" for key, value in values.items()]
    for section, table in sections.items():
        lines += ["", f"[{section}]"] + [f"{k} = {_toml_value(v)}" for k, v in table.items()]
    with open(path, "w", encoding="utf-8") as out:
        out.write("\n".join(lines) + "\n")


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, float | np.floating):
        return f"{float(value):.10g}"
    return str(value)


def _toml_value(value: Any) -> str:
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, Mapping):  # an inline table: rgb.models, rgb.black_level_dn
        return (
            "{" + ", ".join(f"{_toml_value(str(k))} = {_toml_value(v)}" for k, v in value.items()) + "}"
        )
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, float | np.floating):
        return repr(float(value))
    return str(value)
