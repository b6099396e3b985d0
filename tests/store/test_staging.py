"""Staged writes: per write and invisible to xarray, atomic renames that never lose the previous result (crashes and SIGKILL), resumable regions."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.schemas import StoreError
from spectralize.store import RunStore, layout


def small_raw_dark(seed=0):
    return make_raw_dark(
        frames=8, shape=(6, 7), exposure_times=(0.1, 0.2), frames_per_chunk=4, seed=seed
    )


def test_staging_is_per_write_invisible_to_datatree_and_cleaned(dark_store):
    # an abandoned write of another run, of the same data (same fingerprint prefix)
    dark_store.write("dark_copy", dark_store.read("raw/dark", friendly=False), fingerprint="fp")
    staging = dark_store.staging_dir
    abandoned = staging / "dark_copy.0000000000000000.4242-deadbeef"
    abandoned.mkdir(parents=True)
    (abandoned / "zarr.json").write_text('{"zarr_format": 3, "node_type": "group"}')
    dark_store.write("dark_copy", dark_store.read("raw/dark", friendly=False), fingerprint="fp2")
    assert abandoned.is_dir()  # a write removes only its own staged copy
    assert [p.where for p in dark_store.staging_leftovers()] == [str(abandoned)]
    assert dark_store.validate() == []  # a leftover is a warning, not an error
    tree = xr.open_datatree(str(dark_store.path), engine="zarr", consolidated=False)
    assert sorted(node.path for node in tree.subtree) == ["/", "/dark_copy", "/raw", "/raw/dark"]
    assert dark_store.clean() == [abandoned.name]
    assert dark_store.staging_leftovers() == [] and not staging.exists()


def _failing_after(ds, good_chunks):
    """A copy of ``ds`` whose dask graph raises after ``good_chunks`` chunks were computed."""
    counter = {"n": 0}

    def maybe_fail(block):
        counter["n"] += 1
        if counter["n"] > good_chunks:
            raise RuntimeError("simulated crash inside the writer")
        return block

    frames = ds.frames.data.map_blocks(maybe_fail, dtype=ds.frames.dtype)
    return ds.assign(frames=(ds.frames.dims, frames, ds.frames.attrs))


def test_crash_inside_writer_keeps_previous_result_and_nothing_looks_finished(store):
    first = small_raw_dark(seed=1)
    store.write("raw/dark", first, fingerprint="first")
    replacement = _failing_after(small_raw_dark(seed=2), good_chunks=1)
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError, match="crash"):
        store.write("raw/dark", replacement, fingerprint="second")
    assert store.fingerprint("raw/dark") == "first"
    xr.testing.assert_identical(
        store.read("raw/dark", friendly=False).frames.compute(), first.frames.compute()
    )
    assert store.groups() == ["raw/dark"]
    # a write that cannot be resumed removes its own staged copy
    assert store.staging_leftovers() == [] and store.validate() == []


def test_crash_of_a_first_write_leaves_no_group(store):
    with dask.config.set(scheduler="synchronous"), pytest.raises(RuntimeError):
        store.write("raw/dark", _failing_after(small_raw_dark(), 0), fingerprint="x")
    assert store.groups() == [] and store.fingerprint("raw/dark") is None


def test_successful_rewrite_replaces_the_group(store):
    store.write("raw/dark", small_raw_dark(seed=1), fingerprint="first")
    second = small_raw_dark(seed=2)
    store.write("raw/dark", second, fingerprint="second")
    assert store.fingerprint("raw/dark") == "second"
    xr.testing.assert_identical(
        store.read("raw/dark", friendly=False).frames.compute(), second.frames.compute()
    )
    assert list(store.staging_dir.iterdir()) == []


def test_interrupted_replacement_is_recovered_on_open(store):
    store.write("raw/dark", small_raw_dark(), fingerprint="kept")
    # crash between the two renames: the old group was moved aside, the new one not yet in
    os.rename(store.path / "raw" / "dark", store.staging_dir / "raw~dark.replaced-deadbeef")
    reopened = RunStore.open(store.path)
    assert reopened.fingerprint("raw/dark") == "kept"


def test_resumable_write_resumes_only_unfinished_regions(store):
    calls = []

    def lazy_cube(fail_at=None):
        def block(i):
            calls.append(i)
            if i == fail_at:
                raise RuntimeError(f"crash in region {i}")
            return np.full((1, 4, 4), i, np.float32)

        pieces = [da.from_delayed(dask.delayed(block)(i), (1, 4, 4), np.float32) for i in range(4)]
        return xr.Dataset({"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})})

    with pytest.raises(RuntimeError, match="region 2"):
        store.write("cube", lazy_cube(fail_at=2), fingerprint="fp", resumable_along="image")
    assert not store.has("cube")
    assert sorted(calls) == [0, 1, 2]
    calls.clear()
    messages = []
    store.write("cube", lazy_cube(), fingerprint="fp", resumable_along="image", progress=messages.append)
    assert sorted(calls) == [2, 3]  # regions 0 and 1 were not recomputed
    assert "2/4 region(s) of image already written (2/4 along image), resuming" in messages
    values = store.read("cube").v.values
    assert [float(values[i, 0, 0]) for i in range(4)] == [0, 1, 2, 3]
    assert list(store.staging_dir.iterdir()) == []


def _counted_cube(calls, value=0.0):
    """A lazy cube of 3 images, one region each, that notes which region it computes."""

    def block(i):
        calls.append(i)
        return np.full((1, 4, 4), value + i, np.float32)

    pieces = [da.from_delayed(dask.delayed(block)(i), (1, 4, 4), np.float32) for i in range(3)]
    return xr.Dataset({"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})})


def test_a_write_staged_only_is_invisible_until_a_write_of_the_same_data_commits_it(store):
    calls = []
    messages = []
    fingerprint = store.write(
        "cube", _counted_cube(calls), fingerprint="fp", resumable_along="image", commit=False
    )
    assert fingerprint == "fp" and sorted(calls) == [0, 1, 2]
    assert not store.has("cube") and store.groups() == [] and store.fingerprint("cube") is None
    tree = xr.open_datatree(str(store.path), engine="zarr", consolidated=False)
    assert [node.path for node in tree.subtree] == ["/"]
    assert store.staging_leftovers() != []  # staged, flagged
    calls.clear()
    store.write(
        "cube", _counted_cube(calls), fingerprint="fp", resumable_along="image", progress=messages.append
    )
    assert calls == []  # committed from the staged regions, none computed again
    assert messages == ["3/3 region(s) of image already written (3/3 along image), resuming"]
    assert store.read("cube").v.values[:, 0, 0].tolist() == [0, 1, 2]
    assert list(store.staging_dir.iterdir()) == [] and store.validate() == []


def test_discarding_a_staged_write_leaves_nothing_of_it_and_keeps_the_others(store):
    calls = []
    store.write("cube", _counted_cube(calls), fingerprint="a", resumable_along="image", commit=False)
    store.write("cube", _counted_cube(calls, 10), fingerprint="b", resumable_along="image", commit=False)
    kept = sorted(p.name for p in store.staging_dir.iterdir())
    store.discard_staged("cube", "a")
    left = sorted(p.name for p in store.staging_dir.iterdir())
    assert left and set(left) < set(kept) and not store.has("cube")
    store.discard_staged("cube", "b")
    assert list(store.staging_dir.iterdir()) == [] and store.staging_leftovers() == []
    calls.clear()
    store.write("cube", _counted_cube(calls), fingerprint="a", resumable_along="image")
    assert sorted(calls) == [0, 1, 2]  # nothing was left to adopt: every region computed


def test_flags_a_killed_writer_left_without_metadata_start_the_write_over(store):
    # killed between zarr making the flags' directory and renaming their metadata into it
    store.write("cube", _counted_cube([]), fingerprint="fp", resumable_along="image", commit=False)
    (flags,) = [p for p in store.staging_dir.iterdir() if p.name.endswith(".done")]
    (flags / "zarr.json").unlink()
    calls = []
    store.write("cube", _counted_cube(calls), fingerprint="fp", resumable_along="image")
    assert sorted(calls) == [0, 1, 2]  # nothing adopted: every region computed again
    assert store.read("cube").v.values[:, 0, 0].tolist() == [0, 1, 2]
    assert list(store.staging_dir.iterdir()) == [] and store.validate() == []


def test_a_write_staged_only_must_be_resumable(store):
    with pytest.raises(StoreError, match="commit=False .* needs resumable_along"):
        store.write("cube", _counted_cube([]), fingerprint="fp", commit=False)
    assert not store.staging_dir.exists() or list(store.staging_dir.iterdir()) == []


def test_chunks_half_written_by_a_killed_writer_are_dropped_on_resume(store):
    def cube(fail):
        def block(i):
            if fail and i == 1:
                raise RuntimeError("killed")
            return np.full((1, 3, 3), i, np.float32)

        pieces = [da.from_delayed(dask.delayed(block)(i), (1, 3, 3), np.float32) for i in range(3)]
        return xr.Dataset({"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})})

    with pytest.raises(RuntimeError, match="killed"):
        store.write("cube", cube(fail=True), fingerprint="fp", resumable_along="image")
    staged = next(
        p
        for p in store.staging_dir.iterdir()
        if p.name.startswith("cube.") and not p.name.endswith(".done")
    )
    # what a region's writer leaves when SIGKILL lands between writing and renaming a file
    from spectralize.store.staging import region_path

    half = region_path(staged, 1) / ".v.npy.partial"
    half.parent.mkdir(parents=True, exist_ok=True)
    half.write_bytes(b"half")
    store.write("cube", cube(fail=False), fingerprint="fp", resumable_along="image")
    final = store.path / "cube"
    assert not list(final.rglob("*.partial"))
    manifest = json.loads((final / "spectralize_manifest.json").read_text())
    assert "spectralize_manifest" not in store.group_attrs("cube")  # not in the attrs
    assert manifest["files"] and not any(name.endswith(".partial") for name in manifest["files"])
    store.verify("cube")
    assert store.read("cube").v.values[:, 0, 0].tolist() == [0, 1, 2]


def test_resumable_regions_may_differ_in_size_and_run_concurrently(store):
    sizes = (3, 1, 2)
    pieces = [
        da.full((n, 4, 6), float(i), dtype=np.float32, chunks=(n, 4, 6)) for i, n in enumerate(sizes)
    ]
    cube = xr.Dataset(
        {"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})},
        coords={"image": np.arange(6)},
    )
    messages = []
    store.write(
        "cube",
        cube,
        fingerprint="fp",
        resumable_along="image",
        chunks={"x": 3},
        concurrent_regions=2,
        progress=messages.append,
    )
    back = store.read("cube")
    # x as asked; along image the chunk of a write in one piece (all 6 fit), not the regions'
    assert back.v.encoding["chunks"] == (6, 4, 3)
    np.testing.assert_array_equal(back.v.values[:, 0, 0], [0, 0, 0, 1, 2, 2])
    assert sum("written" in m for m in messages) == 3
    assert messages[-1].endswith("(3/3 done, 6/6 along image)")


def test_regions_of_unequal_size_stage_a_file_per_region_not_per_image(store, monkeypatch):
    from spectralize.store import staging

    sizes = (5, 3, 7, 2)  # the staged group's chunks along image: 1 (gcd of the starts)
    labels = np.random.default_rng(1).permutation(sum(sizes))
    pieces = [da.full((n, 2, 2), float(i), dtype=np.float32, chunks=n) for i, n in enumerate(sizes)]
    names = da.from_array(np.array([f"img{k}" for k in labels], dtype=object), chunks=(sizes,))
    ds = xr.Dataset(
        {"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})},
        coords={"image": labels, "name": ("image", names.astype(np.dtypes.StringDType()))},
    )
    staged_files = []
    pack = staging.pack_staged

    def counting_pack(staged, *args, **kwargs):  # the real pack, after counting what it packs
        regions = staging.regions_path(staged)
        staged_files.extend(p.relative_to(regions) for p in regions.rglob("*") if p.is_file())
        pack(staged, *args, **kwargs)

    monkeypatch.setattr("spectralize.store.run_store.pack_staged", counting_pack)
    store.write("cube", ds, fingerprint="fp", resumable_along="image", concurrent_regions=2)
    assert len(staged_files) == 2 * len(sizes)  # v and name, once per region
    back = store.read("cube", friendly=False)
    order = np.argsort(labels)
    expected = np.repeat(np.arange(len(sizes), dtype=np.float32), sizes)[order]
    np.testing.assert_array_equal(back.v.values[:, 1, 1], expected)
    assert back.image.values.tolist() == sorted(labels.tolist())
    assert back.name.values.tolist() == [f"img{k}" for k in sorted(labels.tolist())]
    assert list(store.staging_dir.iterdir()) == []


def test_region_by_region_write_keeps_memory_bounded_by_the_region_not_the_cube(store):
    import tracemalloc

    regions, shape = 24, (1, 32, 256, 256)  # 8.4 MB per region, 200 MB in all
    region_bytes = int(np.prod(shape)) * 4
    pieces = [
        da.from_delayed(dask.delayed(np.full)(shape, float(i), np.float32), shape, np.float32)
        for i in range(regions)
    ]
    cube = xr.Dataset({"v": (("image", "wavelength", "y", "x"), da.concatenate(pieces), {"units": "1"})})
    tracemalloc.start()
    try:
        store.write("cube", cube, fingerprint="m", resumable_along="image", concurrent_regions=2)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # the regions are written 2 at a time, then packed one shard at a time: bounded by those
    bound = 8 * region_bytes + 2 * layout.SHARD_BYTES
    assert peak < min(bound, 0.6 * regions * region_bytes), f"peak {peak / 1e6:.0f} MB"
    assert float(store.read("cube").v[regions - 1, 0, 0, 0]) == regions - 1


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


@pytest.mark.slow
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


def test_many_small_regions_are_written_together_and_read_back_in_label_order(store):
    from spectralize.store import staging

    sets = [[k + 100, k] for k in range(100)]  # 100 regions of 2 images, 2 labels apart
    pieces = [
        da.from_array(np.asarray(s, np.float32)[:, None, None] * np.ones((1, 2, 2), np.float32))
        for s in sets
    ]
    image = np.concatenate(sets)
    ds = xr.Dataset(
        {"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})}, coords={"image": image}
    )
    assert staging.join_regions([2] * 100, 10) == [slice(k, k + 10) for k in range(0, 200, 10)]
    messages = []
    store.write("cube", ds, fingerprint="fp", resumable_along="image", progress=messages.append)
    last = messages[-1]  # 200 images x 16 B: one region
    assert len(messages) < 100 and last.endswith("(1/1 done, 200/200 along image)")
    back = store.read("cube", friendly=False)
    assert back.image.values.tolist() == list(range(200))
    assert back.v.values[:, 0, 0].tolist() == list(range(200))
