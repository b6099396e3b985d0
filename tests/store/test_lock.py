"""One writer per store: a second writer is told who holds the lock, readers never block, and the lock of a killed holder is taken over. Real processes."""

import signal
import subprocess
import sys
import textwrap

import pytest
import xarray as xr

from spectralize.store import (
    StoreBusyError,
    work_dir,
)

HOLDER = textwrap.dedent(
    """
    import sys, time
    from spectralize.store import RunStore
    with RunStore.open(sys.argv[1]).lock("holder test"):
        print("locked", flush=True)
        time.sleep(300)
    """
)


def test_one_writer_per_store_and_a_dead_holder_is_taken_over(dark_store):
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(dark_store.path)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(
            StoreBusyError, match=rf"store busy: run by pid {holder.pid} on host \S+ since"
        ):
            dark_store.write("other", xr.Dataset({"v": ("x", [1.0])}))
        assert dark_store.read("raw/dark").frames.shape == (2, 8, 6, 7)  # readers never block
        assert dark_store.validate() == []
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (work_dir(dark_store.path) / "lock.json").exists()  # a killed holder leaves its note behind
    with pytest.warns(
        RuntimeWarning, match=rf"taking over the lock of a run that is gone \(pid {holder.pid}"
    ):
        dark_store.write("other", xr.Dataset({"v": ("x", [1.0])}))
    assert dark_store.has("other") and not (work_dir(dark_store.path) / "lock.json").exists()
