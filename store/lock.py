"""One writer per run store: an OS file lock plus a side file saying who holds it.

The lock is :mod:`filelock`'s (``flock`` on POSIX, ``msvcrt`` on Windows): the operating
system releases it when the holding process dies, however it dies, so a lock left behind by
a killed run is never "stuck". Lock and side file live in the store's work directory
(:func:`work_dir`, beside the store). Who holds it (pid, host, start time, what runs, the Prefect
flow run id once there is one) is kept in a side file next to it, only for messages: a
second writer is told ``store busy: run by pid N on host H since T``, and a writer that
finds the side file of a holder that is gone takes the store over with a warning (and the
caller can mark that holder's flow run as crashed).

Reading never takes the lock. Inside one process the lock is re-entrant across threads
(a flow holds it while its Prefect tasks write from worker threads).
"""

from __future__ import annotations

import json
import os
import socket
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import filelock

from spectralize.schemas import Problem, StoreError

__all__ = ["StoreBusyError", "StoreLock", "LockHolder", "work_dir"]


def work_dir(store: str | os.PathLike[str]) -> Path:
    """Where a store's lock and unfinished writes live: ``.<name>.spectralize/`` beside it.

    Beside the store, not in it: anything in a zarr directory that is not zarr makes zarr
    warn on every listing (``xarray.open_datatree``), and staged groups inside would be
    listed as groups. A rename from there into the store stays on one file system.
    """
    path = Path(store).absolute()
    return path.parent / f".{path.name}.spectralize"


class StoreBusyError(StoreError):
    """Another process is writing to the run store (its lock is held)."""


@dataclass(frozen=True)
class LockHolder:
    """Who holds (or held) a store's lock, from its side file."""

    pid: int | None
    host: str
    since: str
    command: str = ""
    flow_run_id: str | None = None

    @classmethod
    def read(cls, path: Path) -> LockHolder | None:
        try:
            info = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(info, dict):
            return None
        return cls(
            pid=info.get("pid"),
            host=str(info.get("host", "?")),
            since=str(info.get("since", "?")),
            command=str(info.get("command", "")),
            flow_run_id=info.get("flow_run_id"),
        )

    def describe(self) -> str:
        return f"pid {self.pid if self.pid is not None else '?'} on host {self.host} since {self.since}"


def _now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%S%z")


class StoreLock:
    """The write lock of the run store at ``path`` (one object per store and process).

    Use :meth:`hold` as a context manager; it raises :class:`StoreBusyError` at once (it
    never waits) when another process holds the lock, and :class:`StoreError` when the store
    cannot be written at all (read-only file system, no permission).
    """

    _instances: dict[Path, StoreLock] = {}
    _guard = threading.Lock()

    def __new__(cls, path: str | os.PathLike[str]) -> StoreLock:
        key = Path(path).absolute()
        with cls._guard:
            lock = cls._instances.get(key)
            if lock is None:
                lock = super().__new__(cls)
                lock._setup(key)
                cls._instances[key] = lock
            return lock

    def _setup(self, path: Path) -> None:
        self.path = path
        self.work = work_dir(path)
        self.lock_file = self.work / "lock"
        self.info_file = self.work / "lock.json"
        # not thread-local: the flow's thread takes it, its task threads re-enter it
        self._lock = filelock.FileLock(self.lock_file, timeout=0, thread_local=False)
        self._depth = 0
        self._depth_guard = threading.RLock()
        #: the holder whose stale side file was found when this process took the lock
        self.previous: LockHolder | None = None

    @property
    def held(self) -> bool:
        """Whether this process holds the lock now."""
        return self._depth > 0

    def holder(self) -> LockHolder | None:
        """Who holds the lock according to its side file (``None``: nobody says so)."""
        return LockHolder.read(self.info_file)

    def _acquire(self, purpose: str) -> None:
        try:
            self.work.mkdir(exist_ok=True)
            self._lock.acquire(timeout=0)
        except filelock.Timeout:
            holder = self.holder()
            who = holder.describe() if holder else "another process (it has not said which yet)"
            what = f" ({holder.command})" if holder and holder.command else ""
            raise StoreBusyError(
                f"store busy: run by {who}{what}",
                [
                    Problem(
                        str(self.path),
                        "no other writing run",
                        f"a run by {who}",
                        "wait for it to finish, or stop it; read-only commands work meanwhile",
                    )
                ],
            ) from None
        except OSError as error:  # read-only file system, no permission
            raise StoreError(
                f"cannot write to run store {str(self.path)!r}: {error.strerror or error}",
                [Problem(str(self.path), "a writable run store", f"{type(error).__name__}: {error}")],
            ) from None
        stale = self.holder()
        if stale is not None and not (stale.pid == os.getpid() and stale.host == socket.gethostname()):
            self.previous = stale
            warnings.warn(
                f"run store {self.path.name}: taking over the lock of a run that is gone "
                f"({stale.describe()}); it was killed or crashed",
                RuntimeWarning,
                stacklevel=4,
            )
        else:
            self.previous = None
        try:
            self._write_info(
                {
                    "pid": os.getpid(),
                    "host": socket.gethostname(),
                    "since": _now(),
                    "command": purpose or " ".join(Path(sys.argv[0]).name.split() + sys.argv[1:]),
                }
            )
        except OSError as error:
            self._lock.release()
            raise StoreError(
                f"cannot write to run store {str(self.path)!r}: {error.strerror or error}"
            ) from None

    def _write_info(self, info: dict[str, Any]) -> None:
        temporary = self.info_file.with_name(f"{self.info_file.name}.{os.getpid()}.tmp")
        temporary.write_text(json.dumps(info))
        os.replace(temporary, self.info_file)

    def note(self, **fields: Any) -> None:
        """Add fields (e.g. ``flow_run_id``) to the side file while the lock is held."""
        if not self.held:
            return
        try:
            info = json.loads(self.info_file.read_text())
            info.update(fields)
            self._write_info(info)
        except (OSError, ValueError):
            pass  # only messages depend on it

    def _release(self) -> None:
        try:
            holder = self.holder()
            if holder is not None and holder.pid == os.getpid():
                self.info_file.unlink(missing_ok=True)
        finally:
            self._lock.release(force=True)

    @contextmanager
    def hold(self, purpose: str = "") -> Iterator[StoreLock]:
        """Hold the lock for the duration of the block (re-entrant within this process)."""
        with self._depth_guard:
            if self._depth == 0:
                self._acquire(purpose)
            self._depth += 1
        try:
            yield self
        finally:
            with self._depth_guard:
                self._depth -= 1
                if self._depth == 0:
                    self._release()
