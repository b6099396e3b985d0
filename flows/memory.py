"""The peak resident memory of a block of work (a node's run) in this process.

Linux keeps a process's high-water mark of resident memory (``VmHWM`` in
``/proc/self/status``) and lets the process set it back to its current resident set by
writing ``5`` to ``/proc/self/clear_refs`` (``proc(5)``, "clear_refs"). So the peak of a
block is measured by resetting the mark before it and reading it after:

.. math::

    \\mathrm{peak}(\\text{block}) = \\max_{t \\in \\text{block}} \\mathrm{RSS}(t)
    = \\mathrm{VmHWM}(\\text{end}) \\quad \\text{after a reset at its start,}

two small file operations, whatever the block does. What it counts: every thread of this
process (dask's local threads included); not other processes (the workers of a
``distributed`` cluster, a subprocess).

Resetting the mark loses the peak before it, which is also what ``getrusage``'s
``ru_maxrss`` and ``/proc/self/status`` of this process report afterwards; this module keeps
that peak (:func:`process_peak_bytes`), so a caller can still tell the whole process's peak.

Between blocks, :func:`release_free_memory` hands the memory that Python and the C library
have freed but kept back to the system (``gc.collect``, then glibc's ``malloc_trim(0)``), so a
block starts from what is still in use, not from what the blocks before it left in malloc's
free lists (which grows with the image count of a run).

Where the mark cannot be read or reset (not Linux, a restricted ``/proc``),
:class:`PeakMemory` measures nothing and says so (``peak_bytes`` is ``None``); nothing fails.

References
----------
.. [1] Linux ``proc(5)``: ``/proc/pid/clear_refs`` ("5": reset the peak resident set size)
       and ``/proc/pid/status`` (``VmHWM``, ``VmRSS``).
.. [2] glibc ``malloc_trim(3)``: release free memory from the heap (every arena, also pages
       inside it since glibc 2.8).
"""

from __future__ import annotations

import sys
import threading
from pathlib import Path

__all__ = ["PeakMemory", "process_peak_bytes", "release_free_memory", "resident_bytes"]

_STATUS = Path("/proc/self/status")
_CLEAR_REFS = Path("/proc/self/clear_refs")
_LOCK = threading.Lock()
_EARLIER_PEAK = [0]  # the largest high-water mark reset away so far [bytes]


def resident_bytes(field: str = "VmHWM") -> int | None:
    """``VmHWM`` (peak) or ``VmRSS`` (current) resident set of this process [bytes]; ``None``
    where ``/proc/self/status`` does not tell it."""
    try:
        text = _STATUS.read_text()
    except OSError:
        return None
    for line in text.splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) * 1024  # kB
    return None


def _reset() -> bool:
    """Set the high-water mark back to the current resident set, keeping the old one in
    :data:`_EARLIER_PEAK`; ``False`` where it cannot be reset."""
    with _LOCK:
        before = resident_bytes()
        if before is None:
            return False
        try:
            with _CLEAR_REFS.open("w") as file:
                file.write("5")
        except OSError:
            return False
        _EARLIER_PEAK[0] = max(_EARLIER_PEAK[0], before)
        return True


def process_peak_bytes() -> int | None:
    """This process's peak resident set since it started [bytes], resets included; ``None``
    where it cannot be read."""
    now = resident_bytes()
    if now is None:
        return None
    return max(now, _EARLIER_PEAK[0])


def release_free_memory(collect: bool = True) -> bool:
    """Collect Python's garbage (unless ``collect`` is false), then give the free pages of
    glibc's heaps back to the system (``malloc_trim(0)``); ``False`` where the C library is
    not glibc.

    Costs a full garbage collection (tens of ms in a flow's process) and a walk over malloc's
    free lists (milliseconds); call it between nodes or between the regions of a write, not
    inside loops over pixels or images.
    """
    if collect:
        import gc

        gc.collect()
    if not sys.platform.startswith("linux"):
        return False
    import ctypes
    import ctypes.util

    try:
        trim = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").malloc_trim
    except (OSError, AttributeError):  # not glibc (musl)
        return False
    trim(ctypes.c_size_t(0))
    return True


class PeakMemory:
    """The peak resident set of this process during a ``with`` block.

    ``peak_bytes`` (after the block): the largest resident set while it ran [bytes], ``None``
    where it cannot be measured (see the module docstring); ``peak_gb`` the same in GB
    (1e9 bytes). Blocks must not overlap in time: the high-water mark is one per process.

    Examples
    --------
    >>> with PeakMemory() as measured:
    ...     data = bytearray(10**8)
    >>> measured.peak_bytes is None or measured.peak_bytes >= 10**8
    True
    """

    def __init__(self) -> None:
        self.peak_bytes: int | None = None
        self._measuring = False

    def __enter__(self) -> PeakMemory:
        self._measuring = _reset()
        return self

    def __exit__(self, *exc: object) -> None:
        self.peak_bytes = resident_bytes() if self._measuring else None
        if self.peak_bytes is not None:
            # the kernel's resident-set counters are approximate (batched per thread or CPU),
            # so a later reading can come out a page batch lower: keep what this block saw, and
            # the process's peak is never below a block's
            with _LOCK:
                _EARLIER_PEAK[0] = max(_EARLIER_PEAK[0], self.peak_bytes)

    @property
    def peak_gb(self) -> float | None:
        return None if self.peak_bytes is None else self.peak_bytes / 1e9
