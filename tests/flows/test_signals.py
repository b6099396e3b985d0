"""After an interrupt, coroutines closed after their event loop print nothing; other errors do.

Run in a fresh interpreter: pytest replaces ``sys.unraisablehook`` with its own.
"""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import gc, sys
from spectralize.flows.signals import quiet_cut_off_io

class Suspend:
    def __await__(self):
        yield

async def cut_off(message):
    try:
        await Suspend()
    finally:  # what asyncio raises when a cut-off task is closed after its loop
        raise RuntimeError(message)

def abandon(message):
    coroutine = cut_off(message)
    coroutine.send(None)  # suspended, as a pending zarr read is
    del coroutine
    gc.collect()

if sys.argv[1] == "quiet":
    quiet_cut_off_io()
abandon("Event loop is closed")
abandon("a real failure")
"""


def _stderr(mode: str) -> str:
    done = subprocess.run(
        [sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=60, check=True
    )
    return done.stderr


def test_closed_loop_errors_are_dropped_and_others_printed():
    plain = _stderr("plain")
    assert "Event loop is closed" in plain and "a real failure" in plain
    quiet = _stderr("quiet")
    assert "Event loop is closed" not in quiet
    assert "a real failure" in quiet and "Traceback" in quiet
