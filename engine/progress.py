"""Progress of long work inside a node (a solver run), for whoever shows it.

A node reports a long task with :func:`task`; a display registers a :class:`TaskListener`
with :func:`listening` (the flows do: :func:`spectralize.flows.progress.node_tasks` turns
the tasks into bars under the running node's line)::

    from spectralize.engine import progress

    with progress.task("images 4, 5, 6", total=max_iterations, tolerance=tolerance) as solving:
        callback = None if solving is None else counting_iterations(solving.advance, residual=True)
        result = reconstruct(..., callback=callback)

A task that completes some of the run's images says how many (``images=``: a set's owned
images, a tile's share of them), so a display can count the run's images done, not its tasks.

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

What a display is told of a task is an :class:`Estimate`: the share of its work done and
the seconds left, measured, never read off an iteration limit. A solver that reports its
residual (``advance(done, residual)``) and was given its ``tolerance`` is estimated from the
convergence rate it shows: with the relative residual ``r_k`` falling by a factor ``rho``
per iteration (the mean of the rates over all iterations so far and over their second half:
CG's fast start makes the first optimistic, a plateau the second pessimistic; measured from
:data:`MIN_ITERATIONS` on), ``log(r_k / tolerance) / -log(rho)`` iterations are left, plus
the ``fixed`` iterations that always follow (the ``S >= 0`` refinement); each costs the mean
time per iteration measured so far. A task without a tolerance counts ``total`` steps
exactly. The share done is in time, set-up included (:class:`Estimate`).

Standard library only (and the error hierarchy), so any node may import it.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the iterative solve of eq. 1).
"""

from __future__ import annotations

import contextlib
import itertools
import math
import sys
import threading
import time
from collections.abc import Iterator
from typing import NamedTuple, Protocol, TypeVar

from spectralize.schemas.errors import ParameterError, Problem

__all__ = [
    "Estimate",
    "Listeners",
    "TaskListener",
    "Task",
    "convergence_estimate",
    "listening",
    "listened",
    "task",
]

L = TypeVar("L")


class TaskListener(Protocol):
    """What a display of tasks is told. Every method is called from the task's thread.

    ``key`` tells concurrent tasks apart (two may have the same label).
    """

    def task_started(self, key: int, label: str, total: int | None) -> None: ...

    def task_advanced(self, key: int, done: int, estimate: Estimate | None) -> None: ...

    def task_finished(self, key: int, done: int) -> None: ...

    # Optional (a listener without it is not told): the run's images a task completes, told
    # right after ``task_started`` by a task reported with ``images`` (a set: its owned
    # images; a tile: their share in its core), so a display counts images, not tasks.

    def task_images(self, key: int, images: float) -> None: ...


class Estimate(NamedTuple):
    """How far a task is, measured.

    Attributes
    ----------
    fraction
        Share of the task's work done, 0 to 1, in time: the time since the task started
        (its set-up included) over that plus the time left. A bar of it moves at the rate
        the work is done.
    seconds_left
        Time left [s] at the measured rate.
    """

    fraction: float
    seconds_left: float


#: Iterations a solver's convergence rate is measured over before it is trusted (CG's first
#: iterations fall irregularly).
MIN_ITERATIONS = 20


