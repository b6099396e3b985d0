"""A run on local threads bounds glibc's malloc arenas (a long run's resident set stays flat)."""

import subprocess
import sys

import pytest

from spectralize.flows.dask_setup import MALLOC_ARENAS, bound_malloc_arenas

THREADS = """
import ctypes, sys, threading
from spectralize.flows.dask_setup import bound_malloc_arenas
print(bound_malloc_arenas(), flush=True)
def work():
    for _ in range(2000):
        blocks = [bytearray(4096) for _ in range(16)]
        del blocks
threads = [threading.Thread(target=work) for _ in range(8)]
for t in threads: t.start()
for t in threads: t.join()
ctypes.CDLL("libc.so.6").malloc_stats()  # one "Arena n:" section per arena, to stderr
"""


@pytest.mark.slow  # a fresh interpreter imports Prefect (~10 s)
def test_threads_of_a_run_share_at_most_malloc_arenas_arenas():
    env = {k: v for k, v in __import__("os").environ.items() if k != "MALLOC_ARENA_MAX"}
    done = subprocess.run([sys.executable, "-c", THREADS], capture_output=True, text=True, env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"
    arenas = [line for line in done.stderr.splitlines() if line.startswith("Arena ")]
    assert 1 <= len(arenas) <= MALLOC_ARENAS


def test_a_user_set_malloc_arena_max_is_left_alone(monkeypatch):
    monkeypatch.setenv("MALLOC_ARENA_MAX", "4")
    assert bound_malloc_arenas() is False
