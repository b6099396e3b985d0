"""The illuminant input and the ``set_model`` setting (issue 29 part 2): a solver's spectra of
a set refitted with per-texel shapes shared by the set's images."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction import DEFAULT_METHOD, inputs_from_xarray, reconstruct
from spectralize.nodes.reconstruction.estimators.shared_texel import shared_texel_refine
from spectralize.nodes.reconstruction.inputs import ReconstructionInputs
from spectralize.nodes.reconstruction.methods import RECONSTRUCTION_METHODS, SET_MODELS
from spectralize.nodes.reconstruction.set_reconstruction import reconstruct_seed_set
from spectralize.schemas import ReconstructionError

from .conftest import camera_matrix_for, make_scene


def _light(wavelength: np.ndarray) -> np.ndarray:
    """A smooth LED-like relative spectrum."""
    return np.exp(-0.5 * ((wavelength - 560.0) / 70.0) ** 2) + 0.2


@pytest.fixture(scope="module")
def set_scene():
    """Three images (image 0 with every band), shaded differently, small."""
    return make_scene(size=14, n_wavelength=6, n_images=3, shading=True, noise=0.1, seed=3)


@pytest.fixture(scope="module")
def plain(set_scene):
    """The default's solve of ``set_scene`` with set model ``"independent"``."""
    light = _light(_wavelength(set_scene))
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    return reconstruct(
        *args, illuminant=light, set_model="independent", full_output=True, confidence=False
    )


def _wavelength(scene) -> np.ndarray:
    return np.asarray(scene.camera_matrix["wavelength"].values, dtype=float)


# -- the illuminant input ------------------------------------------------------------------
def test_the_illuminant_is_checked_and_named(set_scene):
    wl = _wavelength(set_scene)
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    good = inputs_from_xarray(*args, illuminant=_light(wl))
    assert good.illuminant.shape == (wl.size,) and good.illuminant.dtype == np.float64
    assert inputs_from_xarray(*args).illuminant is None
    for bad, found in (
        (_light(wl)[:-1], f"expected shape \\({wl.size},\\).*found shape \\({wl.size - 1},\\)"),
        (np.where(np.arange(wl.size) == 2, np.nan, _light(wl)), "expected finite values.*1 NaN"),
        (-_light(wl), "expected values >= 0.*negative"),
        (np.zeros(wl.size), "expected a positive value, found all zero"),
    ):
        with pytest.raises(ReconstructionError, match="illuminant: " + found):
            inputs_from_xarray(*args, illuminant=bad)
    # the dataclass checks it too
    with pytest.raises(ReconstructionError, match="illuminant: expected shape"):
        ReconstructionInputs(**{**good.__dict__, "illuminant": np.ones(wl.size + 1)})


def test_a_calibration_illuminant_is_put_on_the_bands_wavelengths(set_scene):
    wl = _wavelength(set_scene)
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    fine = np.arange(400.0, 701.0, 1.0)  # a finer grid, as a calibration measures it
    measured = xr.DataArray(_light(fine), dims="wavelength", coords={"wavelength": fine})
    on_bands = inputs_from_xarray(*args, illuminant=measured).illuminant
    np.testing.assert_allclose(on_bands, _light(wl), rtol=1e-4)
    narrow = measured.sel(wavelength=slice(500, 700))
    with pytest.raises(ReconstructionError, match="illuminant: expected a wavelength grid covering"):
        inputs_from_xarray(*args, illuminant=narrow)
    with pytest.raises(ReconstructionError, match="illuminant: expected dims"):
        inputs_from_xarray(*args, illuminant=measured.rename(wavelength="band"))


# -- the setting ---------------------------------------------------------------------------
def test_the_default_pools_materials_and_every_other_preset_is_independent():
    for name, record in RECONSTRUCTION_METHODS.items():
        if name == DEFAULT_METHOD:
            assert record.settings["set_model"] == "evidence-blend" in SET_MODELS
        elif record.kind == "solver":
            assert record.settings["set_model"] == "independent" == SET_MODELS[0]
        else:
            assert "set_model" not in record.options


def test_the_defaults_set_model_applies_with_the_illuminant_only(set_scene, plain):
    wl = _wavelength(set_scene)
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    pooled = reconstruct(*args, illuminant=_light(wl), set_model="material-pooled")
    default = reconstruct(*args, illuminant=_light(wl))
    assert default.attrs["set_model"] == "material-pooled"
    np.testing.assert_array_equal(default.values, pooled.values)
    assert not np.allclose(default.values, plain.spectra.values)  # it did refit
    # without the illuminant the preset's set model keeps the solve and says so
    bare = reconstruct(*args)
    assert bare.attrs["set_model"] == "independent"
    np.testing.assert_array_equal(bare.values, plain.spectra.values)
    with pytest.raises(ReconstructionError, match="'material-pooled'.*needs the illuminant"):
        reconstruct(*args, set_model="material-pooled")


