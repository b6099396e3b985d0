"""Progress of long work inside a node (a solver run), for whoever shows it.

A node reports a long task with :func:`task`; a display registers a :class:`TaskListener`
with :func:`listening` (the flows do: :func:`spectralize.flows.progress.node_tasks` turns
the tasks into bars under the running node's line)::

    from spectralize.engine import progress

    with progress.task("images 4, 5, 6", total=max_iterations) as solving:
        callback = None if solving is None else lambda iteration, cube: solving.advance(iteration)
        result = reconstruct(..., callback=callback)

Without a listener :func:`task` yields ``None``: nothing is reported and the node passes no
callback, so library use and tests pay nothing.

Listeners live in a module-level registry guarded by a lock, not in context variables: nodes
run in dask's worker threads, which do not carry the context of the thread that registered
the listener. A listener is called from those threads, concurrently for tasks in different
threads; the calls of one task come from its thread, in order (started, advanced...,
finished). :meth:`Task.advance` tells the listeners at most every ``interval`` seconds (a
solver iteration can take less than a millisecond). A listener that raises is dropped with
one line on stderr; the task goes on. Work in another process (a ``dask.distributed``
worker) reports to that process's listeners, normally none.

Standard library only, so any node may import it.
"""

from __future__ import annotations

import contextlib
import itertools
import sys
import threading
import time
from collections.abc import Iterator
from typing import Protocol, TypeVar

__all__ = ["Listeners", "TaskListener", "Task", "listening", "listened", "task"]

L = TypeVar("L")


class TaskListener(Protocol):
    """What a display of tasks is told. Every method is called from the task's thread.

    ``key`` tells concurrent tasks apart (two may have the same label).
    """

    def task_started(self, key: int, label: str, total: int | None) -> None: ...

    def task_advanced(self, key: int, done: int) -> None: ...

    def task_finished(self, key: int, done: int) -> None: ...


class Listeners:
    """A thread-safe list of listeners: register for a block, call a method on every one.

    A listener without the method is skipped; one that raises is dropped with one line on
    stderr (a broken display must never cost a long run).

    Parameters
    ----------
    what
        What a listener is, for that line (``"progress display"``).
    """

    def __init__(self, what: str) -> None:
        self.what = what
        self._listeners: list[object] = []
        self._lock = threading.Lock()

    def __bool__(self) -> bool:
        return bool(self._listeners)

    @contextlib.contextmanager
    def listening(self, listener: L) -> Iterator[L]:
        """Register ``listener`` for the duration of the block."""
        with self._lock:
            self._listeners.append(listener)
        try:
            yield listener
        finally:
            self._drop(listener)

    def _drop(self, listener: object) -> None:
        with self._lock:
            if listener in self._listeners:  # a failing one was dropped already
                self._listeners.remove(listener)

    def emit(self, method: str, *args: object) -> None:
        """Call ``method(*args)`` of every listener that has it."""
        with self._lock:
            listeners = list(self._listeners)
        for listener in listeners:
            call = getattr(listener, method, None)
            if call is None:
                continue
            try:
                call(*args)
            except Exception as error:
                self._drop(listener)
                print(
                    f"spectralize: {self.what} stopped: {type(error).__name__}: {error}",
                    file=sys.stderr,
                )


_LISTENERS = Listeners("task progress listener")
_KEYS = itertools.count(1)


def listening(listener: TaskListener):
    """Send the tasks reported with :func:`task` to ``listener`` for the duration of the block."""
    return _LISTENERS.listening(listener)


def listened() -> bool:
    """Whether any listener is registered (without one, :func:`task` reports nothing)."""
    return bool(_LISTENERS)


_emit = _LISTENERS.emit


class Task:
    """One reported task; :meth:`advance` reports how far it is.

    Attributes
    ----------
    key
        Unique in this process.
    label
        What the task is (``"images 4, 5, 6"``).
    total
        The number of steps it takes at most (a solver's iteration limit); ``None`` if unknown.
    done
        The last value given to :meth:`advance`.
    interval
        Least time [s] between two reports of :meth:`advance` to the listeners.
    """

    __slots__ = ("key", "label", "total", "done", "interval", "_told")

    def __init__(self, key: int, label: str, total: int | None, interval: float) -> None:
        self.key = key
        self.label = label
        self.total = total
        self.done = 0
        self.interval = interval
        self._told = -float("inf")

    def advance(self, done: int) -> None:
        """``done`` steps are done; the listeners hear of it unless they did within ``interval``."""
        self.done = done
        now = time.monotonic()
        if now - self._told >= self.interval:
            self._told = now
            _emit("task_advanced", self.key, done)


@contextlib.contextmanager
def task(label: str, total: int | None = None, *, interval: float = 0.1) -> Iterator[Task | None]:
    """Report one long task (e.g. a solver run) to the listeners for the duration of the block.

    Parameters
    ----------
    label
        What the task is, for the display (``"images 4, 5, 6"``).
    total
        Steps it takes at most (a solver's iteration limit), or ``None`` if unknown.
    interval
        Least time [s] between two reports of :meth:`Task.advance`.

    Yields
    ------
    Task or None
        The task, whose :meth:`~Task.advance` reports progress; ``None`` when no listener is
        registered (report nothing then, e.g. pass no solver callback). The listeners hear
        ``task_finished`` with the last ``done`` when the block ends, also when it raises.

    Raises
    ------
    ValueError
        If ``total`` is negative or ``interval`` is negative.
    """
    if total is not None and total < 0:
        raise ValueError(f"task {label!r}: total must be >= 0 or None, found {total!r}")
    if interval < 0:
        raise ValueError(f"task {label!r}: interval must be >= 0 s, found {interval!r}")
    if not _LISTENERS:  # the common case costs one list check
        yield None
        return
    reported = Task(next(_KEYS), str(label), total, interval)
    _emit("task_started", reported.key, reported.label, total)
    try:
        yield reported
    finally:
        _emit("task_finished", reported.key, reported.done)
