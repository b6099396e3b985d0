"""A store laid out for a full run: label order on disk, shards, one chunk per coordinate,
consolidated metadata, small attrs, and what plain xarray does with it."""

import json
import warnings

import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.schemas import StoreError
from spectralize.store import RunStore, layout, open_run
from spectralize.store.integrity import MANIFEST_FILE


def set_ordered_cube(sets):
    """A spectral cube computed image set by image set: ``image`` in set order, one chunk per set."""
    order = np.concatenate(sets)
    pieces = [
        da.from_array(np.asarray(s, np.float32)[:, None, None, None] * np.ones((1, 3, 4, 4), np.float32))
        for s in sets
    ]
    return xr.Dataset(
        {"radiance": (("image", "wavelength", "y", "x"), da.concatenate(pieces), {"units": "1"})},
        coords={
            "image": order,
            "wavelength": ("wavelength", [450.0, 550.0, 650.0], {"units": "nm"}),
            "theta_i": ("image", da.from_array(order * 10.0, chunks=1), {"units": "degree"}),
            "camera": ("image", da.from_array(order % 3, chunks=1)),
        },
        attrs={"note": "x"},
    )


@pytest.mark.parametrize("resumable", [False, True])
def test_plain_xarray_and_open_run_agree_on_image_order(tmp_path, resumable):
    sets = [[4, 0, 7], [2, 5], [1, 3, 6]]
    store = RunStore.create(tmp_path / "run.zarr")
    store.write(
        "cube",
        set_ordered_cube(sets),
        fingerprint="s",
        resumable_along="image" if resumable else None,
    )
    plain = xr.open_zarr(str(store.path), group="cube")  # default: consolidated metadata
    ours = open_run(store.path).read("cube")
    raw = store.read("cube", friendly=False)
    assert plain.image.values.tolist() == list(range(8))
    assert ours.image.values.tolist() == raw.image.values.tolist() == plain.image.values.tolist()
    assert plain.radiance.isel(image=5).values.max() == ours.radiance.isel(image=5).values.max() == 5
    assert plain.theta_i.values.tolist() == [10.0 * i for i in range(8)]


def test_files_grow_with_shards_and_coordinates_are_one_chunk(tmp_path, monkeypatch):
    monkeypatch.setattr(layout, "SMALL_BYTES", 4096)  # the cube is "large"; coordinates small
    monkeypatch.setattr(layout, "SHARD_BYTES", 100 * 192)  # 100 images of 192 B per shard
    sets = [list(range(k, k + 10)) for k in range(0, 200, 10)][::-1]  # 20 sets, 200 images
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("cube", set_ordered_cube(sets), fingerprint="s", resumable_along="image")
    root = store.path / "cube"
    chunk_files = [p for p in (root / "radiance" / "c").rglob("*") if p.is_file()]
    assert len(chunk_files) == 2  # 200 images in two shards
    meta = json.loads((root / "radiance" / "zarr.json").read_text())
    assert meta["codecs"][0]["name"] == "sharding_indexed"
    assert meta["chunk_grid"]["configuration"]["chunk_shape"] == [100, 3, 4, 4]
    assert store.read("cube").radiance.values[:, 0, 0, 0].tolist() == list(range(200))
    for name in ("theta_i", "camera"):
        assert [p for p in (root / name / "c").rglob("*") if p.is_file()] == [root / name / "c" / "0"]
    files = sum(1 for p in store.path.rglob("*") if p.is_file())
    assert files < 20  # one per array, its metadata, the group's metadata and manifest


def test_a_group_read_by_shard_is_a_task_per_shard_with_the_same_values(tmp_path, monkeypatch):
    monkeypatch.setattr(layout, "SMALL_BYTES", 4096)
    monkeypatch.setattr(layout, "SHARD_BYTES", 100 * 192)  # 100 images of 192 B per shard
    monkeypatch.setattr(layout, "CHUNK_BYTES", 192)  # one image per stored chunk
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("cube", set_ordered_cube([list(range(250))]), fingerprint="s")
    stored = store.read("cube", friendly=False)
    by_shard = store.read("cube", friendly=False, chunks="shards")
    assert store.shard_chunks("cube") == {"image": 100, "wavelength": 3, "y": 4, "x": 4}
    assert stored.radiance.chunks[0] == (1,) * 250  # a task per image
    assert by_shard.radiance.chunks[0] == (100, 100, 50)
    xr.testing.assert_identical(by_shard.load(), stored.load())
    with pytest.raises(StoreError, match="'shards'"):
        store.read("cube", chunks="shard")


