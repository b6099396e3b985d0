import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.evaluation.pixel_metrics import normalised_rmse
from spectralize.nodes.reconstruction.image_sets import select_image_sets
from spectralize.nodes.reconstruction.set_reconstruction import (
    reconstruct_image_sets,
    reconstruct_seed_set,
)
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.schemas import validate_dataset
from spectralize.schemas.run import SPECTRA, SPECTRA_SEED


def reconstruction_inputs(relative_noise=0.2, seed=0):
    """HDR RGB through the true C and noisy bands at the shots, from the tiny run's truth."""
    run = simulate_run(get_recipe("tiny"))
    truth = run["truth/spectra"].load()
    camera = run["truth/camera"].load()
    raw = run["raw/spectral"].load()
    rgb = xr.dot(camera.camera_matrix, truth.radiance, dim="wavelength")
    per_image = {c: truth[c] for c in truth.coords if truth[c].dims == ("image",)}
    hdr = xr.Dataset(
        {
            "radiance": rgb.transpose("image", "y", "x", "channel")
            .astype("float32")
            .assign_attrs(units="1", long_name="relative RGB radiance")
        },
        coords=per_image,
    )
    planes = np.stack(
        [
            truth.radiance.sel(image=i, wavelength=w).values
            for i, w in zip(raw.image.values, raw.wavelength.values, strict=True)
        ]
    )
    noise = np.random.default_rng(seed).normal(0, 1, planes.shape)
    noisy = planes + noise * planes.mean(axis=(1, 2), keepdims=True) * relative_noise
    bands = xr.Dataset(
        {"radiance": (("shot", "y", "x"), noisy.astype("float32"), {"units": "1"})},
        coords={
            name: raw[name]
            for name in ("wavelength", "image", "filter_size", "exposure_time", "rotation", "led")
        },
    )
    sets = select_image_sets(run["raw/rgb"], raw, others_per_set=3)
    return hdr, bands, camera, sets, truth


@pytest.fixture(scope="module")
def solved():
    hdr, bands, camera, sets, truth = reconstruction_inputs()
    seed = reconstruct_seed_set(hdr, bands, camera, sets)
    cube = reconstruct_image_sets(hdr, bands, camera, sets, seed)
    return hdr, sets, truth, seed, cube


def test_seed_set_is_solved_cold_and_follows_the_contract(solved):
    _, sets, _, seed, _ = solved
    assert seed.attrs["seed_set"] == sets.attrs["seed_set"]
    assert int(seed.iterations.min()) > 0 and seed.iterations.dims == ("image",)
    assert validate_dataset(seed, SPECTRA_SEED) == []


def test_cube_is_lazy_one_chunk_per_set_and_holds_every_image_once(solved):
    hdr, sets, _, _, cube = solved
    assert cube.radiance.chunks is not None
    owned_sets = [s for s in range(sets.sizes["set"]) if sets.owned.isel(set=s).any()]
    assert len(cube.radiance.chunks[0]) == len(owned_sets)
    assert sorted(cube.image.values.tolist()) == sorted(hdr.image.values.tolist())
    assert validate_dataset(cube, SPECTRA) == []


def test_images_with_and_without_bands_are_reconstructed(solved):
    _, sets, truth, _, cube = solved
    cube = cube.compute()
    error = normalised_rmse(cube.radiance, truth.radiance.sel(image=cube.image))
    with_bands = sets.has_bands.sel(image=cube.image)
    assert float(error.where(with_bands).median()) < 0.15
    assert float(error.where(~with_bands).median()) < 0.2
    # warm-started sets record their own iterations; the seed's are the cold start
    seed_images = cube.image_set == cube.attrs["seed_set"]
    assert (cube.iterations.where(seed_images, drop=True) == cube.attrs["seed_iterations"]).all()


def test_method_takes_exactly_the_table_and_fails_at_graph_check():
    from spectralize.engine import Step, check_graph
    from spectralize.nodes.reconstruction import BASELINE_METHODS, RECONSTRUCTION_METHODS
    from spectralize.nodes.reconstruction.declarations import (
        RECONSTRUCT_IMAGE_SETS,
        RECONSTRUCT_SEED_SET,
    )
    from spectralize.schemas import PipelineError

    for node in (RECONSTRUCT_SEED_SET, RECONSTRUCT_IMAGE_SETS):
        # the production methods; the comparison baselines are not the nodes'
        assert set(node.parameter_choices()["method"]) == set(RECONSTRUCTION_METHODS)
        assert not set(node.parameter_choices()["method"]) & set(BASELINE_METHODS)
        for method in RECONSTRUCTION_METHODS:
            assert node.parse_parameters({"method": method}).method == method
        assert node.parse_parameters({"prior": 0.3}).prior == 0.3
    available = {
        "hdr": "hdr",
        "bands": "bands",
        "camera_matrix": "camera_matrix",
        "image_sets": "image_sets",
        "spectra_seed": "spectra_seed",
        "endmember_library": "endmember_library",
    }
    with pytest.raises(PipelineError) as info:
        check_graph(
            [Step("reconstruct_image_sets", parameters={"method": "fastest"})], available=available
        )
    message = str(info.value)
    assert "reconstruct_image_sets.method" in message and "'fastest'" in message
    for method in RECONSTRUCTION_METHODS:
        assert repr(method) in message


