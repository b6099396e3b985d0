"""Frames decoded on worker processes: the same frames in the same order as one thread, and a
frame that cannot be read names its file."""

import numpy as np
import pytest
import tifffile

from spectralize.datasets.capture import CaptureError
from spectralize.flows.ingest.decode import PARALLEL_ABOVE, FrameDecoder


@pytest.fixture
def frames(tmp_path):
    """More small TIFF frames than a chunk needs for workers, each a different picture."""
    paths = []
    for k in range(PARALLEL_ABOVE + 44):
        path = tmp_path / f"frame{k:04d}.tif"
        tifffile.imwrite(path, np.full((6, 5), k, np.uint16) + np.arange(5, dtype=np.uint16))
        paths.append(path)
    return paths


def test_a_chunk_is_decoded_on_worker_processes_in_frame_order(frames):
    sources = [("file", str(path)) for path in frames]
    alone = list(FrameDecoder(workers=1).frames(sources, (6, 5)))
    with FrameDecoder(workers=2) as decoder:
        decoder.start()
        together = list(decoder.frames(sources, (6, 5)))
        assert decoder.running() == 2  # worker processes, not this thread
    assert decoder.running() == 0  # stopped with the block
    assert len(together) == len(frames)
    assert [int(f[0, 0]) for f in together] == list(range(len(frames)))
    assert all(
        np.array_equal(a, b) and b.dtype == np.uint16 for a, b in zip(alone, together, strict=True)
    )


def test_a_frame_a_worker_cannot_read_is_named(frames):
    broken = frames[PARALLEL_ABOVE]
    broken.write_bytes(b"II*\x00 not a tiff")
    sources = [("file", str(path)) for path in frames]
    with FrameDecoder(workers=2) as decoder, pytest.raises(CaptureError) as raised:
        list(decoder.frames(sources, (6, 5)))
    assert decoder.running() == 0
    assert str(broken) in str(raised.value)


def test_the_workers_end_when_the_ingest_is_killed(frames):
    """A killed ingest cannot stop its workers: they end on their own (none is left holding
    the pipes of whoever started the ingest)."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(
        f"""
        import os
        from spectralize.flows.ingest.decode import FrameDecoder
        decoder = FrameDecoder(workers=2)
        decoder.start()
        list(decoder.frames([("file", p) for p in {[str(p) for p in frames]!r}], (6, 5)))
        print(decoder.running(), flush=True)
        os._exit(9)
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 9 and done.stdout.strip() == "2", done.stderr
