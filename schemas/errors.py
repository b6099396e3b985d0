"""The one small error hierarchy of spectralize.

Every message says who failed, what was expected, what was found and, where it helps, how to
fix it. All errors derive from :class:`SpectralizeError`; the ones about bad values also derive
from :class:`ValueError`, so plain ``except ValueError`` code keeps working.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = [
    "SpectralizeError",
    "SchemaError",
    "Problem",
    "StoreError",
    "NodeNotFoundError",
    "ParameterError",
    "PipelineError",
    "CalibrationError",
    "ReconstructionError",
]


class SpectralizeError(Exception):
    """Base class of every error raised by spectralize."""


@dataclass(frozen=True)
class Problem:
    """One thing wrong with an array, a group or a graph.

    Attributes
    ----------
    where
        What is wrong: ``"raw/dark:frames"``, ``"node dark_average"``.
    expected
        What the contract asks for.
    found
        What was found instead.
    """

    where: str
    expected: str
    found: str

    def __str__(self) -> str:
        return f"{self.where}: expected {self.expected}, found {self.found}"


class _ProblemList(SpectralizeError):
    """An error that carries every problem found, not just the first."""

    def __init__(self, summary: str, problems: Iterable[Problem | str] = ()):
        self.summary = summary
        self.problems = list(problems)
        lines = [summary] + [f"  - {p}" for p in self.problems]
        super().__init__("\n".join(lines))


class SchemaError(_ProblemList, ValueError):
    """Data that does not follow the run-store contract (dims, coords, dtype, units, values)."""


class StoreError(SpectralizeError):
    """A path that is not a spectralize run store, or a store in an unusable state."""


class NodeNotFoundError(SpectralizeError, KeyError):
    """An unknown node name; the message lists the registered ones."""

    def __str__(self) -> str:  # KeyError would quote the whole message
        return str(self.args[0]) if self.args else ""


class ParameterError(_ProblemList, ValueError):
    """Unknown or invalid node parameters."""


class PipelineError(_ProblemList):
    """A node graph that cannot run: missing inputs, duplicate outputs, cycles, schema mismatches."""


class CalibrationError(SpectralizeError, ValueError):
    """Calibration input that cannot give a meaningful response, QE or camera matrix."""


class ReconstructionError(SpectralizeError, ValueError):
    """Reconstruction input that does not fit together (shapes, wavelengths, filters)."""
