"""A failed write leaves no staging behind: a disk that fills while a group is packed, a writer
killed while it packs. The next ingest finds nothing left over and writes the run."""

import errno
import subprocess
import sys
import textwrap

import pytest
from zarr.storage import LocalStore

from spectralize.flows.ingest import ingest
from spectralize.schemas import StoreError
from spectralize.store import RunStore


def staged_entries(path):
    """Every entry of the store's staging directory (its unfinished writes)."""
    staging = RunStore.open(path).staging_dir
    return sorted(p.name for p in staging.iterdir() if p.name != "zarr.json") if staging.is_dir() else []


def test_a_disk_that_fills_while_a_group_is_packed_leaves_no_staging(capture, tmp_path, monkeypatch):
    path = tmp_path / "run.zarr"
    real_set = LocalStore.set

    async def full_while_packing(self, key, value):  # a chunk of a group's packed copy
        if str(self.root).endswith(".packed") and "/c/" in key:
            raise OSError(errno.ENOSPC, "No space left on device", key)
        return await real_set(self, key, value)

    monkeypatch.setattr(LocalStore, "set", full_while_packing)
    with pytest.raises(StoreError, match="nothing was committed, the staged copy was removed"):
        ingest(capture, path)
    assert staged_entries(path) == []  # nothing: not the regions, not the packed copy
    assert RunStore.open(path).staging_leftovers() == []
    monkeypatch.undo()  # space freed: the next ingest writes every group, and leaves nothing
    report = ingest(capture, path)
    assert set(report.groups.values()) == {"written"}
    assert staged_entries(path) == [] and RunStore.open(path).validate() == []


KILLED_WHILE_PACKING = """
import os
from zarr.storage import LocalStore
from spectralize.flows.ingest import ingest

real_set = LocalStore.set


async def killed_while_packing(self, key, value):
    if str(self.root).endswith(".packed") and "/c/" in key:
        os._exit(9)
    return await real_set(self, key, value)


LocalStore.set = killed_while_packing
ingest({capture!r}, {store!r})
"""


def test_a_copy_left_by_a_writer_killed_while_packing_is_removed_by_the_next_write(capture, tmp_path):
    path = tmp_path / "run.zarr"
    script = textwrap.dedent(KILLED_WHILE_PACKING.format(capture=str(capture), store=str(path)))
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 9, done.stderr
    left = staged_entries(path)
    assert any(name.endswith(".packed") for name in left), left  # a hard kill cleans nothing
    report = ingest(capture, path)  # resumes the killed write from its regions, packs it again
    assert set(report.groups.values()) == {"written"}
    assert staged_entries(path) == [] and RunStore.open(path).validate() == []
