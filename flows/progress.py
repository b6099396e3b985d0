"""Progress of a flow run on the console: which node runs, a bar with ETA per image set, and
one per solver run.

The runtime (:mod:`.runtime`) reports what happens through :func:`notify`; whoever wants to
show it (the command line) registers a listener with :func:`listening`. Without a listener
nothing happens, so library users and tests see no change. Listeners are called from the
flow's threads, including the store's region-writing threads and dask's worker threads.

Work inside a node (a solver run on one image set) is reported by the node through
:mod:`spectralize.engine.progress`, which knows nothing of flows; while a node runs,
:func:`node_tasks` passes those tasks on to the listeners here as ``task_*`` calls.

Two displays:

- :class:`RichProgress` (a terminal): one line per running node with its stage and elapsed
  time, for a resumable write a bar of the regions (image sets) written, with the ETA, and
  under it a bar per running solver (iterations of the limit; its ETA is an upper bound,
  a solver that converges stops earlier); a finished node leaves one line.
- :class:`PlainProgress` (a pipe or a file): the same as plain lines, with the ETA in words;
  a solver run gets a line at most every 10 s (none when it takes less) and one when it ends.

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
from typing import IO, Any, Protocol

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
]


class Listener(Protocol):
    """What a display is told. Every method is called from the flow's threads."""

    def step_started(self, index: int, total: int, node: str) -> None: ...

    def stage(self, node: str, text: str) -> None: ...

    def regions(self, node: str, group: str, done: int, total: int, resumed: int) -> None: ...

    def step_finished(self, node: str, status: str, seconds: float) -> None: ...

    # Optional (a listener without them is not told): a task inside the running node, such
    # as a solver run (see :func:`node_tasks`); ``key`` tells concurrent tasks apart.

    def task_started(self, node: str, key: int, label: str, total: int | None) -> None: ...

    def task_advanced(self, node: str, key: int, done: int) -> None: ...

    def task_finished(self, node: str, key: int, done: int) -> None: ...


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

    def task_advanced(self, key: int, done: int) -> None:
        notify("task_advanced", self.node, key, done)

    def task_finished(self, key: int, done: int) -> None:
        notify("task_finished", self.node, key, done)


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
# are the two messages it sends (tests/flows/test_progress.py checks them against a write).
_REGION = re.compile(r"region \d+ of (?P<total>\d+) written \((?P<done>\d+)/\d+ done\)")
_RESUMING = re.compile(r"(?P<done>\d+)/(?P<total>\d+) region\(s\) of \S+ already written, resuming")


def store_message(node: str, group: str, message: str, resumed: dict[str, int]) -> None:
    """Turn one of the store's region messages into a :meth:`Listener.regions` call.

    ``resumed`` (one dict per write) remembers how many regions an earlier run had written,
    so that the ETA counts only the regions written now.
    """
    found = _RESUMING.search(message)
    if found:
        resumed["done"] = int(found["done"])
        notify("regions", node, group, int(found["done"]), int(found["total"]), resumed["done"])
        return
    found = _REGION.search(message)
    if found:
        done, total = int(found["done"]), int(found["total"])
        notify("regions", node, group, done, total, resumed.get("done", 0))


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


class PlainProgress:
    """Progress as plain lines (for logs and pipes): node starts and stages, every region
    written with the time left, a running solver's iteration at most every ``task_interval``
    seconds (and its end, if it printed), node ends."""

    def __init__(self, stream: IO[str] | None = None, clock=time.monotonic, task_interval: float = 10.0):
        self.stream = stream
        self.clock = clock
        self.task_interval = task_interval
        self._started: dict[tuple[str, str], tuple[float, int]] = {}
        # (node, key) -> [label, total, start time, time of the last line or None]
        self._tasks: dict[tuple[str, int], list[Any]] = {}
        self._lock = threading.Lock()

    def _print(self, text: str) -> None:
        print(text, file=self.stream or sys.stderr, flush=True)

    def step_started(self, index: int, total: int, node: str) -> None:
        self._print(f"[{index}/{total}] {node}")

    def stage(self, node: str, text: str) -> None:
        self._print(f"    {node}: {text}")

    def regions(self, node: str, group: str, done: int, total: int, resumed: int) -> None:
        # the rate is measured from the first message on (the time before it, spent on the
        # first region, is not known here)
        with self._lock:
            now = self.clock()
            start, first = self._started.setdefault((node, group), (now, done))
        line = f"    {node}: {group}: {done}/{total} image set(s) written"
        if resumed and done == resumed:
            self._print(f"{line} by an earlier run, resuming")
            return
        written, left = done - first, total - done
        if written > 0 and left > 0 and now > start:
            line += f", about {format_seconds((now - start) / written * left)} left"
        self._print(line)

    def task_started(self, node: str, key: int, label: str, total: int | None) -> None:
        with self._lock:
            self._tasks[(node, key)] = [label, total, self.clock(), None]

    def task_advanced(self, node: str, key: int, done: int) -> None:
        # a line only after task_interval without one (since the start), so a solver run
        # shorter than that prints nothing and many in parallel do not flood the log
        with self._lock:
            state = self._tasks.get((node, key))
            if state is None:
                return
            label, total, start, last = state
            now = self.clock()
            if now - (start if last is None else last) < self.task_interval:
                return
            state[3] = now
        line = f"    {node}: {label}: iteration {done}"
        if total:
            line += f"/{total}"
            if 0 < done < total and now > start:
                left = (now - start) / done * (total - done)
                line += f", at most about {format_seconds(left)} left"
        self._print(line)

    def task_finished(self, node: str, key: int, done: int) -> None:
        with self._lock:
            state = self._tasks.pop((node, key), None)
            now = self.clock()
        if state is not None and state[3] is not None:  # it printed: say that it ended
            self._print(
                f"    {node}: {state[0]}: done after {done} iteration(s) in "
                f"{format_seconds(now - state[2])}"
            )

    def step_finished(self, node: str, status: str, seconds: float) -> None:
        with self._lock:
            for key in [k for k in self._started if k[0] == node]:
                del self._started[key]
            for key in [k for k in self._tasks if k[0] == node]:
                del self._tasks[key]
        if status == "ran":
            self._print(f"    {node}: done in {format_seconds(seconds)}")
        else:
            self._print(f"    {node}: up to date")


