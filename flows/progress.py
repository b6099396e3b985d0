"""Progress of a flow run on the console: which node runs, and a bar with ETA per image set.

The runtime (:mod:`.runtime`) reports what happens through :func:`notify`; whoever wants to
show it (the command line) registers a listener with :func:`listening`. Without a listener
nothing happens, so library users and tests see no change. Listeners are called from the
flow's threads, including the store's region-writing threads.

Two displays:

- :class:`RichProgress` (a terminal): one line per running node with its stage and elapsed
  time, and for a resumable write a bar of the regions (image sets) written, with the ETA;
  a finished node leaves one line.
- :class:`PlainProgress` (a pipe or a file): the same as plain lines, with the ETA in words.

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


_LISTENERS: list[Listener] = []
_LOCK = threading.Lock()


@contextlib.contextmanager
def listening(listener: Listener) -> Iterator[Listener]:
    """Send the runtime's progress to ``listener`` for the duration of the block."""
    with _LOCK:
        _LISTENERS.append(listener)
    try:
        yield listener
    finally:
        with _LOCK:
            if listener in _LISTENERS:  # a failing one was dropped already
                _LISTENERS.remove(listener)


def notify(method: str, *args: Any) -> None:
    """Call ``method(*args)`` of every listener. A failing display never fails the run: its
    error is printed once and the display is dropped."""
    with _LOCK:
        listeners = list(_LISTENERS)
    for listener in listeners:
        try:
            getattr(listener, method)(*args)
        except Exception as error:  # a broken display must not cost a long run
            with _LOCK:
                if listener in _LISTENERS:
                    _LISTENERS.remove(listener)
            print(
                f"spectralize: progress display stopped: {type(error).__name__}: {error}",
                file=sys.stderr,
            )


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
    written with the time left, node ends."""

    def __init__(self, stream: IO[str] | None = None, clock=time.monotonic):
        self.stream = stream
        self.clock = clock
        self._started: dict[tuple[str, str], tuple[float, int]] = {}
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

    def step_finished(self, node: str, status: str, seconds: float) -> None:
        with self._lock:
            for key in [k for k in self._started if k[0] == node]:
                del self._started[key]
        if status == "ran":
            self._print(f"    {node}: done in {format_seconds(seconds)}")
        else:
            self._print(f"    {node}: up to date")


class RichProgress:
    """A live display on a terminal (rich): the running node with its stage and elapsed
    time, and per resumable write a bar of image sets with the ETA."""

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
                return Text(f"ETA {format_seconds(remaining)}" if remaining is not None else "ETA …")

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

    def step_finished(self, node: str, status: str, seconds: float) -> None:
        with self._lock:
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
