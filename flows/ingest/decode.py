"""Frames of a capture folder decoded on every core and handed back in frame order.

Ingest reads a capture folder's frames chunk by chunk (:mod:`.raw_groups`); a chunk of small
frames holds thousands. Decoding a frame is mostly Python (the PNG reader is pure Python, a
small TIFF's tags are parsed in Python), so threads wait on each other for the interpreter:
a :class:`FrameDecoder` decodes a chunk's frames on worker processes instead, a batch of
:data:`FRAMES_PER_TASK` frames per task, and returns them in the order they were asked for,
so the chunk is written exactly as if read in one thread. A chunk of fewer than
:data:`PARALLEL_ABOVE` frames (large frames, small folders) is read in the calling thread:
starting workers would cost more than it saves.

A frame's problems are raised as before, naming its file (the workers raise the same
:class:`~spectralize.datasets.capture.CaptureError`, which crosses the process boundary).
Workers ignore Ctrl-C and SIGTERM (the ingest stops them when it stops) and end when the
ingest's process is gone (killed, it cannot stop them).

On Linux the workers are forked from the ingest's process: they start at once with every
module imported, and nothing of the caller's script runs again in them (a fork server or
spawn would run a script's top level again in every worker unless it is guarded by
``if __name__ == "__main__":``). The ingest runs other threads (the store's I/O loop, dask's),
which a fork leaves stopped in whatever they held, so a worker only decodes files: frames
copied from the store (through zarr and its I/O loop) are read in the calling thread.
Elsewhere the workers are spawned (the guard is then needed, as for any use of
:mod:`multiprocessing` there).

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the frames of a measurement run).
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor
from types import TracebackType

import numpy as np

from spectralize.datasets.capture import CaptureError
from spectralize.datasets.capture.images import read_image

__all__ = ["FRAMES_PER_TASK", "PARALLEL_ABOVE", "FrameDecoder", "available_cores", "load_frame"]

#: Frames one worker task decodes (the cost of handing a task over is paid per batch).
FRAMES_PER_TASK = 64
#: A chunk with fewer frames than this is decoded in the calling thread.
PARALLEL_ABOVE = 256


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def load_frame(source: tuple, frame: tuple[int, ...]) -> np.ndarray:
    """One frame, from its file or (already ingested) from the store; shape ``(1,)*k + frame``.

    ``source`` is ``("file", path)``, ``("file", path, bit_depth)`` or a place in the store.
    A file's header is checked against ``frame`` before it is decoded (a file replaced by a
    larger one since it was probed is refused, not decoded); given its camera's
    ``bit_depth``, its values are checked as they are decoded (at most ``2**bit_depth - 1``,
    right-aligned), so that each frame is decoded once (the capture folder's check leaves
    them to ingest). A frame copied from the store is checked against its chunk's checksum; a
    damaged chunk is not copied: the frame is read from its file again.

    Raises
    ------
    CaptureError
        Naming the file, for a frame that cannot be decoded, has another shape or a value
        above its camera's bit depth.
    """
    if source[0] == "store":
        import zarr

        from spectralize.store.integrity import CheckedLocalStore, ChecksumError

        _, store, array, index, checksums, file = source
        try:
            checked = CheckedLocalStore(store, read_only=True, checksums=checksums)
            data = np.asarray(zarr.open_array(checked, path=array, mode="r")[index])
        except ChecksumError:
            source = ("file", file)
    if source[0] == "file":
        try:
            data = read_image(source[1], shape=frame)
        except CaptureError:  # names the file, what was expected and what it declares
            raise
        except ValueError as error:  # a decoder's own error
            raise CaptureError.single(str(source[1]), f"a frame of shape {frame}", str(error)) from None
    if data.shape != frame:
        raise CaptureError.single(str(source[1]), f"a frame of shape {frame}", f"shape {data.shape}")
    if source[0] == "file" and len(source) > 2 and data.size and int(data.max()) >= 2 ** source[2]:
        bits = source[2]
        raise CaptureError.single(
            str(source[1]),
            f"values up to {2**bits - 1} (a {bits}-bit camera, right-aligned)",
            f"a value of {int(data.max())}",
        )
    return data.astype(np.uint16, copy=False)


def _load_frames(sources: list[tuple], frame: tuple[int, ...]) -> list[np.ndarray]:
    """A worker's task: :func:`load_frame` of each source (files), in order."""
    return [load_frame(source, frame) for source in sources]


#: Seconds between a worker's looks at whether the ingest that started it still runs.
PARENT_CHECK_SECONDS = 0.5


def _worker_started(parent: int) -> None:
    """Workers leave Ctrl-C and SIGTERM to the ingest, which stops them (no traceback per
    worker), and end on their own when the ingest ``parent`` is gone (killed: it could not
    stop them), so none is left holding its pipes or files."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_CHECK_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="ingest-parent-watch", daemon=True).start()


class FrameDecoder:
    """Decodes the frames of a chunk on ``workers`` processes, in order (see the module).

    Use it as a context manager (the workers are started by :meth:`start`, else on the
    first large chunk, and stopped at the end of the block); it may be called from several
    threads at once.

    Parameters
    ----------
    workers
        Worker processes; None: :func:`available_cores`. 1 decodes every frame in the
        calling thread.
    """

    def __init__(self, workers: int | None = None) -> None:
        self.workers = available_cores() if workers is None else max(1, int(workers))
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def __enter__(self) -> FrameDecoder:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, error: BaseException | None, trace: TracebackType | None
    ) -> None:
        self.close()

    def close(self) -> None:
        """Stop the workers (tasks not started are dropped)."""
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)

    def running(self) -> int:
        """Worker processes alive now (0 before the first large chunk and after :meth:`close`)."""
        with self._lock:
            pool = self._pool
        processes = getattr(pool, "_processes", None) or {}
        return sum(process.is_alive() for process in list(processes.values()))

    def start(self) -> None:
        """Start the workers now (forked: at once; spawned: they import what they need while
        the caller goes on)."""
        if self.workers > 1:
            self._started()

    def _started(self) -> ProcessPoolExecutor:
        with self._lock:
            if self._pool is None:
                fork = sys.platform.startswith("linux")
                context = multiprocessing.get_context("fork" if fork else "spawn")
                self._pool = ProcessPoolExecutor(
                    self.workers,
                    mp_context=context,
                    initializer=_worker_started,
                    initargs=(os.getpid(),),
                )
                with warnings.catch_warnings():
                    # the fork is safe here: a worker runs no thread's work (see the module)
                    warnings.filterwarnings("ignore", "This process .* is multi-threaded")
                    for _ in range(self.workers):  # forked now, all of them
                        self._pool.submit(int)
            return self._pool

    def frames(self, sources: list[tuple], frame: tuple[int, ...]) -> Iterator[np.ndarray]:
        """The frames of ``sources`` (:func:`load_frame`), in their order.

        Raises
        ------
        CaptureError
            For the first frame (in order) that cannot be read, naming its file.
        """
        files = sum(source[0] == "file" for source in sources)
        if self.workers == 1 or files < PARALLEL_ABOVE:
            return (load_frame(source, frame) for source in sources)
        batches = [sources[i : i + FRAMES_PER_TASK] for i in range(0, len(sources), FRAMES_PER_TASK)]
        pool = self._started()
        # a batch with a frame copied from the store is read here, when its turn comes
        futures = [
            pool.submit(_load_frames, batch, frame) if all(s[0] == "file" for s in batch) else None
            for batch in batches
        ]
        return itertools.chain.from_iterable(
            _load_frames(batch, frame) if future is None else future.result()
            for batch, future in zip(batches, futures, strict=True)
        )
