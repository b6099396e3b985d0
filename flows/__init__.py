"""spectralize.flows: orchestration only. Prefect flows that wire nodes against a run store.

Prefect's embedded local API (SQLite) is the default; no server needs to be started.
The environment defaults below are set before Prefect is imported (see ../shared/STACK.md):
a new Prefect database can take longer than Prefect's 20 s start-up limit, and the
embedded server's analytics cause 'database is locked' errors.
"""

import os
from typing import TYPE_CHECKING

for _key, _value in {
    "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "90",
    "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
    "DASK_LOGGING__DISTRIBUTED": "warning",
}.items():
    os.environ.setdefault(_key, _value)

from .pipelines import FLOWS, FlowDefinition, get_flow  # noqa: E402

if TYPE_CHECKING:
    from .runtime import RunReport

# Prefect is imported on first use of the runtime, so `spectralize validate`, `clean` and
# `--version` answer without paying for its import.
_RUNTIME = ("RunReport", "StepReport", "run_steps")


def __getattr__(name: str):
    if name in _RUNTIME:
        from . import runtime

        return getattr(runtime, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["FLOWS", "FlowDefinition", "get_flow", "run_flow", "run_steps", "RunReport", "StepReport"]


def run_flow(
    name: str,
    store: str | os.PathLike[str],
    *,
    parameters=None,
    retries: int = 0,
    dask_address: str | None = None,
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
    """
    from .runtime import run_steps, step_parameters

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
    )
