import json
import os
import shutil
import warnings

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.schemas import SchemaError, StoreError
from spectralize.store import (
    FINGERPRINT_ATTR,
    MANIFEST_ATTR,
    PROVENANCE_ATTR,
    RunStore,
    compute_fingerprint,
)


@pytest.fixture
def store(tmp_path):
    return RunStore.create(tmp_path / "run.zarr")


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


def test_fingerprint_depends_on_every_ingredient():
    base = compute_fingerprint("n", "1", {"a": 1}, {"raw/dark": "x"})
    assert base == compute_fingerprint("n", "1", {"a": 1}, {"raw/dark": "x"})
    assert base != compute_fingerprint("m", "1", {"a": 1}, {"raw/dark": "x"})
    assert base != compute_fingerprint("n", "2", {"a": 1}, {"raw/dark": "x"})
    assert base != compute_fingerprint("n", "1", {"a": 2}, {"raw/dark": "x"})
    assert base != compute_fingerprint("n", "1", {"a": 1}, {"raw/dark": "y"})


def test_schema_violation_writes_nothing(store):
    bad = small_raw_dark().drop_attrs()
    with pytest.raises(SchemaError, match="refusing to write group 'raw/dark'"):
        store.write("raw/dark", bad)
    assert store.groups() == []
    assert not (store.path / "raw" / "dark").exists()


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


def test_missing_or_truncated_chunk_is_reported_never_read(store):
    store.write("raw/dark", small_raw_dark(), fingerprint="x", chunks={"frame": 4})
    manifest = json.loads(store.group_attrs("raw/dark")[MANIFEST_ATTR])["files"]
    chunk = sorted(k for k in manifest if k.startswith("frames/"))[0]
    os.remove(store.path / "raw" / "dark" / chunk)
    problems = store.verify("raw/dark")
    assert [p.where for p in problems] == [f"raw/dark/{chunk}"]
    assert "a missing file" in str(problems[0])
    with pytest.raises(StoreError, match="damaged and was not read"):
        store.read("raw/dark")


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
    assert "2/4 region(s) of image already written, resuming" in messages
    values = store.read("cube").v.values
    assert [float(values[i, 0, 0]) for i in range(4)] == [0, 1, 2, 3]
    assert list(store.staging_dir.iterdir()) == []


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
    # what zarr's local store leaves when SIGKILL lands between writing and renaming a chunk
    chunk_dir = staged / "v" / "c" / "1" / "0"
    chunk_dir.mkdir(parents=True, exist_ok=True)
    (chunk_dir / "0.0123abcd.partial").write_bytes(b"half")
    store.write("cube", cube(fail=False), fingerprint="fp", resumable_along="image")
    final = store.path / "cube"
    assert not list(final.rglob("*.partial"))
    manifest = json.loads(json.loads((final / "zarr.json").read_text())["attributes"][MANIFEST_ATTR])
    assert manifest["files"] and not any(name.endswith(".partial") for name in manifest["files"])
    store.verify("cube")
    assert store.read("cube").v.values[:, 0, 0].tolist() == [0, 1, 2]


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
    assert back.v.encoding["chunks"] == (1, 4, 3)
    np.testing.assert_array_equal(back.v.values[:, 0, 0], [0, 0, 0, 1, 2, 2])
    assert sum("written" in m for m in messages) == 3
    assert messages[-1].endswith("(3/3 done)")


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
    assert peak < 8 * region_bytes, f"peak {peak / 1e6:.0f} MB for {region_bytes / 1e6:.0f} MB regions"
    assert float(store.read("cube").v[regions - 1, 0, 0, 0]) == regions - 1


def test_text_is_stored_with_a_specified_zarr_type_and_read_back_equal(store):
    lazy_labels = da.from_array(np.array(["red", "green", "blue"]), chunks=2)
    ds = xr.Dataset(
        {"label": (("image",), lazy_labels)},
        coords={"camera": ("image", np.array(["cam00", "cam01", "cam02"]))},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. zarr's UnstableSpecificationWarning for <U
        store.write("text", ds, fingerprint="t")
    for name in ("label", "camera"):
        meta = json.loads((store.path / "text" / name / "zarr.json").read_text())
        assert meta["data_type"] == "string", (name, meta["data_type"])
    back = store.read("text")
    assert back.label.values.tolist() == ["red", "green", "blue"]
    assert back.camera.values.tolist() == ["cam00", "cam01", "cam02"]
