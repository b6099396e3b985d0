"""Tests of the hard benchmark scenes (nodes/simulation/scenes)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.simulation.camera_model import SimulationParameterError, camera_sensitivities
from spectralize.nodes.simulation.ground_truth import WAVELENGTHS
from spectralize.nodes.simulation.scenes import SCENES, get_scene, set_geometry, subspace_residual
from spectralize.nodes.simulation.scenes.materials import (
    COLLECTIONS,
    all_reflectances,
    material_library,
    metameric_pair,
    reflectance_collections,
    sharp_led,
    subspace_basis,
)


def test_every_collection_is_shipped_and_in_range():
    collections = reflectance_collections(WAVELENGTHS)
    assert list(collections) == list(COLLECTIONS)
    for values in collections.values():
        assert values.shape[1] == WAVELENGTHS.size and values.shape[0] >= 3
        assert values.min() >= 0 and values.max() <= 1
    assert all_reflectances(WAVELENGTHS).shape[0] > 300


def test_material_library_draws_from_all_collections():
    reflectance, notes = material_library(WAVELENGTHS, 20, np.random.default_rng(1))
    assert reflectance.shape == (20, WAVELENGTHS.size)
    assert {n.split(",")[0] for n in notes} == set(COLLECTIONS)
    assert reflectance.min() >= 0.005 and reflectance.max() <= 0.98


def test_metameric_pair_has_the_same_rgb_and_a_different_spectrum():
    c = camera_sensitivities(WAVELENGTHS).values
    ell = sharp_led(WAVELENGTHS)
    rho = reflectance_collections(WAVELENGTHS)["colourchecker:ColorChecker N Ohta"][5]
    twin = metameric_pair(rho, c, ell, np.random.default_rng(0))
    np.testing.assert_allclose(c @ (ell * twin), c @ (ell * rho), rtol=1e-9)
    assert np.sqrt(np.mean((twin - rho) ** 2)) > 0.02 * rho.max()


def test_led_has_a_narrow_blue_peak():
    ell = sharp_led(WAVELENGTHS)
    assert ell.argmax() == np.searchsorted(WAVELENGTHS, 450) and ell[0] < 1e-2
    assert ell[np.searchsorted(WAVELENGTHS, 480)] < 0.5  # narrow: half gone 30 nm away


@pytest.mark.parametrize("name", list(SCENES))
def test_single_image_scene_is_hard(name):
    capture = get_scene(name, size=48, seed=0)
    p = capture.properties
    assert capture.truth.shape == (1, 32, 48, 48) and capture.bands.sizes["shot"] == 32
    assert capture.truth.values.min() >= 0
    assert 1.5 < p["median_band_signal_dn"] < 4  # a few DN
    assert p["median_band_snr"] <= 1.0
    assert p["mean_intensity_rel_white"] < 0.25
    assert min(p["filter_size_px"]) == pytest.approx(6.0)
    # deterministic from the seed, different noise for another seed
    again = get_scene(name, size=48, seed=0)
    np.testing.assert_array_equal(again.bands.values, capture.bands.values)
    other = get_scene(name, size=48, seed=1)
    np.testing.assert_array_equal(other.truth.values, capture.truth.values)
    assert not np.array_equal(other.bands.values, capture.bands.values)


@pytest.mark.parametrize("name", list(SCENES))
def test_truth_is_not_in_a_low_dimensional_subspace(name):
    capture = get_scene(name, size=32, n_images=20)
    assert capture.properties["subspace8_nrmse_p95"] > 0.1


def test_subspace_residual_is_zero_inside_the_span():
    basis = subspace_basis(WAVELENGTHS, sharp_led(WAVELENGTHS))
    coefficients = np.random.default_rng(0).normal(size=(2, 8, 3, 3))
    inside = np.einsum("kw,mkyx->mwyx", basis, coefficients) + 10 * basis[0][None, :, None, None]
    assert subspace_residual(inside, basis).max() < 1e-10


def test_btf_set_of_20_rectified_images():
    capture = get_scene("glossy-mosaic", size=32, n_images=20)
    assert capture.truth.shape == (20, 32, 32, 32)
    np.testing.assert_array_equal(capture.images_with_bands, np.arange(10))
    assert capture.bands.sizes["shot"] == 32
    assert np.all(capture.rgb["theta_o"].values[:10] == 45.0)
    assert np.all(capture.rgb["theta_o"].values[10:] != 45.0)
    # light and view change a texel's brightness by factors of several
    assert capture.properties["texel_brightness_ratio_median"] > 3
    assert len(set_geometry(20, 10)) == 20


def test_metamers_are_placed_apart():
    capture = get_scene("dark-still-life", size=48)
    (a, b) = capture.layout.metamers[0]
    fa, fb = capture.layout.material_fractions(a), capture.layout.material_fractions(b)
    ya, xa = np.argwhere(fa > 0.5).mean(axis=0)
    yb, xb = np.argwhere(fb > 0.5).mean(axis=0)
    assert np.hypot(ya - yb, xa - xb) > 24


def test_unknown_scene_lists_the_known_ones():
    with pytest.raises(SimulationParameterError, match="woven-fabric"):
        get_scene("nope")
