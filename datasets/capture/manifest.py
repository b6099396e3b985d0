"""The parser of ``manifest.csv``: text in, :class:`~.model.Row` objects and problems out.

Only the table itself is checked here (columns, numbers, kinds); whether a row makes sense
for its camera, and whether the rows together form the exposure series a run needs, is
:mod:`.checks`' question.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (what each image of the gantry is).
"""

from __future__ import annotations

import csv
import io
import math
from typing import Any

from spectralize.schemas import Problem

from .model import ANGLES, KINDS, MANIFEST, MANIFEST_COLUMNS, Row

__all__ = ["parse_manifest"]


def parse_manifest(text: str) -> tuple[list[Row], list[Problem]]:
    """Parse the text of ``manifest.csv`` (UTF-8, header row first).

    Parameters
    ----------
    text
        The file's text, line endings as stored (read with ``newline=""``).

    Returns
    -------
    rows, problems
        The rows that parsed (blank lines skipped; ``Row.line`` counts the header as 1) and
        one :class:`~spectralize.schemas.Problem` per bad cell, naming line and column. A row
        with a problem is left out.
    """
    problems: list[Problem] = []
    try:
        table = list(csv.reader(io.StringIO(text, newline="")))
    except csv.Error as error:
        problems.append(Problem(MANIFEST, "a readable CSV file", f"{type(error).__name__}: {error}"))
        return [], problems
    if not table:
        problems.append(
            Problem(MANIFEST, f"a header with {', '.join(MANIFEST_COLUMNS)}", "an empty file")
        )
        return [], problems
    header = [h.strip() for h in table[0]]
    missing = [c for c in MANIFEST_COLUMNS if c not in header]
    if missing:
        problems.append(
            Problem(f"{MANIFEST} line 1", f"the columns {', '.join(MANIFEST_COLUMNS)}", f"no {missing}")
        )
        return [], problems
    index = {name: header.index(name) for name in MANIFEST_COLUMNS}
    rows = []
    for line, cells in enumerate(table[1:], start=2):
        if not any(c.strip() for c in cells):
            continue
        cells = cells + [""] * (len(header) - len(cells))
        row = _row(line, {name: cells[i].strip() for name, i in index.items()}, problems)
        if row is not None:
            rows.append(row)
    return rows, problems


def _row(line: int, value: dict[str, str], problems: list[Problem]) -> Row | None:
    """One row from its cells by column name; ``None`` (and problems) when a cell is bad."""
    where = f"{MANIFEST} line {line} ({value['file'] or 'no file'})"
    bad = len(problems)

    def number(name: str, kind: type = float) -> Any:
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
    return row if len(problems) == bad else None