def test_bookkeeping_stays_out_of_the_attrs_and_records_are_kept_beside(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    files = {"radiance": [[f"rgb/img{i:05d}.png", 1000, 1] for i in range(5000)]}
    store.write("cube", set_ordered_cube([[1, 0]]), fingerprint="s", records={"frames_from": files})
    attrs = store.group_attrs("cube")
    assert "spectralize_manifest" not in attrs and "frames_from" not in attrs
    assert len((store.path / "cube" / "zarr.json").read_bytes()) < 8000
    assert store.record("cube", "frames_from") == files
    assert (store.path / "cube" / MANIFEST_FILE).is_file()
    assert "frames_from.json" in store.manifest("cube")["files"]  # checksummed like the data
    assert store.verify("cube") == []


def test_consolidated_metadata_opens_without_warnings_and_writes_to_netcdf(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("cube", set_ordered_cube([[2, 0], [1]]), fingerprint="s")
    text = xr.Dataset(coords={"channel": ("channel", np.array(["R", "G", "B"]))})
    text = text.assign(v=("channel", np.arange(3.0), {"clipped": False}))
    text.attrs["converged"] = True  # netCDF has no booleans: stored as 1
    store.write("raw/text", text, fingerprint="t")
    root = json.loads((store.path / "zarr.json").read_text())
    assert {"cube", "raw/text"} <= set(root["consolidated_metadata"]["metadata"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        tree = xr.open_datatree(str(store.path), engine="zarr")
        ds = xr.open_zarr(str(store.path), group="cube")
    tree.to_netcdf(tmp_path / "run.nc")
    back = xr.open_datatree(tmp_path / "run.nc")
    assert back["raw/text"].channel.values.tolist() == ["R", "G", "B"]
    assert back["raw/text"].attrs["converged"] == 1 and store.group_attrs("raw/text")["converged"]
    # per-image coordinates are one small chunk: where(drop=True) needs them in memory
    eager = xr.open_zarr(str(store.path), group="cube", chunks=None)
    assert eager.where(eager.theta_i < 15, drop=True).image.values.tolist() == [0, 1]
    assert ds.where(ds.theta_i.compute() < 15, drop=True).image.values.tolist() == [0, 1]


def test_a_store_of_the_first_layout_is_read_and_its_groups_get_other_fingerprints(tmp_path):
    from spectralize.store import compute_fingerprint

    store = RunStore.create(tmp_path / "run.zarr")
    store.write("cube", set_ordered_cube([[1, 0]]), fingerprint="s")
    group = store.path / "cube"
    manifest = json.loads((group / MANIFEST_FILE).read_text())
    meta = json.loads((group / "zarr.json").read_text())  # the first layout: manifest in attrs
    meta["attributes"]["spectralize_manifest"] = json.dumps(manifest)
    (group / "zarr.json").write_text(json.dumps(meta))
    (group / MANIFEST_FILE).unlink()
    assert store.manifest("cube") == manifest and store.verify("cube") == []
    assert store.first_layout_note() is None
    root = json.loads((store.path / "zarr.json").read_text())  # the first layout's root tag
    root["attributes"] = {"spectralize": {"format": "spectralize-run-store", "version": 1}}
    (store.path / "zarr.json").write_text(json.dumps(root))
    assert "every group this flow makes is recomputed" in RunStore.open(store.path).first_layout_note()
    assert store.read("cube").image.values.tolist() == [0, 1]
    payload = {"node": "n", "version": "1", "parameters": {}, "inputs": {}}  # no "layout"
    import hashlib

    old = hashlib.sha256(json.dumps(payload, sort_keys=True, separators=(",", ":")).encode()).hexdigest()
    assert compute_fingerprint("n", "1", {}, {}) != old


def test_a_large_variable_in_one_dask_chunk_is_stored_in_small_chunks_inside_its_shards(
    tmp_path, monkeypatch
):
    """A group computed as one dask chunk (a full run's ``hdr`` with tiny frames) is stored in
    chunks of at most CHUNK_BYTES along its first dim, inside shards: reading a few images
    reads their chunks, not the whole variable."""
    monkeypatch.setattr(layout, "SMALL_BYTES", 4096)
    monkeypatch.setattr(layout, "CHUNK_BYTES", 10 * 192)  # 10 images of 192 B per chunk
    monkeypatch.setattr(layout, "SHARD_BYTES", 100 * 192)
    cube = set_ordered_cube([list(range(200))]).chunk({"image": -1})  # one dask chunk
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("cube", cube, fingerprint="s")
    meta = json.loads((store.path / "cube" / "radiance" / "zarr.json").read_text())
    assert meta["chunk_grid"]["configuration"]["chunk_shape"] == [100, 3, 4, 4]  # the shard
    assert meta["codecs"][0]["configuration"]["chunk_shape"] == [10, 3, 4, 4]
    ds = store.read("cube", friendly=False)
    assert ds.radiance.chunks[0] == (10,) * 20  # dask reads chunk by chunk
    some = ds.radiance.isel(image=[3, 57])
    import dask

    (culled,) = dask.optimize(some.data)  # the graph as computed
    graph = dict(culled.__dask_graph__())
    reads = sorted(k[1] for k in graph if isinstance(k, tuple) and "open_dataset-radiance" in k[0])
    assert reads == [0, 5]  # the chunks of images 3 and 57, not all 20
    assert some.values[:, 0, 0, 0].tolist() == [3, 57]


def test_a_resumable_write_is_packed_like_a_write_in_one_piece_in_chunks_of_many_images(
    tmp_path, monkeypatch
):
    """Regions of unequal size (image sets in set order), the write killed after some of them
    and resumed, are packed with the chunks and shards a write of the whole cube in one piece
    gets: many images per stored chunk, so a reader's dask array is a task per chunk, not per
    image; the values bit-identical to that write's."""
    monkeypatch.setattr(layout, "SMALL_BYTES", 4096)
    monkeypatch.setattr(layout, "CHUNK_BYTES", 10 * 192)  # 10 images of 192 B per chunk
    monkeypatch.setattr(layout, "SHARD_BYTES", 100 * 192)
    rng = np.random.default_rng(3)
    labels = rng.permutation(250)
    sizes = np.diff([0, *sorted(rng.choice(np.arange(1, 250), 49, replace=False)), 250])
    values = rng.random((250, 3, 4, 4), dtype=np.float32)  # in set order, as computed

    def cube(fail_after=None):
        done = []

        def region(block):
            done.append(1)
            if fail_after is not None and len(done) > fail_after:
                raise RuntimeError("killed while writing")
            return block

        data = da.from_array(values, chunks=(tuple(sizes), 3, 4, 4)).map_blocks(region)
        return xr.Dataset(
            {"radiance": (("image", "wavelength", "y", "x"), data, {"units": "1"})},
            coords={"image": labels, "wavelength": ("wavelength", [450.0, 550.0, 650.0])},
        )

    store = RunStore.create(tmp_path / "run.zarr")
    with pytest.raises(RuntimeError, match="killed"):
        store.write("cube", cube(fail_after=20), fingerprint="s", resumable_along="image")
    messages = []
    store.write("cube", cube(), fingerprint="s", resumable_along="image", progress=messages.append)
    assert any("already written" in m for m in messages)  # resumed, not started over
    store.write("whole", cube().chunk({"image": -1}), fingerprint="w")  # in one piece
    packed, whole = (
        json.loads((store.path / g / "radiance" / "zarr.json").read_text()) for g in ("cube", "whole")
    )
    assert packed["codecs"][0]["configuration"]["chunk_shape"] == [10, 3, 4, 4]
    assert packed["codecs"] == whole["codecs"] and packed["chunk_grid"] == whole["chunk_grid"]
    read = store.read("cube", friendly=False)
    assert read.radiance.chunks[0] == (10,) * 25  # a task per stored chunk of 10 images
    expected = values[np.argsort(labels)]
    assert read.radiance.values.tobytes() == expected.tobytes()
    assert store.read("whole", friendly=False).radiance.values.tobytes() == expected.tobytes()
    assert store.verify("cube") == [] and store.validate() == []
