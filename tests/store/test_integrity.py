"""Nothing damaged is trusted: missing, truncated, edited, bit-rotten and added files are found by the manifest's sizes and checksums, cheaply, deeply and on read."""

import os

import pytest

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.schemas import StoreError
from spectralize.store import ChecksumError


def small_raw_dark(seed=0):
    return make_raw_dark(
        frames=8, shape=(6, 7), exposure_times=(0.1, 0.2), frames_per_chunk=4, seed=seed
    )


def chunk_of(store, group, variable):
    manifest = store.manifest(group)["files"]
    rel = sorted(k for k in manifest if k.startswith(f"{variable}/c/"))[0]
    return store.path / group / rel


def flip_bytes(path, count=64, keep_time=False):
    """Overwrite ``count`` bytes in the middle of a file with their complement, same size."""
    stat = path.stat()
    data = bytearray(path.read_bytes())
    start = max(0, len(data) // 2 - count // 2)
    for i in range(start, min(len(data), start + count)):
        data[i] ^= 0xFF
    path.write_bytes(bytes(data))
    if keep_time:  # bit rot: the bytes change, the time does not
        os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    assert path.stat().st_size == stat.st_size


def test_flipped_bytes_are_found_cheaply_deeply_and_on_read(dark_store):
    chunk = chunk_of(dark_store, "raw/dark", "frames")
    flip_bytes(chunk)
    problems = dark_store.verify("raw/dark")
    assert [p.where for p in problems] == [
        f"raw/dark/{chunk.relative_to(dark_store.path / 'raw/dark').as_posix()}"
    ]
    assert "edited after commit" in problems[0].found
    with pytest.raises(StoreError, match="damaged and was not read"):
        dark_store.read("raw/dark")


def test_bit_rot_with_the_same_time_is_found_by_deep_checks_and_on_read(dark_store):
    chunk = chunk_of(dark_store, "raw/dark", "frames")
    flip_bytes(chunk, keep_time=True)
    assert dark_store.verify("raw/dark") == []  # the cheap check trusts sizes and times
    deep = dark_store.verify("raw/dark", deep=True)
    assert len(deep) == 1 and "changed on disk" in deep[0].found
    assert [p.where for p in dark_store.validate(deep=True)] == [deep[0].where]
    with pytest.raises(ChecksumError, match=r"chunk raw/dark/frames/c/.* is damaged"):
        dark_store.read("raw/dark").frames.load()  # every chunk read is checked


def test_files_added_after_commit_are_reported(dark_store):
    extra = dark_store.path / "raw" / "dark" / "frames" / "c" / "9" / "0" / "0" / "0"
    extra.parent.mkdir(parents=True)
    extra.write_bytes(b"\0" * 16)
    assert [p.found for p in dark_store.verify("raw/dark")] == ["a file added later"]


def test_missing_or_truncated_chunk_is_reported_never_read(store):
    store.write("raw/dark", small_raw_dark(), fingerprint="x", chunks={"frame": 4})
    manifest = store.manifest("raw/dark")["files"]
    chunk = sorted(k for k in manifest if k.startswith("frames/"))[0]
    os.remove(store.path / "raw" / "dark" / chunk)
    problems = store.verify("raw/dark")
    assert [p.where for p in problems] == [f"raw/dark/{chunk}"]
    assert "a missing file" in str(problems[0])
    with pytest.raises(StoreError, match="damaged and was not read"):
        store.read("raw/dark")
