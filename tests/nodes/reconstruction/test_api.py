"""The xarray API: output layout, attrs, invariances and clear errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction import (
    BASELINE_METHODS,
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
    reconstruct,
)
from spectralize.nodes.reconstruction.methods import RUN_INPUTS, SETUP_OPTIONS, get_method
from spectralize.schemas.errors import ReconstructionError, SpectralizeError

EVERY_METHOD = {**RECONSTRUCTION_METHODS, **BASELINE_METHODS}


@pytest.fixture
def scene(scene_factory):
    return scene_factory(
        size=20,
        n_wavelength=6,
        n_images=2,
        shading=True,
        noise=0.02,
        rgb_noise=1e-3,
        shots={0: [0, 1, 2, 3, 4, 5], 1: [2]},
    )


def test_output_dims_dtype_coords_and_attrs(scene):
    rgb = scene.rgb.assign_coords(image=[10, 11], rotation=("image", [3, 4]))
    bands = scene.bands.assign_coords(image=("shot", scene.bands["image"].values + 10))
    out = reconstruct(rgb, bands, scene.camera_matrix)
    assert out.dims == ("image", "wavelength", "y", "x")
    assert out.shape == (2, 6, 20, 20)
    assert out.dtype == np.float32
    np.testing.assert_allclose(out["wavelength"], scene.camera_matrix["wavelength"])
    assert out["wavelength"].attrs["units"] == "nm"
    assert out["image"].values.tolist() == [10, 11]
    assert out["rotation"].values.tolist() == [3, 4]
    assert out.attrs["units"] == "1"
    assert "long_name" in out.attrs
    assert out.attrs["method"] == DEFAULT_METHOD == "natural-prior-pcg"
    assert out.attrs["iterations"] >= 1
    # the default's iterations are its CG iterations plus those of its S >= 0 refinement
    cg_iterations = out.attrs["iterations"] - out.attrs["projected_iterations"]
    assert out.attrs["residual_history_length"] == cg_iterations + 1
    assert out.attrs["gamma_hat"] == 20.0  # a set of two images
    assert out.attrs["final_relative_residual"] <= out.attrs["tolerance"]


def test_result_object_records_the_solve(scene):
    result = reconstruct(
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        method="paper-cg",
        max_iterations=5,
        tolerance=1e-12,
        full_output=True,
    )
    assert result.iterations == 5 and not result.converged
    assert len(result.residual_history) == 6
    assert result.wall_time >= result.setup_time > 0
    assert result.spectra.attrs["converged"] == 0


def test_single_image_uses_gamma_hat_one(scene_factory):
    single = scene_factory(size=16, n_wavelength=4)
    out = reconstruct(single.rgb, single.bands, single.camera_matrix)
    assert out.attrs["gamma_hat"] == 1.0


def test_inputs_in_any_dim_order_and_channel_order(scene):
    reference = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, tolerance=1e-6)
    shuffled = reconstruct(
        scene.rgb.transpose("channel", "x", "image", "y"),
        scene.bands.transpose("y", "shot", "x"),
        scene.camera_matrix.isel(channel=[2, 0, 1]).transpose(),
        tolerance=1e-6,
    )
    np.testing.assert_allclose(
        shuffled.values, reference.values, rtol=1e-4, atol=1e-5 * float(np.abs(reference).max())
    )


def test_result_scales_with_radiance_and_ignores_the_gain_of_c(scene):
    reference = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, tolerance=1e-6)
    dim = reconstruct(scene.rgb * 0.01, scene.bands * 0.01, scene.camera_matrix, tolerance=1e-6)
    np.testing.assert_allclose(
        dim.values, 0.01 * reference.values, rtol=1e-3, atol=1e-6 * float(np.abs(reference).max())
    )
    gain = reconstruct(scene.rgb * 7.0, scene.bands, scene.camera_matrix * 7.0, tolerance=1e-6)
    np.testing.assert_allclose(
        gain.values, reference.values, rtol=1e-3, atol=1e-5 * float(np.abs(reference).max())
    )


@pytest.mark.parametrize("method", sorted(EVERY_METHOD))
def test_every_method_of_the_tables_runs_through_reconstruct(scene, method):
    record = get_method(method)
    assert record.name == method and record.kind in ("solver", "baseline", "estimator")
    result = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method=method, full_output=True)
    out = result.spectra
    assert out.dims == ("image", "wavelength", "y", "x")
    assert out.shape == (2, 6, 20, 20)
    assert out.dtype == np.float32
    assert out.attrs["method"] == result.method == method
    assert np.isfinite(out.values).all()
    if record.kind == "solver":
        assert result.iterations >= 1 and result.problem is not None
        assert result.problem.dtype == record.dtype
        assert out.attrs["tolerance"] == record.defaults()["tolerance"]  # the method's own
        assert out.attrs["tolerance"] == (
            3e-3 if method in ("mixture-prior-pcg", "natural-prior-pcg") else 1e-3
        )
    else:
        assert result.iterations == 0 and result.problem is None
    # every setting of the method is reachable and recorded (a set without the illuminant:
    # the set model applied is "independent", whatever the preset's)
    for name, default in record.defaults().items():
        if isinstance(default, int | float | str) and name != "gamma_hat":
            assert out.attrs[name] == ("independent" if name == "set_model" else default), name


@pytest.mark.parametrize("method", sorted(EVERY_METHOD))
def test_every_preset_holds_every_setting(method):
    """One dict per method holds all its settings: a run never falls back on a function's
    own keyword default (only the run-time inputs are no settings)."""
    record = get_method(method)
    assert set(record.settings) == set(record.options) - set(RUN_INPUTS)
    if record.kind == "solver":
        assert set(SETUP_OPTIONS) <= set(record.settings)
    assert record.defaults() == {name: record.settings.get(name) for name in record.options}


def test_the_presets_settings():
    assert RECONSTRUCTION_METHODS["guided-prior-pcg"].settings["prior"] == 0.1
    assert RECONSTRUCTION_METHODS["block-jacobi-pcg"].settings["prior"] == 0.0
    # the two presets of eq. 1's PCG differ in the prior alone, the prior PCG's in its priors
    # and the solve's stopping
    for pair, differ in (
        (("guided-prior-pcg", "block-jacobi-pcg"), {"prior"}),
        (
            ("mixture-prior-pcg", "spectral-prior-pcg"),
            {"prior", "prior_weighting", "prior_source", "tolerance", "projected_iterations"},
        ),
    ):
        a, b = (RECONSTRUCTION_METHODS[name].settings for name in pair)
        assert {name for name in a if a[name] != b[name]} == differ
    assert {
        "alpha_hat",
        "beta_hat",
        "gamma_hat",
        "k",
        "centre_spacing",
        "normalize_camera_matrix",
        "tolerance",
        "max_iterations",
        "initial",
        "callback",
    } <= set(RECONSTRUCTION_METHODS["paper-cg"].options)
    assert set(BASELINE_METHODS["guided-projected"].options) == {"window_scale", "epsilon"}
    assert set(BASELINE_METHODS["wiener"].options) == {"relative_noise"}
    assert BASELINE_METHODS["pseudo-inverse"].options == {}


def test_production_methods_and_baselines_are_apart():
    assert not set(RECONSTRUCTION_METHODS) & set(BASELINE_METHODS)
    assert {record.kind for record in BASELINE_METHODS.values()} == {"baseline"}
    assert {record.kind for record in RECONSTRUCTION_METHODS.values()} == {"solver", "estimator"}
    assert DEFAULT_METHOD in RECONSTRUCTION_METHODS
    assert "material-prior-pcg" not in EVERY_METHOD  # retired: spectral-prior-pcg, spectral_prior=0


# -- bad input ------------------------------------------------------------------------------
def _raises(match, *args, **kwargs):
    with pytest.raises(ReconstructionError, match=match) as info:
        reconstruct(*args, **kwargs)
    assert isinstance(info.value, ValueError) and isinstance(info.value, SpectralizeError)
    return str(info.value)


def test_unknown_method_lists_the_known_ones(scene):
    message = _raises(
        "unknown method 'multigrid'", scene.rgb, scene.bands, scene.camera_matrix, method="multigrid"
    )
    for name in EVERY_METHOD:  # production methods and baselines
        assert name in message


def test_unknown_option_lists_the_methods_options(scene):
    message = _raises(
        r"method 'paper-cg': unknown option\(s\) \['prior'\]",
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        method="paper-cg",
        prior=0.1,
    )
    for name in RECONSTRUCTION_METHODS["paper-cg"].options:
        assert name in message
    assert "'prior' is an option of" in message and "guided-prior-pcg" in message
    message = _raises(
        r"unknown option\(s\) \['gamma_hat', 'tolerance'\]",
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        method="wiener",
        tolerance=1e-3,
        gamma_hat=1.0,
    )
    assert "its options are: relative_noise" in message
    _raises("unknown option", scene.rgb, scene.bands, scene.camera_matrix, smoothness=3)


def test_image_size_mismatch(scene):
    message = _raises(
        "bands: expected the rgb image size",
        scene.rgb,
        scene.bands.isel(x=slice(0, 18)),
        scene.camera_matrix,
    )
    assert "x: 18" in message


def test_wrong_dims_and_channel_count(scene):
    _raises(
        r"rgb: expected dims \('image', 'y', 'x', 'channel'\)",
        scene.rgb.isel(image=0).rename(x="column"),
        scene.bands,
        scene.camera_matrix,
    )
    # one (y, x, channel) image is a valid form, but these bands pair with two images
    _raises(
        r"names images \[1\] that rgb does not have",
        scene.rgb.isel(image=0),
        scene.bands,
        scene.camera_matrix,
    )
    _raises(
        "rgb: expected 3 channels, found 2",
        scene.rgb.isel(channel=[0, 1]),
        scene.bands,
        scene.camera_matrix.isel(channel=[0, 1]),
    )
    _raises(
        "camera_matrix: expected dims",
        scene.rgb,
        scene.bands,
        scene.camera_matrix.rename(wavelength="band"),
    )
    _raises("rgb: expected an xarray.DataArray", scene.rgb.values, scene.bands, scene.camera_matrix)


def test_wavelength_mismatch_names_both_grids(scene):
    shifted = scene.bands.assign_coords(
        wavelength=("shot", scene.bands["wavelength"].values + np.r_[0, 0, 0, 0, 0, 5.0, 0])
    )
    message = _raises("not on camera_matrix's wavelength grid", scene.rgb, shifted, scene.camera_matrix)
    grid = scene.camera_matrix["wavelength"].values
    assert str(grid.tolist()) in message  # the camera matrix's grid
    assert str(np.unique(shifted["wavelength"].values).tolist()) in message  # the bands'
    _raises(
        "expected a coordinate 'filter_size'",
        scene.rgb,
        scene.bands.drop_vars("filter_size"),
        scene.camera_matrix,
    )


def test_a_wider_camera_matrix_grid_is_restricted_to_the_bands(scene):
    """C on 400-730 nm for bands on a grid inside it: the same result as C on the bands'
    wavelengths exactly, and the spectra live on the bands' wavelengths."""
    exact = scene.camera_matrix
    step = float(np.diff(exact["wavelength"].values)[0])
    below = exact.isel(wavelength=[0, 0]).assign_coords(
        wavelength=exact["wavelength"].values[0] - step * np.array([2.0, 1.0])
    )
    above = exact.isel(wavelength=[-1]).assign_coords(wavelength=[exact["wavelength"].values[-1] + step])
    wider = xr.concat([above, exact, below], dim="wavelength")  # unsorted, too
    reference = reconstruct(scene.rgb, scene.bands, exact)
    restricted = reconstruct(scene.rgb, scene.bands, wider)
    np.testing.assert_array_equal(restricted["wavelength"].values, exact["wavelength"].values)
    np.testing.assert_allclose(
        restricted.values, reference.values, rtol=1e-6, atol=1e-6 * float(np.abs(reference).max())
    )
    # a grid that does not cover the bands is still an error, naming both grids
    narrow = exact.isel(wavelength=slice(0, -1))
    message = _raises("not on camera_matrix's wavelength grid", scene.rgb, scene.bands, narrow)
    assert str(narrow["wavelength"].values.tolist()) in message
    assert str(exact["wavelength"].values.tolist()) in message


