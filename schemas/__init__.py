"""spectralize.schemas: the data contract of a run store and its validation.

The one error hierarchy (:mod:`.errors`), array and group specs and their checks
(:mod:`.spec`), the run store's group schemas (:mod:`.run`) and the capture-folder contract
(:mod:`.capture`). The store that keeps data by this contract is :mod:`spectralize.store`.
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
from .run import GROUP_SCHEMAS, register_schema, render_table, schema_for
from .spec import (
    ArraySpec,
    GroupSchema,
    Precision,
    check_dataset,
    validate_dataset,
    validate_values,
)

__all__ = [
    "ArraySpec",
    "GroupSchema",
    "Precision",
    "GROUP_SCHEMAS",
    "register_schema",
    "render_table",
    "schema_for",
    "validate_dataset",
    "validate_values",
    "check_dataset",
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
    "Problem",
]
