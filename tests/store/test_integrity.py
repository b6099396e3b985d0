"""Nothing damaged or stale is trusted: checksums, one writer per store, own staging only,
values checked on disk, xarray-friendly reads. Real zarr stores, real processes."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.schemas import StoreError
from spectralize.store import MANIFEST_ATTR, ChecksumError, RunStore, StoreBusyError, work_dir


@pytest.fixture
def store(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    store.write(
        "raw/dark",
        make_raw_dark(frames=8, shape=(6, 7), exposure_times=(0.1, 0.2), frames_per_chunk=4),
        fingerprint="raw",
    )
    return store


def chunk_of(store, group, variable):
    manifest = json.loads(store.group_attrs(group)[MANIFEST_ATTR])["files"]
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


def test_flipped_bytes_are_found_cheaply_deeply_and_on_read(store):
    chunk = chunk_of(store, "raw/dark", "frames")
    flip_bytes(chunk)
    problems = store.verify("raw/dark")
    assert [p.where for p in problems] == [
        f"raw/dark/{chunk.relative_to(store.path / 'raw/dark').as_posix()}"
    ]
    assert "edited after commit" in problems[0].found
    with pytest.raises(StoreError, match="damaged and was not read"):
        store.read("raw/dark")


def test_bit_rot_with_the_same_time_is_found_by_deep_checks_and_on_read(store):
    chunk = chunk_of(store, "raw/dark", "frames")
    flip_bytes(chunk, keep_time=True)
    assert store.verify("raw/dark") == []  # the cheap check trusts sizes and times
    deep = store.verify("raw/dark", deep=True)
    assert len(deep) == 1 and "changed on disk" in deep[0].found
    assert [p.where for p in store.validate(deep=True)] == [deep[0].where]
    with pytest.raises(ChecksumError, match=r"chunk raw/dark/frames/c/.* is damaged"):
        store.read("raw/dark").frames.load()  # every chunk read is checked


def test_files_added_after_commit_are_reported(store):
    extra = store.path / "raw" / "dark" / "frames" / "c" / "9" / "0" / "0" / "0"
    extra.parent.mkdir(parents=True)
    extra.write_bytes(b"\0" * 16)
    assert [p.found for p in store.verify("raw/dark")] == ["a file added later"]


def test_staging_is_per_write_invisible_to_datatree_and_cleaned(store):
    # an abandoned write of another run, of the same data (same fingerprint prefix)
    store.write("dark_copy", store.read("raw/dark", friendly=False), fingerprint="fp")
    staging = store.staging_dir
    abandoned = staging / "dark_copy.0000000000000000.4242-deadbeef"
    abandoned.mkdir(parents=True)
    (abandoned / "zarr.json").write_text('{"zarr_format": 3, "node_type": "group"}')
    store.write("dark_copy", store.read("raw/dark", friendly=False), fingerprint="fp2")
    assert abandoned.is_dir()  # a write removes only its own staged copy
    assert [p.where for p in store.staging_leftovers()] == [str(abandoned)]
    assert store.validate() == []  # a leftover is a warning, not an error
    tree = xr.open_datatree(str(store.path), engine="zarr", consolidated=False)
    assert sorted(node.path for node in tree.subtree) == ["/", "/dark_copy", "/raw", "/raw/dark"]
    assert store.clean() == [abandoned.name]
    assert store.staging_leftovers() == [] and not staging.exists()


HOLDER = textwrap.dedent(
    """
    import sys, time
    from spectralize.store import RunStore
    with RunStore.open(sys.argv[1]).lock("holder test"):
        print("locked", flush=True)
        time.sleep(300)
    """
)


def test_one_writer_per_store_and_a_dead_holder_is_taken_over(store):
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(store.path)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(
            StoreBusyError, match=rf"store busy: run by pid {holder.pid} on host \S+ since"
        ):
            store.write("other", xr.Dataset({"v": ("x", [1.0])}))
        assert store.read("raw/dark").frames.shape == (2, 8, 6, 7)  # readers never block
        assert store.validate() == []
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert (work_dir(store.path) / "lock.json").exists()  # a killed holder leaves its note behind
    with pytest.warns(
        RuntimeWarning, match=rf"taking over the lock of a run that is gone \(pid {holder.pid}"
    ):
        store.write("other", xr.Dataset({"v": ("x", [1.0])}))
    assert store.has("other") and not (work_dir(store.path) / "lock.json").exists()


def image_cube(order):
    n = len(order)
    return xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                da.from_array(
                    np.arange(n, dtype=np.float32)[:, None, None, None]
                    * np.ones((1, 3, 2, 2), np.float32)
                ),
                {"units": "1"},
            )
        },
        coords={
            "image": np.asarray(order),
            "wavelength": ("wavelength", [450.0, 550.0, 650.0], {"units": "nm"}),
            "camera": ("image", da.from_array(np.asarray(order) % 2)),
        },
    )


def test_reads_are_sorted_have_loaded_coords_pixel_coords_and_netcdf_friendly_attrs(store, tmp_path):
    store.write(
        "cube", image_cube([3, 0, 2, 1]), fingerprint="c", provenance={"node": "n", "p": {"a": 1}}
    )
    ds = store.read("cube")
    assert ds.image.values.tolist() == [0, 1, 2, 3]
    assert ds.radiance.sel(image=0, wavelength=555, method="nearest").values.tolist() == [[1, 1], [1, 1]]
    assert ds.sel(image=slice(0, 1)).sizes["image"] == 2
    assert ds.camera.chunks is None  # loaded
    assert ds.where(ds.camera == 1, drop=True).image.values.tolist() == [1, 3]
    assert ds.x.values.tolist() == [0, 1] and ds.y.attrs["units"] == "px"
    assert json.loads(ds.attrs["spectralize_provenance"])["p"] == {"a": 1}  # JSON text
    assert store.provenance("cube")["p"] == {"a": 1}
    ds.to_netcdf(tmp_path / "read.nc")  # a read() result writes as it is
    assert store.read("cube", friendly=False).image.values.tolist() == [3, 0, 2, 1]  # as stored
    plain = xr.open_zarr(str(store.path), group="cube", consolidated=False)
    assert json.loads(plain.attrs["spectralize_provenance"])["node"] == "n"
    plain.to_netcdf(tmp_path / "cube.nc")  # bookkeeping attrs are JSON strings
    assert xr.open_dataset(tmp_path / "cube.nc").radiance.shape == (4, 3, 2, 2)


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


KILLED_WRITER = textwrap.dedent(
    """
    import sys
    import numpy as np, xarray as xr
    from spectralize.store import RunStore
    store = RunStore.open(sys.argv[1])
    for i in range(10**6):
        value = float(i % 2)
        data = xr.Dataset({"v": (("image", "y", "x"), np.full((4, 64, 64), value, np.float32), {"units": "1"})})
        store.write("g", data.chunk({"image": 1}), fingerprint=f"fp{i % 2}")
        print(i, flush=True)
    """
)


@pytest.mark.filterwarnings("ignore:run store run.zarr. taking over the lock:RuntimeWarning")
def test_sigkill_during_commits_never_leaves_a_damaged_or_half_group(tmp_path):
    path = RunStore.create(tmp_path / "run.zarr").path
    rng = np.random.default_rng(0)
    for _ in range(6):
        writer = subprocess.Popen(
            [sys.executable, "-c", KILLED_WRITER, str(path)], stdout=subprocess.PIPE
        )
        writer.stdout.readline()  # at least one write finished
        time.sleep(rng.uniform(0, 0.3))
        writer.send_signal(signal.SIGKILL)
        writer.wait()
        store = RunStore.open(path)  # puts back a group caught between its two renames
        assert store.groups() == ["g"]
        assert store.verify("g", deep=True) == []
        values = np.unique(store.read("g").v.values)
        fingerprint = store.fingerprint("g")
        assert values.tolist() in ([0.0], [1.0]) and fingerprint == f"fp{int(values[0])}"
    store.clean()
    assert store.staging_leftovers() == []