def test_shared_texel_is_the_solve_then_the_refinement(set_scene, plain):
    wl = _wavelength(set_scene)
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    light = _light(wl)
    shared = reconstruct(
        *args, illuminant=light, set_model="shared-texel", full_output=True, confidence=False
    )
    assert plain.spectra.attrs["set_model"] == "independent"
    assert shared.spectra.attrs["set_model"] == "shared-texel"
    assert shared.spectra.attrs["set_model_time_s"] >= 0
    assert shared.iterations == plain.iterations
    inputs = inputs_from_xarray(*args, illuminant=light)
    initial = np.moveaxis(plain.spectra.values, 0, 1)  # the solver's float32 cube
    direct = shared_texel_refine(inputs, initial, light)
    np.testing.assert_allclose(
        shared.spectra.values, np.moveaxis(direct, 0, 1).astype(np.float32), rtol=1e-5, atol=1e-6
    )
    assert not np.allclose(shared.spectra.values, plain.spectra.values)  # it did refit


def test_a_single_image_is_left_as_solved(scene_factory):
    scene = scene_factory(size=14, n_wavelength=6, n_images=1, noise=0.1)
    args = (scene.rgb.isel(image=0), scene.bands, scene.camera_matrix)
    plain = reconstruct(*args)
    shared = reconstruct(*args, set_model="shared-texel")  # no illuminant needed either
    np.testing.assert_array_equal(shared.values, plain.values)


def test_shared_texel_without_an_illuminant_or_a_wrong_name_fails_clearly(set_scene):
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    with pytest.raises(ReconstructionError, match="'shared-texel'.*needs the illuminant.*found none"):
        reconstruct(*args, set_model="shared-texel")
    with pytest.raises(ReconstructionError, match="set_model: expected one of"):
        reconstruct(*args, set_model="pooled")
    with pytest.raises(ReconstructionError, match="unknown option.*set_model"):
        reconstruct(*args, method="wiener", set_model="shared-texel")
    assert DEFAULT_METHOD in RECONSTRUCTION_METHODS


# -- the set nodes -------------------------------------------------------------------------
FINE = np.arange(400.0, 701.0, 1.0)
"""A calibration's own (finer) wavelength grid, as ``truth/camera`` holds ``C`` and ``L``."""


def _store_groups(scene, illuminant: bool):
    """The set nodes' input groups for ``scene`` as one set (all images owned, the seed),
    with a calibration group like ``truth/camera`` (``C`` and, if asked, ``L`` on FINE)."""
    n = scene.rgb.sizes["image"]
    hdr = xr.Dataset({"radiance": scene.rgb})
    bands = xr.Dataset({"radiance": scene.bands})
    calibration = xr.Dataset(
        {"camera_matrix": (("channel", "wavelength"), camera_matrix_for(FINE))},
        coords={"channel": ["R", "G", "B"], "wavelength": FINE},
    )
    if illuminant:
        calibration["illuminant"] = ("wavelength", _light(FINE))
    sets = xr.Dataset(
        {
            "image_set": ("image", np.zeros(n, dtype=np.int64)),
            "has_bands": ("image", np.isin(np.arange(n), scene.bands["image"].values)),
            "member": (("set", "slot"), np.arange(n)[None]),
            "owned": (("set", "slot"), np.ones((1, n), dtype=bool)),
        },
        coords={"image": np.arange(n)},
        attrs={"seed_set": 0},
    )
    return hdr, bands, calibration, sets


def test_the_set_nodes_pass_the_calibrations_illuminant(set_scene, plain):
    hdr, bands, calibration, sets = _store_groups(set_scene, illuminant=True)
    args = (set_scene.rgb, set_scene.bands, set_scene.camera_matrix)
    for given, model in (("shared-texel", "shared-texel"), (None, "material-pooled")):
        # a given set model, and the default's own: each the direct call with the calibration's L
        options = {} if given is None else {"set_model": given}
        seed = reconstruct_seed_set(hdr, bands, calibration, sets, tile=None, **options)
        assert seed.radiance.attrs["set_model"] == model
        direct = reconstruct(*args, illuminant=calibration["illuminant"], set_model=model)
        np.testing.assert_allclose(seed.radiance.values, direct.values, rtol=1e-5, atol=1e-6)
        assert not np.allclose(seed.radiance.values, plain.spectra.values)
    # set model 'independent' leaves the solve as it was
    independent = reconstruct_seed_set(hdr, bands, calibration, sets, set_model="independent", tile=None)
    np.testing.assert_array_equal(independent.radiance.values, plain.spectra.values)


def test_the_set_nodes_refuse_shared_texel_without_an_illuminant(set_scene):
    hdr, bands, calibration, sets = _store_groups(set_scene, illuminant=False)
    with pytest.raises(
        ReconstructionError, match="'shared-texel' needs the illuminant.*no 'illuminant'"
    ):
        reconstruct_seed_set(hdr, bands, calibration, sets, set_model="shared-texel", tile=None)
    # the default's own set model needs no illuminant: the solve is kept
    kept = reconstruct_seed_set(hdr, bands, calibration, sets, tile=None)
    plain = reconstruct_seed_set(hdr, bands, calibration, sets, set_model="independent", tile=None)
    np.testing.assert_array_equal(kept.radiance.values, plain.radiance.values)
    with pytest.raises(ReconstructionError, match="method 'endmember-mixture' has no set model"):
        reconstruct_seed_set(
            hdr, bands, calibration, sets, method="endmember-mixture", set_model="shared-texel"
        )
