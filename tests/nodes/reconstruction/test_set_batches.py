"""Sets solved in batches (a run of many sets of tiny frames) give what each set's own task gives."""

import numpy as np
import pytest

from spectralize.nodes.reconstruction import set_reconstruction
from spectralize.nodes.reconstruction.set_reconstruction import (
    reconstruct_image_sets,
    reconstruct_seed_set,
)

from .test_set_reconstruction import reconstruction_inputs


@pytest.mark.slow  # two runs of every set (~15 s on 2 busy cores)
def test_batched_sets_equal_one_task_per_set(monkeypatch):
    hdr, bands, camera, sets, _ = reconstruction_inputs()
    settings = {"tolerance": 1e-2, "max_iterations": 3}
    seed = reconstruct_seed_set(hdr, bands, camera, sets, **settings)
    per_set = reconstruct_image_sets(hdr, bands, camera, sets, seed, **settings)
    owned_sets = [s for s in range(sets.sizes["set"]) if sets.owned.isel(set=s).any()]
    assert len(per_set.radiance.chunks[0]) == len(owned_sets)

    monkeypatch.setattr(set_reconstruction, "BATCH_SETS_ABOVE", 0)
    pixel = hdr.sizes["y"] * hdr.sizes["x"] * 4 * (camera.sizes["wavelength"] + 1)
    monkeypatch.setattr(set_reconstruction, "BATCH_BYTES", 7 * pixel)  # two sets of three a batch
    batched = reconstruct_image_sets(hdr, bands, camera, sets, seed, **settings)
    # fewer tasks: the seed set's chunk, then batches of whole sets of at most seven images
    assert len(batched.radiance.chunks[0]) < len(owned_sets)
    assert batched.radiance.chunks == batched.radiance.data.chunks
    np.testing.assert_array_equal(batched.image.values, per_set.image.values)
    np.testing.assert_array_equal(batched.image_set.values, per_set.image_set.values)
    per_set, batched = per_set.compute(), batched.compute()
    for name in ("radiance", "confidence", "iterations"):
        np.testing.assert_array_equal(batched[name].values, per_set[name].values, err_msg=name)


@pytest.mark.slow  # solves the seed set (~5 s)
def test_a_batch_reads_only_the_chunks_of_its_images(monkeypatch):
    """Each batch's task depends on the chunks of ``hdr`` that hold its sets' images, not on
    every chunk of the run (a full run's ~220 batches each built a graph over all of them)."""
    from spectralize.nodes.reconstruction.image_sets import set_members

    hdr, bands, camera, sets, _ = reconstruction_inputs()
    settings = {"tolerance": 1e-2, "max_iterations": 3}
    seed = reconstruct_seed_set(hdr, bands, camera, sets, **settings).compute()
    monkeypatch.setattr(set_reconstruction, "BATCH_SETS_ABOVE", 0)
    pixel = hdr.sizes["y"] * hdr.sizes["x"] * 4 * (camera.sizes["wavelength"] + 1)
    monkeypatch.setattr(set_reconstruction, "BATCH_BYTES", 7 * pixel)
    per_image = hdr.chunk({"image": 1})  # one chunk per image, as a store might hold them
    batched = reconstruct_image_sets(per_image, bands, camera, sets, seed, **settings)
    name = per_image["radiance"].data.name
    graph = batched.radiance.data.__dask_graph__()
    batches = [layer for layer in graph.layers if layer.startswith("solve-sets-")]
    assert len(batches) >= 2
    labels = per_image["image"].values
    for layer in batches:
        (task,) = graph.layers[layer].values()
        reads = {int(k[1]) for arg in task[1:] if isinstance(arg, list) for k in arg if k[0] == name}
        first, last = (int(v) for v in layer.split("-")[2:4])  # solve-sets-<first>-<last>-<token>
        solved = [i for i in np.unique(batched.image_set.values) if first <= i <= last]
        members = np.unique(np.concatenate([set_members(sets, int(i))[0] for i in solved]))
        assert reads == set(np.searchsorted(labels, members).tolist()), layer
