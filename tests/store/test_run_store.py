"""The run-store API: create and open, write and read back, schemas enforced before writing, group names, content fingerprints of imported groups, values checked on disk, full and read-only disks."""

import json
import os
import shutil
import subprocess

import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.schemas import SchemaError, StoreError
from spectralize.store import (
    FINGERPRINT_ATTR,
    PROVENANCE_ATTR,
    RunStore,
    compute_fingerprint,
)


def small_raw_dark(seed=0):
    return make_raw_dark(
        frames=8, shape=(6, 7), exposure_times=(0.1, 0.2), frames_per_chunk=4, seed=seed
    )


def test_open_rejects_what_is_not_a_run_store(tmp_path):
    with pytest.raises(StoreError, match="no such directory"):
        RunStore.open(tmp_path / "missing.zarr")
    (tmp_path / "plain").mkdir()
    with pytest.raises(StoreError, match="not a zarr v3 store"):
        RunStore.open(tmp_path / "plain")
    xr.Dataset({"a": ("x", [1, 2])}).to_zarr(tmp_path / "other.zarr", zarr_format=3, consolidated=False)
    with pytest.raises(StoreError, match="not a spectralize run store"):
        RunStore.open(tmp_path / "other.zarr")
    (tmp_path / "v2").mkdir()
    (tmp_path / "v2" / "zarr.json").write_text(json.dumps({"zarr_format": 2}))
    with pytest.raises(StoreError, match="zarr_format=2"):
        RunStore.open(tmp_path / "v2")


def test_create_refuses_an_existing_path(store):
    with pytest.raises(StoreError, match="already exists"):
        RunStore.create(store.path)
    assert RunStore.create(store.path, exist_ok=True).path == store.path


def test_write_read_round_trip_with_explicit_chunks_and_fingerprint(store):
    raw = small_raw_dark()
    fp = compute_fingerprint("gen", "1", {"seed": 0}, {})
    assert (
        store.write(
            "raw/dark",
            raw,
            fingerprint=fp,
            provenance={"node": "gen"},
            chunks={"exposure_time": 1, "frame": 4},
        )
        == fp
    )
    back = store.read("raw/dark", friendly=False)
    xr.testing.assert_identical(back.frames.compute(), raw.frames.compute())
    assert back.frames.data.chunksize == (1, 4, 6, 7)
    assert back.attrs[FINGERPRINT_ATTR] == fp == store.fingerprint("raw/dark")
    assert json.loads(back.attrs[PROVENANCE_ATTR])["node"] == "gen"
    assert store.provenance("raw/dark")["node"] == "gen"
    assert store.groups() == ["raw/dark"]
    assert store.has("raw/dark") and not store.has("raw") and not store.has("dark")
    assert store.validate() == []


def test_a_read_without_dask_reads_the_same_values_and_still_checks_each_chunk(store):
    raw = small_raw_dark()
    store.write("raw/dark", raw, fingerprint="f", chunks={"exposure_time": 1, "frame": 4})
    back = store.read("raw/dark", friendly=False, dask=False)
    assert back.frames.chunks is None  # no dask
    np.testing.assert_array_equal(back.frames.isel(frame=slice(0, 4)).values, raw.frames.values[:, :4])
    chunk = next(
        p
        for p in (store.path / "raw" / "dark" / "frames").rglob("*")
        if p.is_file() and p.stat().st_size > 64
    )
    data = bytearray(chunk.read_bytes())
    data[-5] ^= 0xFF
    chunk.write_bytes(bytes(data))
    with pytest.raises(Exception, match="checksum|damaged"):
        np.asarray(store.read("raw/dark", friendly=False, dask=False).frames)


def test_schema_violation_writes_nothing(store):
    bad = small_raw_dark().drop_attrs()
    with pytest.raises(SchemaError, match="refusing to write group 'raw/dark'"):
        store.write("raw/dark", bad)
    assert store.groups() == []
    assert not (store.path / "raw" / "dark").exists()


def test_imported_group_gets_a_content_fingerprint(store):
    small_raw_dark().to_zarr(store.path, group="raw/dark", zarr_format=3, consolidated=False)
    first = store.fingerprint("raw/dark")
    assert first.startswith("content:")
    assert store.fingerprint("raw/dark") == first
    shutil.rmtree(store.path / "raw" / "dark")
    small_raw_dark(seed=5).to_zarr(store.path, group="raw/dark", zarr_format=3, consolidated=False)
    os.utime(store.path / "raw" / "dark" / "zarr.json", ns=(1, 1))
    assert store.fingerprint("raw/dark") != first


