"""The text of ``--set KEY=VALUE``: values parsed and formatted, parameter types shown.

Shared by the command line (:mod:`.cli`, which parses ``--set``) and the node listing
(:mod:`.node_listing`, which prints every parameter as a ``--set`` line whose default parses
back). Imports nothing heavy: ``spectralize --help`` and ``spectralize nodes`` stay fast.
"""

from __future__ import annotations

import ast
import json
from collections.abc import Sequence
from typing import Any

__all__ = ["UsageError", "parse_value", "format_value", "parse_assignments", "type_text"]


class UsageError(Exception):
    """A wrong command line (a malformed ``--set``, an unknown name, a value out of range),
    found before anything loads: exit 2, no traceback."""


def parse_value(text: str) -> Any:
    """A ``--set`` value: JSON (``null``, ``true``, ``[0.5, 0.0]``, ``"text"``), else a Python
    literal (``None``, ``True``, ``(0.5, 0.0)``, ``'D65'``), else the text itself (``demo``)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        pass
    try:
        return ast.literal_eval(text)
    except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
        return text


def format_value(value: Any) -> str:
    """``value`` as ``--set`` text that :func:`parse_value` reads back: a string bare when
    it reads back as itself (``block-jacobi-pcg``), anything else as compact JSON (``null``,
    ``[0.05,0.5]``, ``"None"``)."""
    if isinstance(value, str) and value and value == value.strip() and parse_value(value) == value:
        return value
    from pydantic_core import to_jsonable_python

    return json.dumps(to_jsonable_python(value), separators=(",", ":"))


def parse_assignments(items: Sequence[str]) -> dict[str, Any]:
    """``--set`` items (``KEY=VALUE``) as ``{key: value}``."""
    values = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise UsageError(
                f"--set expects KEY=VALUE (e.g. dark_average.frames_per_chunk=8), got {item!r}"
            )
        values[key.strip()] = parse_value(value.strip())
    return values


def type_text(annotation: str) -> str:
    """A parameter's type without constraint metadata: ``Annotated[float, Field...]`` -> ``float``."""
    while (start := annotation.find("Annotated[")) >= 0:
        depth, first_end, i = 0, None, start + len("Annotated[")
        for i in range(start + len("Annotated["), len(annotation)):
            char = annotation[i]
            if char in "[(":
                depth += 1
            elif char in "])" and depth:
                depth -= 1
            elif char == "," and depth == 0 and first_end is None:
                first_end = i
            elif char == "]" and depth == 0:
                break
        inner = annotation[start + len("Annotated[") : first_end or i]
        annotation = annotation[:start] + inner + annotation[i + 1 :]
    return annotation
