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
import sys
import threading
from collections.abc import Iterator
from typing import Any

__all__ = ["Terminated", "sigterm_as_interrupt", "quiet_cut_off_io"]


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


def _drop_closed_loop_errors(unraisable: Any) -> None:
    """``sys.unraisablehook`` that drops "Event loop is closed" from cut-off coroutines."""
    value = unraisable.exc_value
    if isinstance(value, RuntimeError) and "Event loop is closed" in str(value):
        return
    sys.__unraisablehook__(unraisable)


def quiet_cut_off_io() -> None:
    """After an interrupt: I/O coroutines it cut off (zarr's reads and writes) are closed at
    exit after their event loop, and each would print "Exception ignored ... Event loop is
    closed" with a traceback below the command's one ``interrupted`` line. Those are dropped;
    every other unraisable error is still printed."""
    sys.unraisablehook = _drop_closed_loop_errors
