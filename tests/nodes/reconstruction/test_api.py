"""The xarray API: output layout, attrs, invariances and clear errors for bad input."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction import (
    BASELINE_METHODS,
    SOLVER_METHODS,
    reconstruct,
    reconstruct_baseline,
    reconstruct_spectra,
)
from spectralize.schemas.errors import ReconstructionError, SpectralizeError


@pytest.fixture
def scene(scene_factory):
    return scene_factory(size=20, n_wavelength=6, n_images=2, shading=True, noise=0.02,
                         rgb_noise=1e-3, shots={0: [0, 1, 2, 3, 4, 5], 1: [2]})


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
    assert out.attrs["method"] == "block-jacobi-pcg"
    assert out.attrs["iterations"] >= 1
    assert out.attrs["residual_history_length"] == out.attrs["iterations"] + 1
    assert out.attrs["gamma_hat"] == 20.0  # a set of two images
    assert out.attrs["final_relative_residual"] <= out.attrs["tolerance"]


def test_result_object_records_the_solve(scene):
    result = reconstruct_spectra(scene.rgb, scene.bands, scene.camera_matrix,
                                 method="paper-cg", max_iterations=5, tolerance=1e-12)
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
    shuffled = reconstruct(scene.rgb.transpose("channel", "x", "image", "y"),
                           scene.bands.transpose("y", "shot", "x"),
                           scene.camera_matrix.isel(channel=[2, 0, 1]).transpose(),
                           tolerance=1e-6)
    np.testing.assert_allclose(shuffled.values, reference.values, rtol=1e-4,
                               atol=1e-5 * float(np.abs(reference).max()))


def test_result_scales_with_radiance_and_ignores_the_gain_of_c(scene):
    reference = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, tolerance=1e-6)
    dim = reconstruct(scene.rgb * 0.01, scene.bands * 0.01, scene.camera_matrix,
                      tolerance=1e-6)
    np.testing.assert_allclose(dim.values, 0.01 * reference.values, rtol=1e-3,
                               atol=1e-6 * float(np.abs(reference).max()))
    gain = reconstruct(scene.rgb * 7.0, scene.bands, scene.camera_matrix * 7.0,
                       tolerance=1e-6)
    np.testing.assert_allclose(gain.values, reference.values, rtol=1e-3,
                               atol=1e-5 * float(np.abs(reference).max()))


def test_every_baseline_runs_through_the_dispatcher(scene):
    for method in BASELINE_METHODS:
        out = reconstruct_baseline(scene.rgb, scene.bands, scene.camera_matrix, method=method)
        assert out.dims == ("image", "wavelength", "y", "x")
        assert out.dtype == np.float32
        assert out.attrs["method"] == method
        assert np.isfinite(out.values).all()


# -- bad input ------------------------------------------------------------------------------
def _raises(match, *args, **kwargs):
    with pytest.raises(ReconstructionError, match=match) as info:
        reconstruct(*args, **kwargs)
    assert isinstance(info.value, ValueError) and isinstance(info.value, SpectralizeError)
    return str(info.value)


def test_unknown_method_lists_the_known_ones(scene):
    message = _raises("unknown method 'multigrid'", scene.rgb, scene.bands,
                      scene.camera_matrix, method="multigrid")
    for name in SOLVER_METHODS:
        assert name in message
    with pytest.raises(ReconstructionError, match="pseudo-inverse"):
        reconstruct_baseline(scene.rgb, scene.bands, scene.camera_matrix, method="nope")


def test_image_size_mismatch(scene):
    message = _raises("bands: expected the rgb image size", scene.rgb,
                      scene.bands.isel(x=slice(0, 18)), scene.camera_matrix)
    assert "x: 18" in message


def test_wrong_dims_and_channel_count(scene):
    _raises(r"rgb: expected dims \('image', 'y', 'x', 'channel'\)",
            scene.rgb.isel(image=0), scene.bands, scene.camera_matrix)
    _raises("rgb: expected 3 channels, found 2", scene.rgb.isel(channel=[0, 1]),
            scene.bands, scene.camera_matrix.isel(channel=[0, 1]))
    _raises("camera_matrix: expected dims", scene.rgb, scene.bands,
            scene.camera_matrix.rename(wavelength="band"))
    _raises("rgb: expected an xarray.DataArray", scene.rgb.values, scene.bands,
            scene.camera_matrix)


def test_wavelength_mismatch(scene):
    shifted = scene.bands.assign_coords(
        wavelength=("shot", scene.bands["wavelength"].values + np.r_[0, 0, 0, 0, 0, 5.0, 0]))
    message = _raises("not on camera_matrix's wavelength grid", scene.rgb, shifted,
                      scene.camera_matrix)
    assert "have no band shot" in message  # the wavelength that lost its shot, too
    extra = xr.concat([scene.camera_matrix,
                       scene.camera_matrix.isel(wavelength=[-1]).assign_coords(
                           wavelength=[700.0])], dim="wavelength")
    _raises(r"wavelengths \[700.0\] nm have no band shot", scene.rgb, scene.bands, extra)
    _raises("expected a coordinate 'filter_size'", scene.rgb,
            scene.bands.drop_vars("filter_size"), scene.camera_matrix)


@pytest.mark.parametrize("array", ["rgb", "bands", "camera_matrix"])
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_and_inf(scene, array, bad):
    arrays = {"rgb": scene.rgb.copy(), "bands": scene.bands.copy(),
              "camera_matrix": scene.camera_matrix.copy()}
    arrays[array][(0,) * arrays[array].ndim] = bad
    message = _raises(f"{array}: expected finite values", arrays["rgb"], arrays["bands"],
                      arrays["camera_matrix"])
    assert ("1 NaN" if np.isnan(bad) else "1 inf") in message


def test_filter_larger_than_the_image(scene):
    big = scene.bands.assign_coords(filter_size=("shot", np.r_[3.0, 3, 3, 3, 3, 10.0, 3]))
    message = _raises("larger than the image allows", scene.rgb, big, scene.camera_matrix)
    assert "10.0" in message and "s_i <= 9.5 px" in message
    _raises("filter_size must be finite and > 0", scene.rgb,
            scene.bands.assign_coords(filter_size=("shot", np.r_[3.0, 3, 3, 3, 3, 0, 3])),
            scene.camera_matrix)


def test_empty_set(scene):
    _raises("rgb: is empty", scene.rgb.isel(image=slice(0, 0)), scene.bands,
            scene.camera_matrix)
    _raises("bands: is empty", scene.rgb, scene.bands.isel(shot=slice(0, 0)),
            scene.camera_matrix)


def test_shot_of_an_unknown_image(scene):
    bands = scene.bands.assign_coords(image=("shot", np.r_[0, 0, 0, 0, 0, 0, 5]))
    _raises(r"names images \[5\] that rgb does not have", scene.rgb, bands,
            scene.camera_matrix)


def test_bad_options_and_initial(scene):
    _raises("alpha_hat: expected a finite number > 0", scene.rgb, scene.bands,
            scene.camera_matrix, alpha_hat=-1.0)
    _raises("k: expected an integer >= 1", scene.rgb, scene.bands, scene.camera_matrix, k=0)
    wrong = xr.zeros_like(scene.rgb.isel(channel=0)).expand_dims(wavelength=3)
    _raises("initial: expected shape", scene.rgb, scene.bands, scene.camera_matrix,
            initial=wrong.transpose("image", "wavelength", "y", "x"))