def test_the_nodes_solver_settings_default_to_the_methods_preset():
    """The nodes and ``reconstruct`` read one dict: a solver setting the node leaves None is
    the method's (no iteration limit or neighbour weight of the node's own)."""
    from spectralize.nodes.reconstruction import DEFAULT_METHOD
    from spectralize.nodes.reconstruction.declarations import (
        RECONSTRUCT_IMAGE_SETS,
        RECONSTRUCT_SEED_SET,
    )
    from spectralize.nodes.reconstruction.methods import RECONSTRUCTION_METHODS
    from spectralize.nodes.reconstruction.set_reconstruction import node_method

    for node in (RECONSTRUCT_SEED_SET, RECONSTRUCT_IMAGE_SETS):
        parameters = node.parse_parameters({})
        assert parameters.method == DEFAULT_METHOD
        for name in ("gamma_hat", "tolerance", "max_iterations", "k", "prior", "set_model"):
            assert getattr(parameters, name) is None, name
    unset = dict.fromkeys(("gamma_hat", "tolerance", "max_iterations", "k", "prior", "set_model"))
    resolved = node_method(DEFAULT_METHOD, **unset)
    assert dict(resolved.given) == {}  # reconstruct takes the preset's
    assert dict(resolved.settings) == dict(RECONSTRUCTION_METHODS[DEFAULT_METHOD].settings)
    # a solver parameter given is laid over the preset; the solver parameters do not reach a
    # method without them (an estimator), as their descriptions say
    given = node_method("block-jacobi-pcg", **{**unset, "k": 4, "tolerance": 1e-2})
    assert dict(given.given) == {"tolerance": 1e-2, "k": 4} and given.settings["prior"] == 0.0
    assert dict(node_method("endmember-mixture", **{**unset, "k": 4}).given) == {}


def test_prior_is_a_set_parameter_and_checked_against_the_method():
    from spectralize.schemas import ReconstructionError

    hdr, bands, camera, sets, _ = reconstruction_inputs()
    options = {"method": "guided-prior-pcg", "max_iterations": 30}
    default = reconstruct_seed_set(hdr, bands, camera, sets, **options)
    strong = reconstruct_seed_set(hdr, bands, camera, sets, prior=2.0, **options)
    assert strong.attrs["prior"] == 2.0 and "prior" not in default.attrs
    assert strong.radiance.attrs["prior"] == 2.0 and default.radiance.attrs["prior"] == 0.1
    difference = float(np.abs(strong.radiance - default.radiance).max())
    assert difference > 1e-3 * float(np.abs(default.radiance).max())
    with pytest.raises(ReconstructionError, match="method 'paper-cg' has no prior"):
        reconstruct_seed_set(hdr, bands, camera, sets, method="paper-cg", prior=0.1)
    with pytest.raises(ReconstructionError, match="has no prior"):
        reconstruct_image_sets(hdr, bands, camera, sets, default, method="wiener", prior=0.1)


def test_a_baseline_reconstructs_the_sets_too():
    hdr, bands, camera, sets, truth = reconstruction_inputs()
    seed = reconstruct_seed_set(hdr, bands, camera, sets, method="filtered-projected")
    assert (seed.iterations == 0).all() and seed.radiance.attrs["method"] == "filtered-projected"
    cube = reconstruct_image_sets(hdr, bands, camera, sets, seed, method="filtered-projected").compute()
    assert np.isfinite(cube.radiance.values).all()
    assert (cube.iterations == 0).all()


def test_spectra_group_carries_a_confidence_that_tracks_the_error(solved):
    from scipy.stats import spearmanr

    _, _, truth, _, cube = solved
    cube = cube.compute()
    assert cube.confidence.dims == ("image", "y", "x") and cube.confidence.dtype == np.float32
    assert validate_dataset(cube, SPECTRA) == []
    assert float(cube.confidence.min()) >= 0 and np.isfinite(cube.confidence.values).all()
    # the confidence estimates the nRMSE (per-pixel RMSE / the image's mean): compared with it
    error = normalised_rmse(cube.radiance, truth.radiance.sel(image=cube.image))
    error = error.transpose(*cube.confidence.dims).values
    assert spearmanr(cube.confidence.values.ravel(), error.ravel()).statistic > 0.2


@pytest.mark.slow
def test_seed_confidence_is_solved_with_the_seed_and_passed_on(solved):
    hdr, sets, _, seed, cube = solved
    cube = cube.compute()
    assert seed.confidence.dims == ("image", "y", "x") and seed.confidence.dtype == np.float32
    seed_images = cube.image.where(cube.image_set == sets.attrs["seed_set"], drop=True).values
    assert seed_images.size > 0
    kept = seed.confidence.sel(image=seed_images).values
    assert np.array_equal(cube.confidence.sel(image=seed_images).values, kept)
    # a seed group written before it kept a confidence: the spread is computed again from
    # the seed's spectra; close to the solver's own (same neighbourhoods, searched anew)
    _, bands, camera, _, _ = reconstruction_inputs()
    older = reconstruct_image_sets(hdr, bands, camera, sets, seed.drop_vars("confidence")).compute()
    again = older.confidence.sel(image=seed_images).values
    assert np.isfinite(again).all() and again.shape == kept.shape
    assert np.corrcoef(again.ravel(), kept.ravel())[0, 1] > 0.8
