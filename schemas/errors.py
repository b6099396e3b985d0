"""The one error hierarchy of spectralize.

Every error carries a list of :class:`Problem` items, each naming the array, group or
parameter that is wrong (``where``), what the contract asks for (``expected``) and what was
found (``found``), so one error can report everything wrong at once::

    raise CalibrationError("cannot recover the OECF:", [
        Problem("raw/rgb:frames", "at least 2 exposures per image", "1 exposure"),
    ])
    raise CalibrationError.single("raw/rgb:frames", "at least 2 exposures", "1 exposure")

A plain message (``CalibrationError("message")``) still works and gives an empty problem
list. All errors derive from :class:`SpectralizeError`; those about bad values also derive
from :class:`ValueError`, so plain ``except ValueError`` code keeps working.

====================================  ====================================================
``SpectralizeError``                  base
``SchemaError`` (ValueError)          data that breaks the run-store contract
``StoreError``                        a path that is not a usable run store
``NodeNotFoundError`` (KeyError)      an unknown node name
``NodeDeclarationError``              a node declared wrongly (found at import time)
``ParameterError`` (ValueError)       unknown or invalid node parameters
``PipelineError``                     a node graph that cannot run
``CalibrationError`` (ValueError)     calibration input that cannot give a result
``ReconstructionError`` (ValueError)  reconstruction input that does not fit together
``SimulationError`` (ValueError)      simulator input (camera model, recipe, gantry)
====================================  ====================================================
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Self

__all__ = [
    "Problem",
    "SpectralizeError",
    "SchemaError",
    "StoreError",
    "NodeNotFoundError",
    "NodeDeclarationError",
    "ParameterError",
    "PipelineError",
    "CalibrationError",
    "ReconstructionError",
    "SimulationError",
]


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an array, a group, a parameter or a graph.

    Attributes
    ----------
    where
        What is wrong: ``"raw/dark:frames"``, ``"dark_average.ddof"``, ``"node 'evaluate'"``.
    expected
        What the contract asks for.
    found
        What was found instead.
    hint
        How to fix it, where that helps (optional).
    """

    where: str
    expected: str
    found: str
    hint: str = ""

    def __str__(self) -> str:
        text = f"{self.where}: expected {self.expected}, found {self.found}"
        return f"{text} ({self.hint})" if self.hint else text


class SpectralizeError(Exception):
    """Base class of every error raised by spectralize.

    Parameters
    ----------
    summary
        One line saying who failed (``"invalid parameters for node 'evaluate':"``).
    problems
        Every problem found (:class:`Problem`; plain strings are accepted from older code).

    Attributes
    ----------
    summary : str
    problems : list of Problem
    """

    def __init__(self, summary: str = "", problems: Iterable[Problem | str] = ()):
        self.summary = summary
        self.problems = list(problems)
        if summary and self.problems:
            lines = [summary] + [f"  - {p}" for p in self.problems]
        else:
            lines = [summary] if summary else [str(p) for p in self.problems]
        super().__init__("\n".join(lines))

    @classmethod
    def single(cls, where: str, expected: str, found: Any, *, hint: str = "") -> Self:
        """An error with one :class:`Problem`: ``cls.single("recipe", "one of: ...", "x")``."""
        return cls("", [Problem(where, expected, str(found), hint)])

    def __reduce__(self) -> tuple[Any, ...]:  # keep summary and problems through pickling
        return (_rebuild, (type(self), self.summary, self.problems), self.__dict__)


def _rebuild(cls: type[SpectralizeError], summary: str, problems: list) -> SpectralizeError:
    error = cls.__new__(cls)
    SpectralizeError.__init__(error, summary, problems)
    return error


class SchemaError(SpectralizeError, ValueError):
    """Data that does not follow the run-store contract (dims, coords, dtype, units, values)."""


class StoreError(SpectralizeError):
    """A path that is not a spectralize run store, or a store in an unusable state."""


class NodeNotFoundError(SpectralizeError, KeyError):
    """An unknown node name; the message lists the registered ones."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0]) if self.args else ""


class NodeDeclarationError(SpectralizeError):
    """A node declared wrongly: inputs or parameters that are not arguments of its function,
    no outputs, unresolvable annotations."""


class ParameterError(SpectralizeError, ValueError):
    """Unknown or invalid node parameters."""


class PipelineError(SpectralizeError):
    """A node graph that cannot run: missing inputs, duplicate outputs, cycles, schema mismatches."""


class CalibrationError(SpectralizeError, ValueError):
    """Calibration input that cannot give a meaningful response, QE or camera matrix."""


class ReconstructionError(SpectralizeError, ValueError):
    """Reconstruction input that does not fit together (shapes, wavelengths, filters)."""


class SimulationError(SpectralizeError, ValueError):
    """Simulator input that cannot be captured: camera model, exposure plan, recipe, gantry.

    The simulator's own errors (``CameraModelError``, ``SimulationParameterError``,
    ``ShapeMismatchError`` in :mod:`spectralize.nodes.simulation.camera_model`) derive from it.
    """
