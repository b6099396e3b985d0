"""Progress of a flow run on the console: which node runs, a bar with ETA per image set, and
one per solver run; every ETA measured, never read off an iteration limit.

The runtime (:mod:`.runtime`) reports what happens through :func:`notify`; whoever wants to
show it (the command line) registers a listener with :func:`listening`. Without a listener
nothing happens, so library users and tests see no change. Listeners are called from the
flow's threads, including the store's region-writing threads and dask's worker threads.

Work inside a node (a solver run on one image set) is reported by the node through
:mod:`spectralize.engine.progress`, which knows nothing of flows; while a node runs,
:func:`node_tasks` passes those tasks on to the listeners here as ``task_*`` calls, each
advance with the engine's :class:`~spectralize.engine.progress.Estimate` (share of the
solver's work done and seconds left, from its measured convergence rate and time per
iteration).

What a resumable write has written is counted along its dim (``2,390/5,280 images
written``): a region of the store's write can be one image set or a batch of many
(:func:`store_message`).

How the time left of a node's image sets is measured (:class:`SetClock`): while each region
is one solver run (one image set, solved whole), the work done is the sets written plus the
share done of every set in progress, a set being its solve and what follows until it is
written (both measured); the rate is that work over the time since the first set started;
the time left is the work left at that rate. So the bar moves as the work is done, not in
jumps when sets finish. Where a region takes several solver runs (a batch of sets solved one
after the other in one task, or a set's tiles), which is measured (more runs solved and not
written than can be in flight), the runs no longer tell how far a region is: the time left is
then the time so far per image done (per region, without a count along the dim) times the
images left, an image done once its run is solved where the runs say which images they
complete (a set's owned images, a tile's share of them), so a batch of sets counts set by set.
The bars count images done of the images in all wherever the store counts along the dim.

Two displays, with the same numbers:

- :class:`RichProgress` (a terminal): one line per running node with its stage and elapsed
  time, for a resumable write a bar of the work done with what is written
  (``2,390/5,280 images written``) and the ETA, and under it a bar per running solver
  (share of its work) with its ETA; a finished node leaves one line.
- :class:`PlainProgress` (a pipe or a file): the same as plain lines, with the ETA in words;
  a solver run gets a line at most every ``task_interval`` seconds (none when it takes less) and
  one when it ends.

:func:`quiet_prefect` keeps Prefect's INFO lines off the console (its API still gets them,
so the Prefect UI shows the run's logs); ``spectralize -v`` keeps them.

Nothing here imports Prefect, and rich only when a terminal shows a bar.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import sys
import threading
import time
from collections.abc import Iterator
from typing import IO, Any, NamedTuple, Protocol

__all__ = [
    "Listener",
    "PlainProgress",
    "RichProgress",
    "listening",
    "node_tasks",
    "notify",
    "store_message",
    "quiet_prefect",
    "console_progress",
    "format_seconds",
    "SetClock",
    "Counted",
]


class Listener(Protocol):
    """What a display is told. Every method is called from the flow's threads."""

    def step_started(self, index: int, total: int, node: str) -> None: ...

    def stage(self, node: str, text: str) -> None: ...

    def regions(
        self, node: str, group: str, done: int, total: int, resumed: int, counted: Counted | None = None
    ) -> None: ...

    def step_finished(self, node: str, status: str, seconds: float) -> None: ...

    # Optional (a listener without them is not told): a task inside the running node, such
    # as a solver run (see :func:`node_tasks`); ``key`` tells concurrent tasks apart.

    def task_started(self, node: str, key: int, label: str, total: int | None) -> None: ...

    def task_advanced(self, node: str, key: int, done: int, estimate: Any) -> None: ...

    def task_finished(self, node: str, key: int, done: int) -> None: ...

    # Optional: the run's images a task completes (its owned images; a tile: their share),
    # told right after its ``task_started`` where the node reports it.

    def task_images(self, node: str, key: int, images: float) -> None: ...

    # Optional: a node's peak resident set in GB (flows/memory.py; None where it cannot be
    # measured), told just before its ``step_finished``.

    def step_peak(self, node: str, peak_gb: float | None) -> None: ...


