"""The parser of ``capture.toml``: text in, a :class:`~.model.Config` and problems out.

``capture.toml`` names the cameras, their bit depths, the exposure plan's constants (eq. 2
and 3: ``t0``, ``s0``, ``omega``) and the colour chart. A key the parser does not read is
refused, with the closest known one (a misspelt optional key would otherwise leave its
default in force without a word), as a node's unknown parameter is; the ``[source]`` table
(where the folder came from) is free.

References
----------
Fast Capture of Spectral Image Series, sec. 4, eq. 2 and 3 (the exposure plan).
"""

from __future__ import annotations

import difflib
import tomllib
from collections.abc import Iterable
from typing import Any

from spectralize.schemas import Problem

from .model import CALIBRATION, CAPTURE_FORMAT, CONFIG, Config

__all__ = ["parse_config"]

_FREE_KEYS = ("version", "source")
"""Top-level keys of ``capture.toml`` no check reads: the format's version (one so far) and the
``[source]`` table, free text about where the folder came from."""


def parse_config(text: str, default_name: str) -> tuple[Config | None, list[Problem]]:
    """Parse the text of ``capture.toml``.

    Parameters
    ----------
    text
        The file's text.
    default_name
        The run's name when ``name`` is absent (the capture folder's name).

    Returns
    -------
    config, problems
        The config, or ``None`` when any key is missing, of the wrong type or out of range;
        one :class:`~spectralize.schemas.Problem` per such key (``capture.toml: rgb.bit_depth``).
    """
    where = CONFIG
    problems: list[Problem] = []
    try:
        raw = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as error:
        problems.append(Problem(where, "a readable TOML file", f"{type(error).__name__}: {error}"))
        return None, problems
    top = _Table(raw, _FREE_KEYS)
    tables = {"": top}  # every table read, by section: the keys asked are the known ones
    if top.get("format", CAPTURE_FORMAT) != CAPTURE_FORMAT:
        problems.append(Problem(f"{where}: format", repr(CAPTURE_FORMAT), repr(raw.get("format"))))
    name = str(top.get("name", default_name))

    def section(name: str) -> dict[str, Any]:
        value = top.get(name, {})
        if not isinstance(value, dict):
            problems.append(Problem(f"{where}: [{name}]", "a table", repr(value)))
            return {}
        tables[name] = _Table(value)
        return tables[name]

    def get(table: dict, sect: str, key: str, kind: type | tuple, default: Any = ...) -> Any:
        label = f"{where}: {sect + '.' if sect else ''}{key}"
        if key not in table:
            if default is ...:
                problems.append(Problem(label, f"a {getattr(kind, '__name__', 'value')}", "nothing"))
            return None if default is ... else default
        value = table[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
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
        "rotation_step": get(top, "", "rotation_step_deg", float),
        "tolerance": get(top, "", "angle_tolerance_deg", float, 0.5),
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
    follow = get(top, "", "follow_symlinks", bool, False)
    shared = get(checker, "colour_checker", "shared_patch_index", bool, False)
    models = _camera_table(rgb, "rgb", "models", str, cameras, problems)
    black = _camera_table(rgb, "rgb", "black_level_dn", int, cameras, problems)
    for camera, value in black.items():
        if values["rgb_depth"] is not None and not 0 <= value < 2 ** values["rgb_depth"] - 1:
            problems.append(
                Problem(
                    f"{where}: rgb.black_level_dn.{camera}",
                    f"0..{2 ** values['rgb_depth'] - 2} DN",
                    repr(value),
                )
            )
    white = _camera_table(rgb, "rgb", "white_level_dn", int, cameras, problems)
    for camera, value in white.items():
        low = black.get(camera, 0) + 1
        if values["rgb_depth"] is not None and not low <= value <= 2 ** values["rgb_depth"] - 1:
            problems.append(
                Problem(
                    f"{where}: rgb.white_level_dn.{camera}",
                    f"{low}..{2 ** values['rgb_depth'] - 1} DN (above the black level, at most "
                    "the top code)",
                    repr(value),
                )
            )
    indices = _camera_table(checker, "colour_checker", "patch_indices", str, cameras, problems)
    problems += _unknown_keys(tables)  # last: every key this parser knows was asked for
    if problems:
        return None, problems
    config = Config(
        name=name,
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
        follow_symlinks=bool(follow),
        rgb_models=models,
        black_level_dn=black,
        white_level_dn=white,
        patch_indices=indices,
        shared_patch_index=bool(shared),
        raw=raw,
    )
    return config, problems


def _camera_table(
    table: dict, sect: str, key: str, kind: type, cameras: list | None, problems: list[Problem]
) -> dict:
    """An optional ``[sect.key]`` table of one value per RGB camera (``camera = value``)."""
    label = f"{CONFIG}: {sect}.{key}"
    value = table.get(key, {})
    if not isinstance(value, dict):
        problems.append(Problem(label, "a table of camera = value", repr(value)))
        return {}
    out = {}
    for camera, item in value.items():
        if cameras is not None and camera not in cameras:
            problems.append(Problem(f"{label}.{camera}", f"one of rgb.cameras {cameras}", repr(camera)))
        elif not isinstance(item, kind) or isinstance(item, bool):
            problems.append(Problem(f"{label}.{camera}", f"a {kind.__name__}", repr(item)))
        else:
            out[str(camera)] = item
    return out


class _Table(dict):
    """A table of ``capture.toml`` that remembers which keys the parser asked for.

    The keys asked for (``in``, ``[]``, ``get``) are the ones the parser knows, so the list
    of known keys cannot drift from the parser: a key it never asks for is an unknown one
    (:func:`_unknown_keys`). Every key is asked for on every parse, in the order it is read.
    """

    def __init__(self, table: dict[str, Any], free: Iterable[str] = ()) -> None:
        super().__init__(table)
        self.asked: dict[str, None] = dict.fromkeys(free)

    def __contains__(self, key: object) -> bool:
        self.asked[str(key)] = None
        return super().__contains__(key)

    def __getitem__(self, key: str) -> Any:
        self.asked[key] = None
        return super().__getitem__(key)

    def get(self, key: str, default: Any = None) -> Any:
        self.asked[key] = None
        return super().get(key, default)


def _unknown_keys(tables: dict[str, _Table]) -> list[Problem]:
    """One problem per key of a table that the parser never asked for, with the closest
    known key ("did you mean"), as the engine lists a node's unknown parameters."""
    problems = []
    for sect, table in tables.items():
        known = list(table.asked)
        for key in dict.keys(table):
            if key not in table.asked:
                problems.append(
                    Problem(
                        f"{CONFIG}: {sect + '.' if sect else ''}{key}",
                        f"one of: {', '.join(known)}",
                        f"an unknown key{_did_you_mean(key, known)}",
                    )
                )
    return problems


def _did_you_mean(word: str, candidates: Iterable[str]) -> str:
    """``; did you mean 'x'?`` for the closest candidates, or nothing (the wording of the
    command line's checks, ``spectralize.flows.command_checks.did_you_mean``)."""
    close = difflib.get_close_matches(word, list(candidates), n=3, cutoff=0.6)
    if not close:
        return ""
    return f"; did you mean {' or '.join(repr(c) for c in close)}?"
