"""spectralize.schemas: the data contract of a run store, its validation, and store access.

Nothing here imports Prefect; a notebook can open a run with ``open_run(path)``.
"""

from .errors import (
    CalibrationError,
    NodeDeclarationError,
    NodeNotFoundError,
    ParameterError,
    PipelineError,
    Problem,
    ReconstructionError,
    SchemaError,
    SimulationError,
    SpectralizeError,
    StoreError,
)
from .lock import StoreBusyError
from .run import GROUP_SCHEMAS, register_schema, render_table, schema_for
from .spec import ArraySpec, GroupSchema, check_dataset, validate_dataset, validate_values
from .store import ChecksumError, RunStore, compute_fingerprint

__all__ = [
    "ArraySpec",
    "GroupSchema",
    "GROUP_SCHEMAS",
    "RunStore",
    "register_schema",
    "render_table",
    "schema_for",
    "validate_dataset",
    "validate_values",
    "check_dataset",
    "compute_fingerprint",
    "open_run",
    "SpectralizeError",
    "SchemaError",
    "StoreError",
    "StoreBusyError",
    "ChecksumError",
    "NodeNotFoundError",
    "NodeDeclarationError",
    "ParameterError",
    "PipelineError",
    "CalibrationError",
    "ReconstructionError",
    "SimulationError",
    "Problem",
]


def open_run(path) -> RunStore:
    """Open a run store for analysis: ``open_run("run.zarr").read("spectra")``."""
    return RunStore.open(path)