class Counted(NamedTuple):
    """What a resumable write has written, counted along its dim (its regions can be batches).

    Attributes
    ----------
    done, total
        Indices along the dim written (earlier runs' included) and in all (``2390``, ``5280``).
    resumed
        Of ``done``, those an earlier run wrote.
    unit
        The dim (``"image"``).
    """

    done: int
    total: int
    resumed: int
    unit: str

    def text(self) -> str:
        """``2,390/5,280 images``."""
        plural = self.unit if self.unit.endswith("s") else f"{self.unit}s"
        return f"{self.done:,}/{self.total:,} {self.unit if self.total == 1 else plural}"


def _written_text(done: int, total: int, counted: Counted | None) -> str:
    """``2,390/5,280 images`` (``3/9 region(s)`` from a store that does not count along its dim)."""
    return counted.text() if counted is not None else f"{done}/{total} region(s)"


def _peak_text(peak_gb: float | None) -> str:
    """``, peak 1.23 GB resident`` (nothing where it was not measured)."""
    return "" if peak_gb is None else f", peak {peak_gb:.2f} GB resident"


_DISPLAYS: list = []  # the one Listeners registry, made on first use
_LOCK = threading.Lock()


def _displays():
    """The displays' registry (:class:`spectralize.engine.progress.Listeners`); imported on
    first use, so ``spectralize --help`` stays light."""
    with _LOCK:
        if not _DISPLAYS:
            from spectralize.engine.progress import Listeners

            _DISPLAYS.append(Listeners("progress display"))
    return _DISPLAYS[0]


def listening(listener: Listener):
    """Send the runtime's progress to ``listener`` for the duration of the block."""
    return _displays().listening(listener)


def notify(method: str, *args: Any) -> None:
    """Call ``method(*args)`` of every listener that has it. A failing display never fails the
    run: its error is printed once and the display is dropped."""
    _displays().emit(method, *args)


class _NodeTasks:
    """A :class:`spectralize.engine.progress.TaskListener` that passes the tasks of ``node``
    on to the listeners here."""

    def __init__(self, node: str):
        self.node = node

    def task_started(self, key: int, label: str, total: int | None) -> None:
        notify("task_started", self.node, key, label, total)

    def task_advanced(self, key: int, done: int, estimate: Any) -> None:
        notify("task_advanced", self.node, key, done, estimate)

    def task_finished(self, key: int, done: int) -> None:
        notify("task_finished", self.node, key, done)

    def task_images(self, key: int, images: float) -> None:
        notify("task_images", self.node, key, images)


@contextlib.contextmanager
def node_tasks(node: str) -> Iterator[None]:
    """While ``node`` runs (the block), pass the tasks it reports through
    :mod:`spectralize.engine.progress` (its solver runs) on to the listeners here.

    Without a listener here nothing is registered there, so the node reports nothing and
    passes its solvers no callback. The engine's registry is per process, not per node: two
    nodes running at once in one process would each see the other's tasks too.
    """
    anyone = bool(_displays())
    if not anyone:
        yield
        return
    from spectralize.engine import progress as engine_progress

    with engine_progress.listening(_NodeTasks(node)):
        yield


# The run store's resumable writes report in words (RunStore.write(progress=...)); these
# are the two messages it sends (tests/flows/test_progress.py checks them against a write),
# each with the count along the dim (optional here: an older store's messages lack it).
_ALONG = r"(?P<counted>\d+)/(?P<size>\d+) along (?P<dim>\S+)"
_REGION = re.compile(rf"region \d+ of (?P<total>\d+) written \((?P<done>\d+)/\d+ done(?:, {_ALONG})?\)")
_RESUMING = re.compile(
    rf"(?P<done>\d+)/(?P<total>\d+) region\(s\) of \S+ already written(?: \({_ALONG}\))?, resuming"
)