def test_invalid_group_names_are_rejected(store):
    for name in ("", "../x", ".staging/x", "a//b"):
        with pytest.raises(StoreError, match="invalid group name"):
            store.write(name, small_raw_dark())


def hdr_with_nan():
    """A lazy ``hdr`` group following its contract but for two NaN pixels of image 1."""
    radiance = np.ones((2, 3, 3, 3), np.float32)
    radiance[1, 0, :2, 0] = np.nan
    per_image = {name: ("image", [0, 1]) for name in ("camera", "rotation", "led")}
    angles = {
        name: ("image", [10.0, 20.0], {"units": "degree"})
        for name in ("theta_i", "phi_i", "theta_o", "phi_o")
    }
    return xr.Dataset(
        {"radiance": (("image", "y", "x", "channel"), da.from_array(radiance), {"units": "1"})},
        coords={"channel": ["R", "G", "B"], **per_image, **angles},
    )


def test_validate_checks_values_on_disk_and_required_groups(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    raw = make_raw_dark(frames=4, shape=(4, 4), exposure_times=(0.1, 0.2, 0.3))
    raw = raw.assign_coords(exposure_time=("exposure_time", [0.1, -0.2, np.nan], {"units": "s"}))
    raw.to_zarr(store.path, group="raw/dark", zarr_format=3, consolidated=False)  # an importer
    store.write("hdr", hdr_with_nan(), fingerprint="h")  # lazy: not value-checked on write
    text = "\n".join(map(str, store.validate(required=["raw/rgb"])))
    assert "raw/rgb: expected a finished group (the flow reads it), found nothing" in text
    assert (
        "raw/dark:exposure_time: expected finite values, found 1 NaN/inf value(s) (first at exposure_time=2"
        in text
    )
    assert (
        "raw/dark:exposure_time: expected values in [0, 10000], found range [-0.2, 0.1] (1 value(s) outside, first at exposure_time=1: -0.2)"
        in text
    )
    assert (
        "hdr:radiance: expected finite values, found 2 NaN/inf value(s) (first at image=1, y=0, x=0, channel=0"
        in text
    )


@pytest.fixture
def small_filesystem(tmp_path):
    """A 3 MB tmpfs: a real file system that fills up and can be made read-only."""
    mount = tmp_path / "small"
    mount.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=3m", "tmpfs", str(mount)], check=True)
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=True)


def cube(shape, fill=None):
    """A float32 cube whose computation can fill the disk first (a concurrent writer)."""

    def block(b, block_info=None):
        if fill is not None and block_info[0]["chunk-location"][0] == 1:
            with open(fill, "wb") as f:  # someone else takes the rest of the disk
                try:
                    while True:
                        f.write(b"\0" * 65536)
                except OSError:
                    pass
        return np.random.default_rng(block_info[0]["chunk-location"][0]).random(
            b.shape, dtype=np.float32
        )

    data = da.zeros(shape, dtype=np.float32, chunks=(1,) + shape[1:]).map_blocks(block, dtype=np.float32)
    return xr.Dataset({"v": (("image", "y", "x"), data, {"units": "1"})})


def test_full_disk_and_read_only_store_fail_clearly_and_lose_nothing(small_filesystem):
    store = RunStore.create(small_filesystem / "run.zarr")
    store.write("kept", cube((2, 64, 64)), fingerprint="kept")
    before = store.read("kept").v.values
    # more than the disk has: refused before anything is written
    with pytest.raises(StoreError, match=r"not enough free space .* group 'big': it needs up to 8.4 MB"):
        store.write("big", cube((2, 1024, 1024)), fingerprint="big")
    # fits when it starts, but the disk fills up while it is written
    filler = small_filesystem / "filler"
    for resumable in (None, "image"):
        with pytest.raises(
            StoreError, match="disk full while writing group 'late' .* staged copy was removed"
        ):
            store.write(
                "late", cube((4, 128, 128), fill=filler), fingerprint="late", resumable_along=resumable
            )
        filler.unlink()
        assert store.staging_leftovers() == [] and not store.has("late")
    np.testing.assert_array_equal(store.read("kept").v.values, before)
    assert store.validate(deep=True) == []

    subprocess.run(["mount", "-o", "remount,ro", str(small_filesystem)], check=True)
    with pytest.raises(StoreError, match=r"cannot write to run store .*: Read-only file system"):
        store.write("late", cube((1, 8, 8)), fingerprint="x")
    assert RunStore.open(store.path).validate(deep=True) == []  # read-only commands work
    np.testing.assert_array_equal(store.read("kept").v.values, before)
