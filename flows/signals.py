"""SIGTERM handled like Ctrl-C: a stopped command cleans up as an interrupted one does.

A service manager, ``kill`` or a batch system stops a process with SIGTERM, whose default
action ends Python at once: no ``finally`` block runs, Prefect's flow run stays RUNNING and
its embedded server is left to the watcher. Inside :func:`sigterm_as_interrupt` SIGTERM
raises :class:`Terminated`, a :class:`KeyboardInterrupt`, so it unwinds exactly like SIGINT:
partial output removed, the flow run marked crashed, the embedded server stopped at exit, and
the command line prints one ``interrupted`` line.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["Terminated", "sigterm_as_interrupt"]


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the main thread was (like :class:`KeyboardInterrupt` for SIGINT)."""


def _raise_terminated(signum: int, frame: Any) -> None:
    raise Terminated("terminated (SIGTERM)")


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Within the block, SIGTERM raises :class:`Terminated` in the main thread (elsewhere: no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