def convergence_estimate(
    residuals: list[tuple[int, float]], tolerance: float, fixed: int = 0
) -> tuple[float, float] | None:
    """Iterations done and iterations left of a solver converging to ``tolerance``.

    Parameters
    ----------
    residuals
        ``(iteration, relative residual)`` after each iteration so far, in order.
    tolerance
        The relative residual the solver stops at.
    fixed
        Iterations that always follow convergence (a refinement of fixed length).

    Returns
    -------
    tuple of float or None
        ``(done, left)`` in iterations; ``None`` while the rate is not measurable yet (fewer
        than :data:`MIN_ITERATIONS` iterations, or no decrease).
    """
    if len(residuals) < 2 or residuals[-1][0] < MIN_ITERATIONS or tolerance <= 0:
        return None
    done, last = residuals[-1]
    if last <= tolerance:
        return float(done), float(fixed)
    # the rate over all iterations (CG's fast start makes it optimistic) and over the second
    # half (a plateau makes it pessimistic), averaged
    rates = []
    for since in (0, done // 2):
        index = next(i for i, (k, _) in enumerate(residuals) if k >= since)
        start, first = residuals[min(index, len(residuals) - 2)]
        if done > start and 0 < last < first:
            rates.append((math.log(first) - math.log(last)) / (done - start))
    if not rates:
        return None
    rate = sum(rates) / len(rates)  # per iteration
    return float(done), math.log(last / tolerance) / rate + fixed


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
    """One reported task; :meth:`advance` reports how far it is, with an :class:`Estimate`.

    Attributes
    ----------
    key
        Unique in this process.
    label
        What the task is (``"images 4, 5, 6"``).
    total
        Steps it takes: exactly (without ``tolerance``) or at most (a solver's iteration
        limit, with ``tolerance``); ``None`` if unknown.
    tolerance
        The relative residual a solver stops at (its convergence is then measured).
    fixed
        Steps that always follow convergence.
    images
        The run's images the task completes (a share of them for a tile), or ``None``.
    done
        The last value given to :meth:`advance`.
    interval
        Least time [s] between two reports of :meth:`advance` to the listeners.
    """

    __slots__ = (
        "key",
        "label",
        "total",
        "tolerance",
        "fixed",
        "images",
        "done",
        "interval",
        "_told",
        "_created",
        "_started",
        "_residuals",
    )

    def __init__(
        self,
        key: int,
        label: str,
        total: int | None,
        interval: float,
        tolerance: float | None = None,
        fixed: int = 0,
        images: float | None = None,
    ) -> None:
        self.key = key
        self.label = label
        self.total = total
        self.tolerance = tolerance
        self.fixed = int(fixed)
        self.images = images
        self.done = 0
        self.interval = interval
        self._told = -float("inf")
        self._created = time.monotonic()  # the set-up before the first step is work too
        self._started: tuple[float, int] | None = None  # time and count of the first advance
        self._residuals: list[tuple[int, float]] = []

    def advance(self, done: int, residual: float | None = None) -> None:
        """``done`` steps are done (a solver: with its relative ``residual``); the listeners
        hear of it, with the :meth:`estimate`, unless they did within ``interval``."""
        self.done = done
        now = time.monotonic()
        if self._started is None:
            self._started = (now, done)
        if residual is not None and math.isfinite(residual):
            self._residuals.append((int(done), float(residual)))
        if now - self._told >= self.interval:
            self._told = now
            _emit("task_advanced", self.key, done, self.estimate(now))

    def estimate(self, now: float | None = None) -> Estimate | None:
        """The share done and the seconds left, measured; ``None`` until measurable (the
        time per step needs two reports; a solver's rate needs two residuals)."""
        now = time.monotonic() if now is None else now
        if self._started is None:
            return None
        since, first = self._started
        if self.done <= first or now <= since:
            return None
        per_step = (now - since) / (self.done - first)
        if self.tolerance is not None:
            found = convergence_estimate(self._residuals, self.tolerance, self.fixed)
            if found is None:
                return None
            done, left = found
            if self.total is not None:
                left = min(left, max(0.0, self.total - done))
        elif self.total is not None:
            done, left = float(self.done), max(0.0, float(self.total - self.done))
        else:
            return None
        seconds_left = left * per_step
        spent = now - self._created
        return Estimate(spent / (spent + seconds_left) if seconds_left > 0 else 1.0, seconds_left)


def _refused(label: str, argument: str, expected: str, found: object) -> ParameterError:
    """The error of a :func:`task` argument out of range, naming the task and the argument."""
    return ParameterError(
        f"progress task {label!r} cannot be reported:",
        [Problem(f"task {label!r} {argument}", expected, repr(found))],
    )


@contextlib.contextmanager
def task(
    label: str,
    total: int | None = None,
    *,
    tolerance: float | None = None,
    fixed: int = 0,
    interval: float = 0.1,
    images: float | None = None,
) -> Iterator[Task | None]:
    """Report one long task (e.g. a solver run) to the listeners for the duration of the block.

    Parameters
    ----------
    label
        What the task is, for the display (``"images 4, 5, 6"``).
    total
        Steps it takes (exactly; with ``tolerance``: at most, a solver's iteration limit), or
        ``None`` if unknown.
    tolerance
        A solver's stopping residual: its progress is then estimated from the convergence
        rate it shows (:func:`convergence_estimate`), not from ``total``.
    fixed
        Steps that always follow convergence (a refinement of fixed length).
    interval
        Least time [s] between two reports of :meth:`Task.advance`.
    images
        The run's images the task completes (a set's owned images; a tile: those times its
        core's share of the image), told to the listeners that count images
        (``task_images``); ``None``: not told.

    Yields
    ------
    Task or None
        The task, whose :meth:`~Task.advance` reports progress; ``None`` when no listener is
        registered (report nothing then, e.g. pass no solver callback). The listeners hear
        ``task_finished`` with the last ``done`` when the block ends, also when it raises.

    Raises
    ------
    ParameterError
        If ``total``, ``interval`` or ``images`` is negative or ``images`` is not finite (a
        :class:`ValueError`).
    """
    if total is not None and total < 0:
        raise _refused(label, "total", "a step count >= 0, or None", total)
    if interval < 0:
        raise _refused(label, "interval", "seconds >= 0", interval)
    if images is not None and not (math.isfinite(images) and images >= 0):
        raise _refused(label, "images", "a finite image count >= 0, or None", images)
    if not _LISTENERS:  # the common case costs one list check
        yield None
        return
    reported = Task(next(_KEYS), str(label), total, interval, tolerance, fixed, images)
    _emit("task_started", reported.key, reported.label, total)
    if images is not None:
        _emit("task_images", reported.key, float(images))
    try:
        yield reported
    finally:
        _emit("task_finished", reported.key, reported.done)
