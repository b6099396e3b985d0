"""Where a flow run's messages go: Prefect's run logger inside a run, the console outside.

The steps of a flow (:mod:`.steps`), the damage checks (:mod:`.repair`) and the report task
are also called outside a Prefect run (a plain ``.fn()`` call, a benchmark, the up-to-date
answer that starts no Prefect API); their messages then go to stdout and stderr.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from prefect import get_run_logger

__all__ = ["info_logger", "warn"]


def info_logger() -> Callable[[str], None]:
    """The run logger's ``info`` inside a Prefect run, else :func:`print`."""
    try:
        logger = get_run_logger()
    except Exception:  # called outside a Prefect run (plain .fn() call)
        return print
    return logger.info


def warn(message: str) -> None:
    """A warning in the run's log inside a Prefect run, else on stderr."""
    try:
        get_run_logger().warning(message)
    except Exception:
        print(f"warning: {message}", file=sys.stderr)