def store_message(node: str, group: str, message: str, resumed: dict[str, int]) -> None:
    """Turn one of the store's region messages into a :meth:`Listener.regions` call.

    ``resumed`` (one dict per write) remembers how many regions (and indices along the dim)
    an earlier run had written, so that the ETA counts only the work done now.
    """
    found = _RESUMING.search(message) or _REGION.search(message)
    if found is None:
        return
    done, total = int(found["done"]), int(found["total"])
    if found.re is _RESUMING:
        resumed["done"] = done
        resumed["counted"] = int(found["counted"] or 0)
    counted = None
    if found["counted"] is not None:
        counted = Counted(
            int(found["counted"]), int(found["size"]), resumed.get("counted", 0), found["dim"]
        )
    notify("regions", node, group, done, total, resumed.get("done", 0), counted)


def format_seconds(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``2 h 07 min``."""
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes, secs = divmod(int(round(seconds)), 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


class SetClock:
    r"""The work done on a node's image sets and the time left, measured (see the module
    docstring). Not thread-safe: the displays call it under their lock.

    While each region is one solver run, a set's work is its solve and what follows until it
    is written (its confidence, the write); the time after the solve is measured on the sets
    written so far (solved sets are matched to written regions in order), so a solved set
    waiting for its write is not counted as done.

    A region of several solver runs (a batch of sets, a set's tiles) shows as more runs solved
    and not written than one-run regions can leave (one per region in flight, at most the
    runs seen running at once, plus one); from then on the node's time left is
    :math:`t \, (N - n) / (n - n_0)`: the time :math:`t` since its first run started, per
    index :math:`n - n_0` written along the dim since then (images; regions without a
    count), times the :math:`N - n` left.

    Where the runs say which of the run's images they complete (``task_images``: a set's
    owned images, a tile's share of them), :math:`n - n_0` counts the images solved as well
    as written (the larger of the two: a region copied without a solve, the seed set, is
    written only) plus the running runs' shares of theirs, so the count and the time left
    move set by set, not batch by batch. The work done (:meth:`estimate`) is counted in
    indices along the dim (images) wherever the store counts them, in regions otherwise.
    """

    def __init__(self) -> None:
        self._start: dict[str, float] = {}  # node -> when its first set started
        self._first: dict[str, float] = {}  # node -> when its first region was written
        # (node, key) -> [start, share of the solve done by its estimate, or None before one]
        self._running: dict[tuple[str, int], list[Any]] = {}
        self._took: dict[str, list[float]] = {}  # node -> seconds each finished solve took
        self._after: dict[str, list[float]] = {}  # node -> seconds from solved to written
        # node -> (time solved, seconds it took, images or None) of each set solved, not yet
        # written, in order
        self._solved: dict[str, list[tuple[float, float, float | None]]] = {}
        self._images: dict[tuple[str, int], float] = {}  # (node, key) -> images it completes
        self._finished: dict[str, float] = {}  # node -> images of the runs finished
        self._regions: dict[str, tuple[int, int, int]] = {}  # node -> (done, total, resumed)
        # node -> [done, total, base]: indices along the dim, base counted before the measure
        self._counted: dict[str, list[int]] = {}
        self._most: dict[str, int] = {}  # node -> most solver runs seen running at once
        self._batched: set[str] = set()  # nodes whose regions take several solver runs

    def task_started(self, node: str, key: int, now: float) -> None:
        if node not in self._start:  # sets written before the first solve are not its work
            self._start[node] = now
            if node in self._regions:
                done, total, _ = self._regions[node]
                self._regions[node] = (done, total, done)
            if node in self._counted:
                self._counted[node][2] = self._counted[node][0]
        self._running[(node, key)] = [now, None]
        running = sum(1 for n, _ in self._running if n == node)
        self._most[node] = max(self._most.get(node, 0), running)

    def task_images(self, node: str, key: int, images: float) -> None:
        if (node, key) in self._running:
            self._images[(node, key)] = float(images)

    def task_advanced(self, node: str, key: int, estimate: Any) -> None:
        if (node, key) in self._running and estimate is not None:
            self._running[(node, key)][1] = min(1.0, max(0.0, float(estimate.fraction)))

    def task_finished(self, node: str, key: int, now: float) -> None:
        state = self._running.pop((node, key), None)
        images = self._images.pop((node, key), None)
        if state is not None:
            self._took.setdefault(node, []).append(now - state[0])
            self._solved.setdefault(node, []).append((now, now - state[0], images))
            if images is not None:
                self._finished[node] = self._finished.get(node, 0.0) + images

    @staticmethod
    def _mean(values: list[float] | None) -> float | None:
        return sum(values) / len(values) if values else None

    def _share(self, node: str, state: list[Any], now: float) -> float:
        """A running set's share of its work: its solve's share (its solver's estimate, else,
        during set-up and first iterations, its time over the mean solve) scaled by the solve's
        part of the set's time (the rest is measured after the solves)."""
        spent = now - state[0]
        took = self._mean(self._took.get(node))
        if state[1] is not None and state[1] > 0:
            solve = spent / state[1]  # the solve's projected duration
        elif took:
            solve = max(took, spent / 0.9)
        else:
            return 0.0
        after = self._mean(self._after.get(node)) or 0.0
        return min(0.99, spent / (solve + after))

    def _waiting(self, node: str, now: float) -> list[tuple[float, float | None]]:
        """The share done of each set solved but not yet written, with its images."""
        after = self._mean(self._after.get(node)) or 0.0
        return [
            (min(0.99, (took + now - solved) / (took + after)) if took + after > 0 else 1.0, images)
            for solved, took, images in self._solved.get(node, ())
        ]

    def _running_shares(self, node: str, now: float) -> list[tuple[float, float | None]]:
        """The share done of each running set (:meth:`_share`), with its images."""
        return [
            (self._share(node, state, now), self._images.get(key))
            for key, state in self._running.items()
            if key[0] == node
        ]

    def regions(
        self, node: str, done: int, total: int, resumed: int, now: float, counted: Counted | None = None
    ) -> None:
        previous, _, base = self._regions.get(node, (resumed, total, resumed))
        fresh = node not in self._start and node not in self._first
        if fresh:
            # measured from here (a node without solver tasks) or from its first solve
            base = done
            self._first[node] = now
        self._regions[node] = (done, total, max(base, resumed))
        if counted is not None:
            counted_base = self._counted.get(node, [0, 0, counted.resumed])[2]
            if fresh:
                counted_base = counted.done
            self._counted[node] = [counted.done, counted.total, max(counted_base, counted.resumed)]
        waiting = self._solved.get(node, [])
        for _ in range(max(0, done - previous)):
            if waiting:
                solved, _, _ = waiting.pop(0)
                self._after.setdefault(node, []).append(now - solved)
        # one-run regions leave at most one run solved and unwritten per region in flight
        if len(waiting) > self._most.get(node, 0) + 1:
            self._batched.add(node)

    def _per_written(self, node: str, now: float) -> tuple[float, float | None]:
        """A node of several runs per region: the time so far per index done along the dim
        (per region without a count) times the indices left.

        Without the runs' images, regions in flight count nothing until written, so with
        ``c`` computed at a time the estimate right after a region is at most
        ``(k + c - 1) / k`` times the time left, ``k`` written so far (never less). With
        them, an image counts once its run is solved (and a running run's share of its images
        counts), so the count moves run by run."""
        done, total, resumed = self._regions[node]
        written, size, base = self._counted.get(node, (done, total, resumed))
        elapsed = now - self._start.get(node, self._first.get(node, now))
        work = float(written - base)
        running = [
            (state[1] or 0.0, self._images[key])
            for key, state in self._running.items()
            if key[0] == node and key in self._images
        ]
        if node in self._finished or running:
            solved = max(work, self._finished.get(node, 0.0))
            work = min(float(size - base), solved + sum(share * images for share, images in running))
        if work <= 0 or elapsed <= 0:
            return float(base + max(work, 0.0)), None
        return base + work, elapsed / work * (size - base - work)

    def _in_images(self, node: str, now: float) -> float | None:
        """A node of one run per region: the images done (written, plus each solved or running
        set's share of its images: its own count where told, else the mean images per
        region), or None where the store does not count along the dim."""
        if node not in self._counted:
            return None
        done, total, _ = self._regions[node]
        written, size, _ = self._counted[node]
        mean = size / total if total else 0.0
        partial = [*self._waiting(node, now), *self._running_shares(node, now)]
        return min(float(size), written + sum(s * (mean if i is None else i) for s, i in partial))

    def size(self, node: str) -> int | None:
        """What :meth:`estimate` counts to: the indices along the dim (images) where the store
        counts them, else the regions; None before the node's first region message."""
        if node in self._counted:
            return self._counted[node][1]
        return self._regions[node][1] if node in self._regions else None

    def estimate(self, node: str, now: float) -> tuple[float, float | None]:
        """``(work done, seconds left)``: the work done in indices along the dim (images, see
        :meth:`size`), counting the share of sets in progress; the seconds left are ``None``
        until some work is measured."""
        if node not in self._regions:
            return 0.0, None
        done, total, resumed = self._regions[node]
        if node in self._batched:
            return self._per_written(node, now)
        partial = [share for share, _ in (*self._waiting(node, now), *self._running_shares(node, now))]
        work = min(float(total - resumed), done - resumed + sum(partial))
        images = self._in_images(node, now)
        sets = resumed + max(work, 0.0)
        elapsed = now - self._start.get(node, self._first.get(node, now))
        if work <= 0 or elapsed <= 0:
            return (sets if images is None else images), None
        by_rate = elapsed / work * (total - resumed - work)
        whole = self._makespan(node, now)
        left = (by_rate * whole) ** 0.5 if whole > by_rate else by_rate
        return (sets if images is None else images), left

    def _makespan(self, node: str, now: float) -> float:
        """The time left if the sets not yet started run whole, a mean set's time each, on
        as many workers as ran at once, after the running sets' remaining time.

        The rate alone (work per second so far) assumes the last sets share the workers as
        the first did; but the last set runs on one worker however many are idle, so near
        the end the rate under-counts by up to a whole set's time.
        """
        took = self._mean(self._took.get(node))
        after = self._mean(self._after.get(node)) or 0.0
        free, solves = [], []  # per running set: when its worker is free, its whole solve
        for (n, _), (start, fraction) in self._running.items():
            if n == node:
                spent = now - start
                solve = spent / fraction if fraction else max(took or 0.0, spent)
                free.append(solve - spent)
                solves.append(solve)
        waiting = [max(0.0, after - (now - solved)) for solved, _, _ in self._solved.get(node, ())]
        done, total, _ = self._regions[node]
        unstarted = total - done - len(waiting) - len(free)
        whole = took or max(solves, default=0.0)  # a set's solve
        if unstarted > 0 and whole > 0:
            free += [0.0] * max(0, self._most.get(node, 1) - len(free))
            for _ in range(unstarted):
                free.sort()
                free[0] += whole
        return max([*waiting, *(f + after for f in free), 0.0])

    def forget(self, node: str) -> None:
        for table in (
            self._start,
            self._first,
            self._took,
            self._after,
            self._solved,
            self._regions,
            self._counted,
            self._most,
            self._finished,
        ):
            table.pop(node, None)
        self._batched.discard(node)
        for key in [k for k in self._running if k[0] == node]:
            del self._running[key]
        for key in [k for k in self._images if k[0] == node]:
            del self._images[key]


def _solver_text(done: int, estimate: Any) -> str:
    """``iteration 12 (40 % of its work), about 8 s left`` (without an estimate: the count)."""
    if estimate is None:
        return f"iteration {done}"
    return (
        f"iteration {done} ({100 * estimate.fraction:.0f} % of its work), "
        f"about {format_seconds(estimate.seconds_left)} left"
    )


class PlainProgress:
    """Progress as plain lines (for logs and pipes): node starts and stages, every region
    written with the time left (:class:`SetClock`), a running solver's iteration with its
    share done and time left at most every ``task_interval`` seconds (and its end, if it
    printed), node ends."""

    def __init__(self, stream: IO[str] | None = None, clock=time.monotonic, task_interval: float = 10.0):
        self.stream = stream
        self.clock = clock
        self.task_interval = task_interval
        self.sets = SetClock()
        # (node, key) -> [label, start time, time of the last line or None]
        self._tasks: dict[tuple[str, int], list[Any]] = {}
        self._peaks: dict[str, float | None] = {}  # node -> its peak resident set [GB]
        self._lock = threading.Lock()

    def step_peak(self, node: str, peak_gb: float | None) -> None:
        with self._lock:
            self._peaks[node] = peak_gb

    def _print(self, text: str) -> None:
        print(text, file=self.stream or sys.stderr, flush=True)

    def step_started(self, index: int, total: int, node: str) -> None:
        self._print(f"[{index}/{total}] {node}")

    def stage(self, node: str, text: str) -> None:
        self._print(f"    {node}: {text}")

    def regions(
        self, node: str, group: str, done: int, total: int, resumed: int, counted: Counted | None = None
    ) -> None:
        with self._lock:
            now = self.clock()
            self.sets.regions(node, done, total, resumed, now, counted)
            _, left = self.sets.estimate(node, now)
        line = f"    {node}: {group}: {_written_text(done, total, counted)} written"
        if resumed and done == resumed:
            regions = "" if counted is None else f" ({done}/{total} region(s))"
            self._print(f"{line} by an earlier run{regions}, resuming")
            return
        if left is not None and done < total:
            line += f", about {format_seconds(left)} left"
        self._print(line)

    def task_started(self, node: str, key: int, label: str, total: int | None) -> None:
        with self._lock:
            now = self.clock()
            self.sets.task_started(node, key, now)
            self._tasks[(node, key)] = [label, now, None]

    def task_images(self, node: str, key: int, images: float) -> None:
        with self._lock:
            self.sets.task_images(node, key, images)

    def task_advanced(self, node: str, key: int, done: int, estimate: Any = None) -> None:
        # a line only after task_interval without one (since the start), so a solver run
        # shorter than that prints nothing and many in parallel do not flood the log
        with self._lock:
            self.sets.task_advanced(node, key, estimate)
            state = self._tasks.get((node, key))
            if state is None:
                return
            label, start, last = state
            now = self.clock()
            if now - (start if last is None else last) < self.task_interval:
                return
            state[2] = now
        self._print(f"    {node}: {label}: {_solver_text(done, estimate)}")

    def task_finished(self, node: str, key: int, done: int) -> None:
        with self._lock:
            now = self.clock()
            self.sets.task_finished(node, key, now)
            state = self._tasks.pop((node, key), None)
        if state is not None and state[2] is not None:  # it printed: say that it ended
            self._print(
                f"    {node}: {state[0]}: done after {done} iteration(s) in "
                f"{format_seconds(now - state[1])}"
            )

    def step_finished(self, node: str, status: str, seconds: float) -> None:
        with self._lock:
            self.sets.forget(node)
            for key in [k for k in self._tasks if k[0] == node]:
                del self._tasks[key]
            peak = self._peaks.pop(node, None)
        if status == "ran":
            self._print(f"    {node}: done in {format_seconds(seconds)}{_peak_text(peak)}")
        else:
            self._print(f"    {node}: up to date")


class RichProgress:
    """A live display on a terminal (rich): the running node with its stage and elapsed
    time, per resumable write a bar of the image sets' work done (:class:`SetClock`) with
    its ETA, and per running solver a bar of its share of work done with its ETA (from its
    measured convergence rate and time per iteration)."""

    def __init__(self, console: Any = None, clock=time.monotonic):
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            Progress,
            ProgressColumn,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
        )
        from rich.text import Text

        class WithTotal(ProgressColumn):
            """A column shown only for tasks that have a total (the bars)."""

            def __init__(self, column: ProgressColumn):
                super().__init__()
                self.column = column

            def render(self, task):  # noqa: ANN001 (rich's Task)
                return self.column.render(task) if task.total is not None else Text("")

        class Count(ProgressColumn):
            """``3/9`` image sets written, or a solver's ``iteration 12``."""

            def render(self, task):  # noqa: ANN001
                return Text(task.fields.get("count", ""))

        class Eta(ProgressColumn):
            """The measured time left (the ``eta`` field), ``ETA …`` until it is measured."""

            max_refresh = 0.5

            def render(self, task):  # noqa: ANN001
                if task.total is None or task.finished:
                    return Text("")
                left = task.fields.get("eta")
                return Text(f"ETA {format_seconds(left)}" if left is not None else "ETA …")

        self.clock = clock
        self.console = console or Console(stderr=True)
        self.progress = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            WithTotal(BarColumn()),
            Count(),
            TimeElapsedColumn(),
            Eta(),
            console=self.console,
            transient=True,
        )
        self.sets = SetClock()
        self._steps: dict[str, Any] = {}  # node -> task id
        self._labels: dict[str, str] = {}
        self._bars: dict[tuple[str, str], Any] = {}
        self._tasks: dict[tuple[str, int], Any] = {}  # (node, key) -> task id
        self._peaks: dict[str, float | None] = {}  # node -> its peak resident set [GB]
        self._lock = threading.Lock()

    def step_peak(self, node: str, peak_gb: float | None) -> None:
        with self._lock:
            self._peaks[node] = peak_gb

    def __enter__(self) -> RichProgress:
        self.progress.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.progress.stop()

    def step_started(self, index: int, total: int, node: str) -> None:
        with self._lock:
            self._labels[node] = f"[{index}/{total}] {node}"
            self._steps[node] = self.progress.add_task(self._labels[node], total=None)

    def stage(self, node: str, text: str) -> None:
        with self._lock:
            if node in self._steps:
                self.progress.update(self._steps[node], description=f"{self._labels[node]}: {text}")

    def _update_sets(self, node: str) -> None:
        """Move the node's image-set bars to the work done (images where the store counts
        them), with the time left."""
        work, left = self.sets.estimate(node, self.clock())
        for (owner, _), bar in self._bars.items():
            if owner == node:
                self.progress.update(bar, completed=work, total=self.sets.size(node), eta=left)

    def regions(
        self, node: str, group: str, done: int, total: int, resumed: int, counted: Counted | None = None
    ) -> None:
        with self._lock:
            self.sets.regions(node, done, total, resumed, self.clock(), counted)
            key = (node, group)
            size, before = (total, resumed) if counted is None else (counted.total, counted.resumed)
            if key not in self._bars:
                self._bars[key] = self.progress.add_task(f"    {group}", total=size, completed=before)
            count = f"{_written_text(done, total, counted)} written"
            self.progress.update(self._bars[key], count=count)
            self._update_sets(node)

    def task_started(self, node: str, key: int, label: str, total: int | None) -> None:
        with self._lock:
            self.sets.task_started(node, key, self.clock())
            self._tasks[(node, key)] = self.progress.add_task(
                f"    {label}", total=1.0 if total else None, count=""
            )

    def task_images(self, node: str, key: int, images: float) -> None:
        with self._lock:
            self.sets.task_images(node, key, images)
            self._update_sets(node)

    def task_advanced(self, node: str, key: int, done: int, estimate: Any = None) -> None:
        with self._lock:
            self.sets.task_advanced(node, key, estimate)
            if (node, key) in self._tasks:
                self.progress.update(
                    self._tasks[(node, key)],
                    completed=estimate.fraction if estimate is not None else 0.0,
                    eta=estimate.seconds_left if estimate is not None else None,
                    count=f"iteration {done}",
                )
            self._update_sets(node)

    def task_finished(self, node: str, key: int, done: int) -> None:
        with self._lock:
            self.sets.task_finished(node, key, self.clock())
            if (node, key) in self._tasks:
                self.progress.remove_task(self._tasks.pop((node, key)))
            self._update_sets(node)

    def step_finished(self, node: str, status: str, seconds: float) -> None:
        with self._lock:
            self.sets.forget(node)
            for key in [k for k in self._tasks if k[0] == node]:
                self.progress.remove_task(self._tasks.pop(key))
            for key in [k for k in self._bars if k[0] == node]:
                self.progress.remove_task(self._bars.pop(key))
            if node in self._steps:
                self.progress.remove_task(self._steps.pop(node))
            label = self._labels.pop(node, node)
            peak = self._peaks.pop(node, None)
        done = (
            f"done in {format_seconds(seconds)}{_peak_text(peak)}" if status == "ran" else "up to date"
        )
        self.progress.console.print(f"{label}: {done}", highlight=False)


