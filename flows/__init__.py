"""spectralize.flows: orchestration only. Prefect flows that wire nodes against a run store.

Prefect's embedded local API (SQLite) is the default; no server needs to be started.
The environment defaults below are set before Prefect is imported: a new Prefect database
can take longer than Prefect's default start-up limit, and the embedded server's analytics cause
'database is locked' errors.

Nothing is imported eagerly: ``spectralize --help`` and ``spectralize nodes`` answer without
Prefect (imported by :mod:`.runtime`, when a flow runs) and without the engine's science
stack (imported by :mod:`.pipelines`, on first use of ``FLOWS``). ``from spectralize.flows
import run_flow, FLOWS`` works as before (module ``__getattr__``).
"""

import os
from typing import TYPE_CHECKING

for _key, _value in {
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "90",
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DASK_LOGGING__DISTRIBUTED": "warning",
}.items():
    os.environ.setdefault(_key, _value)

if TYPE_CHECKING:
    from .pipelines import FLOWS, FlowDefinition, get_flow
    from .runtime import run_steps
    from .steps import RunReport, StepReport

# where each lazy attribute lives
_LAZY = {
    "FLOWS": "pipelines",
    "FlowDefinition": "pipelines",
    "get_flow": "pipelines",
    "RunReport": "steps",
    "StepReport": "steps",
    "run_steps": "runtime",
}


def __getattr__(name: str):
    if name in _LAZY:
        from importlib import import_module

        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})


__all__ = ["FLOWS", "FlowDefinition", "get_flow", "run_flow", "run_steps", "RunReport", "StepReport"]


def run_flow(
    name: str,
    store: str | os.PathLike[str],
    *,
    parameters=None,
    retries: int = 0,
    dask_address: str | None = None,
    verify: bool = False,
    strict: bool = False,
) -> "RunReport":
    """Run the named flow (see ``spectralize flows``) against ``store``.

    Parameters
    ----------
    name
        Flow name, e.g. ``"dark"``.
    store
        Run store path.
    parameters
        ``{"node.parameter": value}`` or ``{"parameter": value}`` overrides.
    retries
        Prefect task retries per node.
    dask_address
        Address of an existing ``dask.distributed`` scheduler; local threads by default.
    verify
        Recompute every checksum of the groups the flow reads or writes before trusting them.
    strict
        Stop with a :class:`~spectralize.schemas.CalibrationError` when a calibration node's
        result check warns (before the reconstruction); else the warnings are only logged.
    """
    from .pipelines import get_flow, step_parameters
    from .runtime import run_steps

    definition = get_flow(name)
    problems: list = []
    steps = step_parameters(definition.steps, dict(parameters or {}), problems=problems)
    return run_steps(
        store,
        steps,
        flow_name=name,
        problems=problems,
        retries=retries,
        dask_address=dask_address,
        report=definition.report,
        verify=verify,
        strict=strict,
    )