@pytest.mark.parametrize("array", ["rgb", "bands", "camera_matrix"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_and_inf(scene, array, bad):
    arrays = {
        "rgb": scene.rgb.copy(),
        "bands": scene.bands.copy(),
        "camera_matrix": scene.camera_matrix.copy(),
    }
    arrays[array][(0,) * arrays[array].ndim] = bad
    message = _raises(
        f"{array}: expected finite values", arrays["rgb"], arrays["bands"], arrays["camera_matrix"]
    )
    assert ("1 NaN" if np.isnan(bad) else "1 inf") in message


def test_filter_larger_than_the_image(scene):
    big = scene.bands.assign_coords(filter_size=("shot", np.r_[3.0, 3, 3, 3, 3, 10.0, 3]))
    message = _raises("larger than the image allows", scene.rgb, big, scene.camera_matrix)
    assert "10.0" in message and "s_i <= 9.5 px" in message
    _raises(
        "filter_size must be finite and > 0",
        scene.rgb,
        scene.bands.assign_coords(filter_size=("shot", np.r_[3.0, 3, 3, 3, 3, 0, 3])),
        scene.camera_matrix,
    )


def test_empty_set(scene):
    _raises("rgb: is empty", scene.rgb.isel(image=slice(0, 0)), scene.bands, scene.camera_matrix)
    _raises("bands: is empty", scene.rgb, scene.bands.isel(shot=slice(0, 0)), scene.camera_matrix)


def test_shot_of_an_unknown_image(scene):
    bands = scene.bands.assign_coords(image=("shot", np.r_[0, 0, 0, 0, 0, 0, 5]))
    _raises(r"names images \[5\] that rgb does not have", scene.rgb, bands, scene.camera_matrix)


def test_bad_options_and_initial(scene):
    _raises(
        "alpha_hat: expected a finite number > 0",
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        alpha_hat=-1.0,
    )
    _raises("k: expected an integer >= 1", scene.rgb, scene.bands, scene.camera_matrix, k=0)
    data = (scene.rgb, scene.bands, scene.camera_matrix)
    _raises("spectral_prior: expected a finite number >= 0", *data, spectral_prior=-0.1)
    _raises("covariance_floor: expected a finite number > 0", *data, covariance_floor=0.0)
    _raises("projected_iterations: expected an integer >= 0", *data, projected_iterations=2.5)
    wrong = xr.zeros_like(scene.rgb.isel(channel=0)).expand_dims(wavelength=3)
    _raises(
        "initial: expected shape",
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        initial=wrong.transpose("image", "wavelength", "y", "x"),
    )


# -- single-image forms ----------------------------------------------------------------------
@pytest.fixture
def single(scene_factory):
    return scene_factory(size=20, n_wavelength=6, shading=True, noise=0.02, rgb_noise=1e-3)


def _band_cube(scene):
    """The one image's shots as a (y, x, wavelength) band cube."""
    shots = scene.bands
    return xr.DataArray(
        shots.transpose("y", "x", "shot").values,
        dims=("y", "x", "wavelength"),
        coords={"wavelength": shots["wavelength"].values},
    )


@pytest.mark.parametrize("method", ["block-jacobi-pcg", "paper-cg", "guided-projected"])
def test_one_image_as_band_cube_and_rgb_image_gives_the_shot_form_result(single, method):
    reference = reconstruct(single.rgb, single.bands, single.camera_matrix, method=method)
    rgb_image = single.rgb.isel(image=0).transpose("channel", "y", "x")  # (y, x, channel)
    cube = _band_cube(single)
    out = reconstruct(rgb_image, cube, single.camera_matrix, method=method, filter_size=3.0)
    assert out.dims == ("wavelength", "y", "x")  # like the rgb given: one image
    np.testing.assert_array_equal(out.values, reference.isel(image=0).values)
    # filter sizes as a coordinate along wavelength, with the set-form rgb
    sized = cube.assign_coords(filter_size=("wavelength", np.full(6, 3.0)))
    as_set = reconstruct(
        single.rgb, sized.transpose("wavelength", "x", "y"), single.camera_matrix, method=method
    )
    assert as_set.dims == ("image", "wavelength", "y", "x")
    np.testing.assert_array_equal(as_set.values, reference.values)
    # a (y, x, channel) image with the shot form of the bands
    mixed = reconstruct(rgb_image, single.bands, single.camera_matrix, method=method)
    np.testing.assert_array_equal(mixed.values, reference.isel(image=0).values)


def test_band_cube_errors(single, scene):
    cube = _band_cube(single)
    rgb_image = single.rgb.isel(image=0)
    _raises("needs the filter size", rgb_image, cube, single.camera_matrix)
    _raises(
        "given both as an option and as a coordinate",
        rgb_image,
        cube.assign_coords(filter_size=("wavelength", np.full(6, 3.0))),
        single.camera_matrix,
        filter_size=3.0,
    )
    _raises(
        r"expected one number or 6 \(one per wavelength\)",
        rgb_image,
        cube,
        single.camera_matrix,
        filter_size=[3.0, 3.0],
    )
    _raises(
        "a \\(y, x, wavelength\\) band cube is one image's bands, but rgb has 2 images",
        scene.rgb,
        cube,
        scene.camera_matrix,
        filter_size=3.0,
    )
    _raises(
        "filter_size: only for bands given as a \\(y, x, wavelength\\) band cube",
        single.rgb,
        single.bands,
        single.camera_matrix,
        filter_size=3.0,
    )