# Prefect's console handler (logging.yml: handlers.console), overridable by environment
_CONSOLE_LEVEL = "PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL"
_USER_ENVIRONMENT = frozenset(k for k in os.environ if k == _CONSOLE_LEVEL)  # set by the user


def quiet_prefect(verbose: bool) -> None:
    """Keep Prefect's INFO lines off the console unless ``verbose``; warnings still show.

    Before Prefect is imported this sets its console handler's level through the
    environment (a level the user set there wins); when Prefect is already imported (a
    second command in one process), the level of its console handlers is set directly.
    Prefect's API still receives every log line (the Prefect UI shows them).
    """
    if verbose:
        os.environ[_CONSOLE_LEVEL] = "INFO"
    elif _CONSOLE_LEVEL not in _USER_ENVIRONMENT:
        os.environ[_CONSOLE_LEVEL] = "WARNING"
    if not verbose:
        import prefect.main  # noqa: F401  (sets up Prefect's logging, so its handlers exist)
    if "prefect" not in sys.modules:
        return
    wanted = logging.getLevelName(os.environ[_CONSOLE_LEVEL])
    for name in (None, "uvicorn", "fastapi"):
        for handler in logging.getLogger(name).handlers:
            if type(handler).__name__ == "PrefectConsoleHandler":
                handler.setLevel(wanted)
                for old in [f for f in handler.filters if isinstance(f, _RunFailures)]:
                    handler.removeFilter(old)
                if not verbose:
                    handler.addFilter(_RunFailures())


class _RunFailures(logging.Filter):
    """Drop Prefect's own error lines about failed task and flow runs from the console.

    They repeat the exception with its traceback; the CLI prints the same error once, clearly,
    after the run (``--debug`` adds the traceback, ``-v`` brings Prefect's lines back).
    Warnings, such as a lost dask worker, still show.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        failed_run = record.name.startswith(("prefect.task_runs", "prefect.flow_runs"))
        return not (failed_run and record.levelno >= logging.ERROR)


@contextlib.contextmanager
def console_progress(verbose: bool = False, stream: IO[str] | None = None) -> Iterator[Listener | None]:
    """Show a flow run's progress on ``stream`` (stderr by default) for the block.

    A terminal gets :class:`RichProgress`, anything else :class:`PlainProgress`; with
    ``verbose`` Prefect's own log lines are shown instead (they say the same, and more).
    """
    quiet_prefect(verbose)
    if verbose:
        yield None
        return
    stream = stream or sys.stderr
    if stream.isatty():
        from rich.console import Console

        with RichProgress(Console(file=stream)) as display, listening(display):
            yield display
    else:
        display = PlainProgress(stream)
        with listening(display):
            yield display
