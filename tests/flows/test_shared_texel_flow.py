"""Issue 29 end to end: ``set_model="shared-texel"`` on the calibration's own illuminant.

A real Prefect btf run of the tiny simulated run: ``calibrate_spectral`` writes the measured
illuminant into ``calibration/spectral``, and ``reconstruct_image_sets`` (which the flow points
at that group, not at ``truth/camera``) refits every set of more than one image with it. The
flow's steps run without its HTML report, which this test does not read.
"""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.flows.pipelines import flow_inputs, get_flow, step_parameters
from spectralize.flows.runtime import run_steps
from spectralize.nodes.reconstruction.set_reconstruction import reconstruct_image_sets
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.schemas.run import SPECTRA_PRECISION
from spectralize.store import RunStore
from spectralize.store.precision import round_mantissa


@pytest.mark.slow
def test_btf_reconstructs_the_sets_with_shared_texels_on_the_calibration_s_illuminant(
    prefect_api, tmp_path
):
    store = RunStore.create(tmp_path / "run.zarr")
    run = simulate_run(get_recipe("tiny"))
    for group in flow_inputs("btf"):
        store.write(group, run[group], fingerprint=f"sim-{group}")

    steps = step_parameters(get_flow("btf").steps, {"reconstruct_image_sets.set_model": "shared-texel"})
    report = run_steps(store.path, steps, flow_name="btf")
    assert {s.node: s.status for s in report.steps}["reconstruct_image_sets"] == "ran"
    assert store.validate() == []
    calibration = store.read("calibration/spectral")
    white = store.read("raw/white_reference")
    np.testing.assert_allclose(
        calibration["illuminant"].values,
        white["illuminant"].sel(wavelength=calibration["wavelength"].values).values,
    )
    spectra = store.read("spectra")
    assert spectra.attrs["set_model"] == "shared-texel"
    shared_texel = spectra["radiance"].load()
    assert np.isfinite(shared_texel.values).all() and (shared_texel.values >= 0).all()

    # the same node on the same groups, every image solved on its own
    groups = {g: store.read(g) for g in ("hdr", "bands", "image_sets", "spectra_seed")}
    alone = reconstruct_image_sets(
        groups["hdr"],
        groups["bands"],
        calibration,
        groups["image_sets"],
        groups["spectra_seed"],
        set_model="independent",
    )
    assert alone.attrs["set_model"] == "independent"
    alone = alone["radiance"].load().sel(image=shared_texel["image"].values)
    sets = groups["image_sets"]
    members = np.asarray(sets["member"].values)
    seed = int(sets.attrs["seed_set"])
    owner = dict(zip(sets["image"].values.tolist(), sets["image_set"].values.tolist(), strict=True))
    refitted = [s for s in range(members.shape[0]) if s != seed and (members[s] >= 0).sum() > 1]
    assert refitted, "the tiny run has no set of more than one image besides the seed"
    for s in refitted:  # the set's own images refitted with shared texel shapes
        images = [int(i) for i in members[s] if i >= 0 and owner[int(i)] == s]
        got, independent = shared_texel.sel(image=images).values, alone.sel(image=images).values
        change = np.abs(got - independent).max() / np.abs(independent).max()
        assert change > 1e-3, (s, images, change)
    # the seed set's images are copied from spectra_seed (solved independently) in both,
    # stored at the cube's precision
    seed_images = [int(i) for i in members[seed] if i >= 0 and owner[int(i)] == seed]
    np.testing.assert_array_equal(
        shared_texel.sel(image=seed_images).values,
        round_mantissa(alone.sel(image=seed_images).values, SPECTRA_PRECISION.keepbits),
    )
