"""The calibration tables of a capture folder (``calibration/*.csv``, the patch label image).

- ``illuminant.csv`` (``wavelength_nm, value``): the measured LED spectrum, relative;
- ``white_reference.csv`` (``wavelength_nm, reflectance``): the white target's certificate;
- ``colour_checker.csv`` (``patch, wavelength_nm, reflectance``), or a colour-science chart
  named in ``capture.toml``, and the chart's patch label image (0 frame, ``k`` patch ``k``);
- ``exposure_plan.csv`` (``wavelength_nm, exposure_time_s, filter_size_px``), optional.

Tables are interpolated linearly onto the wavelengths of the white reference's band series
(``bands``), which they must cover. :func:`parse_table` and :func:`on_bands` are pure (text or
arrays in, result and problems out); :func:`read_calibration` reads the files.

References
----------
Fast Capture of Spectral Image Series, sec. 4 (spectral calibration with a white reference
and a colour checker).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from spectralize.schemas import Problem

from .images import read_image, reader_failure
from .model import CALIBRATION, CONFIG, Config, contained_path

__all__ = [
    "parse_table",
    "on_bands",
    "patches_from_table",
    "patches_from_chart",
    "check_patch_index",
    "LED_POWER",
    "parse_led_power",
    "read_led_power",
    "read_calibration",
]


def parse_table(
    text: str, where: str, columns: Sequence[str], *, text_columns: Sequence[str] = ()
) -> tuple[dict[str, list] | None, list[Problem]]:
    """Parse a calibration CSV table (header row first; blank rows are skipped).

    Parameters
    ----------
    text
        The file's text, line endings as stored (read with ``newline=""``).
    where
        The file's name in problems (``calibration/illuminant.csv``).
    columns
        The columns to read (more are ignored); numbers unless in ``text_columns``.

    Returns
    -------
    table, problems
        ``{column: values}``, or ``None`` with the problem (a missing column, a cell that is
        not a number, no rows).
    """
    problems: list[Problem] = []
    table: list[tuple[int, list[str]]] = []  # (line in the file, cells), blank rows left out
    try:
        reader = csv.reader(io.StringIO(text, newline=""))
        for cells in reader:
            if any(c.strip() for c in cells):
                table.append((reader.line_num, cells))
    except csv.Error as error:
        problems.append(Problem(where, "a readable CSV file", f"{type(error).__name__}: {error}"))
        return None, problems
    header = [h.strip() for h in table[0][1]] if table else []
    if not table or any(c not in header for c in columns):
        problems.append(Problem(f"{where} line 1", f"the columns {', '.join(columns)}", f"{header}"))
        return None, problems
    out: dict[str, list] = {c: [] for c in columns}
    for line, cells in table[1:]:
        for c in columns:
            cell = cells[header.index(c)].strip() if header.index(c) < len(cells) else ""
            if c in text_columns:
                out[c].append(cell)
                continue
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                problems.append(Problem(f"{where} line {line}: {c}", "a finite number", repr(cell)))
                return None, problems
            out[c].append(value)
    if not table[1:]:
        problems.append(Problem(where, "at least one row", "none"))
        return None, problems
    return out, problems


def on_bands(
    where: str, wavelength: np.ndarray, values: np.ndarray, bands: np.ndarray
) -> tuple[np.ndarray | None, list[Problem]]:
    """A tabulated spectrum interpolated linearly onto ``bands`` [nm], which it must cover."""
    order = np.argsort(wavelength)
    wavelength, values = wavelength[order], values[order]
    if np.unique(wavelength).size != wavelength.size:
        return None, [Problem(where, "each wavelength once", "duplicate wavelengths")]
    outside = bands[(bands < wavelength[0] - 1e-6) | (bands > wavelength[-1] + 1e-6)]
    if outside.size:
        return None, [
            Problem(
                where,
                f"values covering every band ({bands.min():g}..{bands.max():g} nm)",
                f"{wavelength[0]:g}..{wavelength[-1]:g} nm (missing {outside.tolist()})",
            )
        ]
    return np.interp(bands, wavelength, values), []


def patches_from_table(
    table: dict[str, list], bands: np.ndarray, chart: str
) -> tuple[tuple[list[str], np.ndarray, str] | None, list[Problem]]:
    """``(names, reflectance (patch, band), chart)`` of a parsed ``colour_checker.csv``.

    Patches are numbered in the order they first appear in the table.
    """
    problems: list[Problem] = []
    names = list(dict.fromkeys(table["patch"]))
    rows = []
    for name in names:
        pick = [i for i, p in enumerate(table["patch"]) if p == name]
        wl = np.asarray(table["wavelength_nm"])[pick]
        rf = np.asarray(table["reflectance"])[pick]
        row, found = on_bands(f"{CALIBRATION}/colour_checker.csv patch {name!r}", wl, rf, bands)
        problems += found
        rows.append(row)
    if all(r is not None for r in rows) and bands.size:
        return (names, np.stack(rows), chart), problems
    return None, problems


def patches_from_chart(
    chart: str, bands: np.ndarray
) -> tuple[tuple[list[str], np.ndarray, str] | None, list[Problem]]:
    """``(names, reflectance (patch, band), chart)`` of a colour-science chart, on ``bands``."""
    import colour

    charts = colour.SDS_COLOURCHECKERS
    if chart not in charts:
        return None, [
            Problem(f"{CONFIG}: colour_checker.chart", f"one of {sorted(charts)}", repr(chart))
        ]
    if not bands.size:
        return None, []
    sds = charts[chart]
    names = list(sds)
    rows = [np.interp(bands, sds[n].wavelengths, sds[n].values) for n in names]
    return (names, np.clip(np.stack(rows), 0, 1), chart), []


def check_patch_index(
    where: str, index: np.ndarray, frame_shape: tuple[int, int] | None, n_patches: int | None
) -> tuple[np.ndarray | None, list[Problem]]:
    """The patch label image as ``(y, x)`` int16 patch indices, -1 on the frame.

    ``index`` holds 0 on the frame and ``k`` on patch ``k`` (1-based); it must have the frames'
    shape and no label above ``n_patches``.
    """
    if index.ndim != 2 or (frame_shape is not None and index.shape != frame_shape):
        return None, [
            Problem(
                where, f"a monochrome image of the frames' shape {frame_shape}", f"shape {index.shape}"
            )
        ]
    if n_patches is not None and int(index.max()) > n_patches:
        return None, [
            Problem(where, f"labels 0 (frame) .. {n_patches} (patches)", f"a label {int(index.max())}")
        ]
    return index.astype(np.int16) - 1, []


def read_calibration(
    root: Path,
    config: Config,
    bands: np.ndarray,
    frame_shape: tuple[int, int] | None,
    cameras: Sequence[str] = (),
    leds: dict[int, str] | None = None,
) -> tuple[dict[str, Any], list[Problem]]:
    """Read and check the calibration tables of a capture folder.

    Parameters
    ----------
    root
        The capture folder.
    config
        Its ``capture.toml``.
    bands
        The wavelengths of the white reference's band series [nm].
    frame_shape
        The frames' shape, which the patch label images must have (``None``: unknown).
    cameras
        The RGB cameras with chart frames of their own: each needs its patch label image
        (:meth:`~.model.Config.patch_index_of`).
    leds
        ``{led: where}`` of every LED the rows use (``where``: the first manifest line using
        it), which ``led_power.csv``, when there is one, must list.

    Returns
    -------
    tables, problems
        ``illuminant``, ``white`` (on ``bands``), ``patches`` (names, reflectance, chart),
        ``patch_index``, ``rgb_patch_index`` (camera -> labels), ``led_power`` (``None``
        without ``led_power.csv``) and, when ``exposure_plan.csv`` exists, ``plan``
        (wavelength, time, filter size); every problem found.
    """
    problems: list[Problem] = []
    out: dict[str, Any] = {}
    for key, name, column, what in (
        ("illuminant", "illuminant.csv", "value", "the measured LED spectrum"),
        ("white", "white_reference.csv", "reflectance", "the white target's certified reflectance"),
    ):
        table = _read_table(root, name, ("wavelength_nm", column), problems, config=config)
        if table is None and not _is_file(root, name, config):
            problems.append(Problem(f"{CALIBRATION}/{name}", what, "no such file"))
        if table is not None:
            wl, v = np.asarray(table["wavelength_nm"]), np.asarray(table[column])
            if (v < 0).any() or (key == "white" and (v > 1).any()):
                problems.append(
                    Problem(
                        f"{CALIBRATION}/{name}",
                        "values >= 0" + (" and <= 1" if key == "white" else ""),
                        f"{v.min():g}..{v.max():g}",
                    )
                )
            if bands.size:
                out[key], found = on_bands(f"{CALIBRATION}/{key}", wl, v, bands)
                problems += found
    # the colour checker: a table or a chart of colour-science
    if _is_file(root, "colour_checker.csv", config):
        table = _read_table(
            root,
            "colour_checker.csv",
            ("patch", "wavelength_nm", "reflectance"),
            problems,
            config=config,
            text_columns=("patch",),
        )
        if table is not None:
            patches, found = patches_from_table(table, bands, config.chart or "colour_checker.csv")
            problems += found
            if patches is not None:
                out["patches"] = patches
    elif config.chart:
        patches, found = patches_from_chart(config.chart, bands)
        problems += found
        if patches is not None:
            out["patches"] = patches
    else:
        problems.append(
            Problem(
                f"{CALIBRATION}/colour_checker.csv",
                "the patches' reflectance, or colour_checker.chart in capture.toml",
                "neither",
            )
        )
    n_patches = len(out["patches"][0]) if "patches" in out else None
    index = _read_patch_index(root, config, config.patch_index, frame_shape, n_patches, problems)
    if index is not None:
        out["patch_index"] = index
    out["rgb_patch_index"] = {}
    for camera in cameras:
        name = config.patch_index_of(camera)
        index = (
            out.get("patch_index")
            if name == config.patch_index
            else _read_patch_index(root, config, name, frame_shape, n_patches, problems, camera)
        )
        if index is not None:
            out["rgb_patch_index"][camera] = index
    if leds is not None:
        power, found = read_led_power(root, config, leds)
        problems += found
        out["led_power"] = power
    columns = ("wavelength_nm", "exposure_time_s", "filter_size_px")
    table = _read_table(root, "exposure_plan.csv", columns, problems, config=config)
    if table is not None:
        out["plan"] = tuple(np.asarray(table[c]) for c in columns)
    return out, problems


def _read_patch_index(
    root: Path,
    config: Config,
    name: str,
    frame_shape: tuple[int, int] | None,
    n_patches: int | None,
    problems: list[Problem],
    camera: str | None = None,
) -> np.ndarray | None:
    """A patch label image (:func:`check_patch_index`), or ``None`` with its problem."""
    whose = f"RGB camera {camera!r}'s" if camera else "the colour checker's"
    labels, why = contained_path(root, name, follow_symlinks=config.follow_symlinks)
    if labels is None:
        problems.append(Problem(name, "a file inside the capture folder", why))
        return None
    if not labels.is_file():
        hint = (
            " (or colour_checker.patch_indices in capture.toml, or shared_patch_index = true when "
            "the cameras' frames of the chart are one view)"
            if camera
            else ""
        )
        problems.append(Problem(name, f"{whose} patch label image of the chart{hint}", "no such file"))
        return None
    try:
        index = read_image(labels)
    except Exception as error:
        problems.append(Problem(name, "a readable TIFF or PNG file", reader_failure(error)))
        return None
    index, found = check_patch_index(name, index, frame_shape, n_patches)
    problems += found
    return index


LED_POWER = "led_power.csv"
"""Optional table ``led, relative_power``: the power of each LED relative to the others."""


def parse_led_power(
    table: dict[str, list], lines: list[int], leds: dict[int, str], where: str
) -> tuple[dict[int, float] | None, list[Problem]]:
    """``{led: relative power}`` of a parsed ``led_power.csv``; every LED of ``leds`` listed once.

    ``lines`` are the file's line numbers of the table's rows (problems name them).
    """
    problems: list[Problem] = []
    power: dict[int, float] = {}
    for line, led, value in zip(lines, table["led"], table["relative_power"], strict=True):
        if led != int(led):
            problems.append(Problem(f"{where} line {line}: led", "an LED index (integer)", repr(led)))
        elif int(led) in power:
            problems.append(
                Problem(f"{where} line {line}: led", "each LED once", f"LED {int(led)} again")
            )
        elif not value > 0:
            problems.append(
                Problem(f"{where} line {line}: relative_power", "a positive number", repr(value))
            )
        else:
            power[int(led)] = float(value)
    missing = sorted(set(leds) - set(power))
    for led in missing:
        problems.append(Problem(where, f"a row for LED {led}, which lights {leds[led]}", "none"))
    return (None if problems else power), problems


def read_led_power(
    root: Path, config: Config, leds: dict[int, str]
) -> tuple[dict[int, float] | None, list[Problem]]:
    """``calibration/led_power.csv``, when it exists: ``{led: relative power}`` (``None``
    without the file); an LED the manifest uses but the table lacks is a problem."""
    problems: list[Problem] = []
    table = _read_table(root, LED_POWER, ("led", "relative_power"), problems, config=config)
    if table is None:
        return None, problems
    path, _ = contained_path(root, f"{CALIBRATION}/{LED_POWER}", follow_symlinks=config.follow_symlinks)
    with open(path, newline="", encoding="utf-8-sig") as handle:
        reader = csv.reader(handle)
        lines = [reader.line_num for cells in reader if any(c.strip() for c in cells)][1:]
    power, found = parse_led_power(table, lines, leds, f"{CALIBRATION}/{LED_POWER}")
    return power, problems + found


def _is_file(root: Path, name: str, config: Config) -> bool:
    """Whether ``calibration/<name>`` is a file inside the folder (refusals: :func:`_read_table`)."""
    path, _ = contained_path(root, f"{CALIBRATION}/{name}", follow_symlinks=config.follow_symlinks)
    return path is not None and path.is_file()


def _read_table(
    root: Path,
    name: str,
    columns: Sequence[str],
    problems: list[Problem],
    *,
    config: Config,
    text_columns: Sequence[str] = (),
) -> dict[str, list] | None:
    """:func:`parse_table` of ``calibration/<name>``; ``None`` when it is absent, outside or bad."""
    where = f"{CALIBRATION}/{name}"
    path, why = contained_path(root, where, follow_symlinks=config.follow_symlinks)
    if path is None:
        problems.append(Problem(where, "a file inside the capture folder", why))
        return None
    if not path.is_file():
        return None
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            text = handle.read()
    except (OSError, UnicodeDecodeError) as error:
        problems.append(Problem(where, "a readable CSV file", f"{type(error).__name__}: {error}"))
        return None
    table, found = parse_table(text, where, columns, text_columns=text_columns)
    problems += found
    return table