class RichProgress:
    """A live display on a terminal (rich): the running node with its stage and elapsed
    time, per resumable write a bar of image sets with the ETA, and per running solver a bar
    of its iterations with the ETA at the iteration limit (``ETA <= ...``)."""

    def __init__(self, console: Any = None):
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            ProgressColumn,
            SpinnerColumn,
            TextColumn,
            TimeElapsedColumn,
        )
        from rich.text import Text

        class WithTotal(ProgressColumn):
            """A column shown only for tasks that have a total (the region bars)."""

            def __init__(self, column: ProgressColumn):
                super().__init__()
                self.column = column

            def render(self, task):  # noqa: ANN001 (rich's Task)
                return self.column.render(task) if task.total is not None else Text("")

        class Eta(ProgressColumn):
            max_refresh = 0.5

            def render(self, task):  # noqa: ANN001
                if task.total is None or task.finished:
                    return Text("")
                remaining = task.time_remaining
                # a solver's total is its iteration limit: it may stop earlier
                eta = "ETA <=" if task.fields.get("at_most") else "ETA"
                return Text(
                    f"{eta} {format_seconds(remaining)}" if remaining is not None else f"{eta} …"
                )

        self.console = console or Console(stderr=True)
        self.progress = Progress(
            SpinnerColumn(),
            TextColumn("{task.description}"),
            WithTotal(BarColumn()),
            WithTotal(MofNCompleteColumn()),
            TimeElapsedColumn(),
            Eta(),
            console=self.console,
            transient=True,
        )
        self._steps: dict[str, Any] = {}  # node -> task id
        self._labels: dict[str, str] = {}
        self._bars: dict[tuple[str, str], Any] = {}
        self._tasks: dict[tuple[str, int], Any] = {}  # (node, key) -> task id
        self._lock = threading.Lock()

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

    def regions(self, node: str, group: str, done: int, total: int, resumed: int) -> None:
        with self._lock:
            key = (node, group)
            if key not in self._bars:
                # the bar's speed (and so its ETA) counts only regions written by this run
                self._bars[key] = self.progress.add_task(
                    f"    {group}: image sets", total=total, completed=resumed
                )
            self.progress.update(self._bars[key], completed=done, total=total)

    def task_started(self, node: str, key: int, label: str, total: int | None) -> None:
        with self._lock:
            self._tasks[(node, key)] = self.progress.add_task(
                f"    {label}: iterations" if total else f"    {label}", total=total, at_most=True
            )

    def task_advanced(self, node: str, key: int, done: int) -> None:
        with self._lock:
            if (node, key) in self._tasks:
                self.progress.update(self._tasks[(node, key)], completed=done)

    def task_finished(self, node: str, key: int, done: int) -> None:
        with self._lock:
            if (node, key) in self._tasks:
                self.progress.remove_task(self._tasks.pop((node, key)))

    def step_finished(self, node: str, status: str, seconds: float) -> None:
        with self._lock:
            for key in [k for k in self._tasks if k[0] == node]:
                self.progress.remove_task(self._tasks.pop(key))
            for key in [k for k in self._bars if k[0] == node]:
                self.progress.remove_task(self._bars.pop(key))
            if node in self._steps:
                self.progress.remove_task(self._steps.pop(node))
            label = self._labels.pop(node, node)
        done = f"done in {format_seconds(seconds)}" if status == "ran" else "up to date"
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
