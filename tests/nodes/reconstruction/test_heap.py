"""A tile solver's freed memory kept in the heap: taken in a fresh worker process (its
threads included), left alone where the user set it, and a tile's result unchanged on
reused memory."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from spectralize.nodes.reconstruction import heap
from spectralize.nodes.reconstruction.heap import MALLOPT_SETTINGS, keep_freed_memory
from spectralize.nodes.reconstruction.methods import resolve_method
from spectralize.nodes.reconstruction.tiling import solve_tile
from spectralize.nodes.simulation.scenes import get_scene


def _glibc() -> tuple[int, ...]:
    """glibc's version, or () elsewhere."""
    try:
        name, version = (os.confstr("CS_GNU_LIBC_VERSION") or "").split()
    except (ValueError, OSError, AttributeError):
        return ()
    return tuple(int(part) for part in version.split(".")[:2]) if name == "glibc" else ()


GLIBC = _glibc()

# a worker process: the setting made at its start, then a thread (as a dask worker's task)
# frees a block far above glibc's mmap threshold; glibc's counters say where it went
WORKER = f"""
import ctypes, importlib.util, sys, threading
spec = importlib.util.spec_from_file_location("heap", {str(Path(heap.__file__))!r})
module = importlib.util.module_from_spec(spec)
spec.loader.exec_module(module)  # the module alone: no package import in the worker
taken = module.keep_freed_memory()
libc = ctypes.CDLL("libc.so.6")
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]

# glibc's counters: mallinfo2 (glibc >= 2.33, size_t fields), else mallinfo (int fields)
modern = hasattr(libc, "mallinfo2")
class Mallinfo(ctypes.Structure):
    _fields_ = [(name, ctypes.c_size_t if modern else ctypes.c_int) for name in (
        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks", "uordblks",
        "fordblks", "keepcost")]

mallinfo = libc.mallinfo2 if modern else libc.mallinfo
mallinfo.restype = Mallinfo
size = 96 << 20
def task():
    block = libc.malloc(size)
    ctypes.memset(block, 1, size)
    libc.free(block)
thread = threading.Thread(target=task)
thread.start()
thread.join()
print(taken, mallinfo().fordblks >= size)  # the freed block still in the heap
"""


def _worker(env: dict[str, str]) -> list[str]:
    done = subprocess.run(
        [sys.executable, "-c", WORKER], capture_output=True, text=True, env=env, timeout=60
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.split()


def test_a_worker_keeps_a_freed_large_block_in_its_heap_and_a_user_setting_is_left_alone():
    plain = {k: v for k, v in os.environ.items() if k not in MALLOPT_SETTINGS}
    if GLIBC:
        assert _worker(plain) == ["True", "True"]
        # the user's own settings (here glibc's defaults) win: the block goes back to the system
        users = {**plain, "MALLOC_MMAP_MAX_": "65536", "MALLOC_TRIM_THRESHOLD_": "131072"}
        assert _worker(users)[1] == "False"
    else:  # not glibc (macOS, musl): the documented no-op, nothing set
        assert heap.glibc_mallopt() is None and heap._set_mallopt() is False


def test_keep_freed_memory_is_set_once_per_process():
    assert keep_freed_memory() is keep_freed_memory()


def test_a_tile_on_reused_memory_is_bit_identical():
    """The solve's memory comes from freed blocks (a tile's own, or poisoned ones) instead of
    fresh zeroed pages: nothing it reads before writing may differ."""
    scene = get_scene("glossy-mosaic", size=40, n_images=2, seed=3)
    inner = (slice(8, 32), slice(8, 32))
    method = resolve_method(None, max_iterations=30)

    def solve(poison: float) -> tuple[np.ndarray, np.ndarray]:
        freed = np.full(8 << 20, poison)  # 64 MB, freed into the heap before the solve
        del freed
        spectra, _, spread = solve_tile(
            scene.rgb, scene.bands, scene.camera_matrix, inner, method=method, confidence=True
        )
        return spectra, spread

    keep_freed_memory()
    first, second = solve(0.0), solve(np.nan)
    assert np.isfinite(first[0]).all()
    assert np.array_equal(first[0], second[0]) and np.array_equal(first[1], second[1])
