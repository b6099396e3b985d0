"""A tile solver's freed memory kept in its process's heap for the next tile.

A tile's solve of eq. 1 makes and frees work arrays of its window's size again and again
(the neighbourhood search's, the spectral prior's, the set model's cubes). glibc's malloc
serves every block above its mmap threshold from a fresh mapping and unmaps it when it is
freed, so the kernel faults each new cube in again, page by page, zeroing it (the
process's *system* time), and a worker that solves tile after tile pays that on every tile.
:func:`keep_freed_memory` has glibc serve large blocks from its heap and keep the freed
ones there for the next request (``mallopt``: ``M_MMAP_MAX`` 0, ``M_TRIM_THRESHOLD`` -1:
never trimmed), and has the threads started afterwards share that one heap (``M_ARENA_MAX``
1: glibc's other arenas map a block larger than their own heaps afresh whatever the
setting). The numbers a tile computes do not change, only where their memory comes from;
the process's resident set no longer shrinks after a tile's peak, the memory stays ready
for the next one, and the peak itself can rise: a kept heap grows past the arrays alive
at once where a freed block is too small for the next request. What it was measured to
change: ``docs/benchmarks_notes.md`` (paper_scale_throughput).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1) and section 4 (sets solved
   tile by tile).
.. [2] The GNU C Library manual, "Malloc Tunable Parameters" (``mallopt``).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from collections.abc import Callable

__all__ = ["glibc_mallopt", "keep_freed_memory", "MALLOPT_SETTINGS"]

MALLOPT_SETTINGS: dict[str, tuple[int, int]] = {
    "MALLOC_MMAP_MAX_": (-4, 0),  # M_MMAP_MAX: no block in a mapping of its own
    "MALLOC_TRIM_THRESHOLD_": (-1, -1),  # M_TRIM_THRESHOLD: -1, the heap is never trimmed
    "MALLOC_ARENA_MAX": (-8, 1),  # M_ARENA_MAX: new threads share the heap that keeps it
}
"""The glibc environment variable of each setting (which, where set, is the user's choice
and left alone) -> its ``mallopt`` parameter (``<malloc.h>``) and the value set."""

_applied: bool | None = None  # once per process: the result of the first call


def keep_freed_memory() -> bool:
    """Keep the memory a tile frees in this process's heap for the next tile (glibc).

    Sets :data:`MALLOPT_SETTINGS` once per process; later calls return the first one's
    result. Each setting whose environment variable is set is left as the user chose it.
    A no-op (``False``) where the C library is not glibc (macOS, musl, Windows). Call it
    before the threads that solve tiles start: a thread keeps the arena it first allocated
    from, and only the main heap keeps large blocks.

    Returns
    -------
    bool
        Whether glibc took the settings.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (sets solved tile by tile).
    """
    global _applied
    if _applied is None:
        _applied = _set_mallopt()
    return _applied


def glibc_mallopt() -> Callable[[int, int], bool] | None:
    """glibc's ``mallopt(parameter, value)``, or None where the C library is not glibc
    (macOS, musl, Windows): whether glibc took the setting."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        function = libc.mallopt
    except (OSError, AttributeError):  # not glibc
        return None
    return lambda parameter, value: bool(function(ctypes.c_int(parameter), ctypes.c_int(value)))


def _set_mallopt() -> bool:
    """:data:`MALLOPT_SETTINGS` through glibc's ``mallopt`` (False: not glibc, or refused)."""
    mallopt = glibc_mallopt()
    if mallopt is None:
        return False
    taken = True
    for variable, (parameter, value) in MALLOPT_SETTINGS.items():
        if variable not in os.environ:
            taken &= mallopt(parameter, value)
    return taken
