"""Tests of the spectral ground truth (measured spectra, procedural textures, rendering)."""

from __future__ import annotations

import colour
import numpy as np
import pytest

from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.ground_truth import (
    WAVELENGTHS,
    ColourCheckerChart,
    colourchecker_reflectances,
    direction,
    illuminant_spd,
    render,
    shading,
    spectral_scene,
    spectral_texture,
    wavelength_grid,
)


def test_paper_wavelength_grid():
    assert WAVELENGTHS.size == 32 and WAVELENGTHS[0] == 410 and WAVELENGTHS[-1] == 720
    np.testing.assert_array_equal(wavelength_grid(), WAVELENGTHS)
    with pytest.raises(SimulationParameterError, match="stop"):
        wavelength_grid(700, 410, 10)


def test_measured_spectra_come_from_colour_science():
    refl = colourchecker_reflectances()
    assert refl.dims == ("patch", "wavelength") and refl.shape == (24, 32)
    sd = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["orange"]
    np.testing.assert_allclose(refl.sel(patch=6).values, sd[WAVELENGTHS])
    assert refl.patch_name.values[6] == "orange"
    ell = illuminant_spd(name="LED-B3")
    assert ell.max() == pytest.approx(1.0) and ell.attrs["units"] == "1"
    assert ell.values[0] < 0.05  # the white LED is weak at 410 nm
    with pytest.raises(SimulationParameterError, match="LED-B1"):
        illuminant_spd(name="LED-X")
    with pytest.raises(SimulationParameterError, match="known"):
        colourchecker_reflectances(chart="nope")
    with pytest.raises(SimulationParameterError, match="strictly increasing"):
        colourchecker_reflectances(WAVELENGTHS[::-1])


@pytest.fixture(scope="module")
def texture():
    return spectral_texture(48, seed=3, n_materials=5)


def test_texture_is_deterministic_and_well_formed(texture):
    full = texture.evaluate(slice(0, 48), slice(0, 48))
    again = spectral_texture(48, seed=3, n_materials=5).evaluate(slice(0, 48), slice(0, 48))
    np.testing.assert_array_equal(full.weights, again.weights)
    other = spectral_texture(48, seed=4, n_materials=5).evaluate(slice(0, 48), slice(0, 48))
    assert not np.allclose(full.weights, other.weights)
    np.testing.assert_allclose(full.weights.sum(axis=0), 1.0, rtol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(full.normal, axis=0), 1.0, rtol=1e-5)
    assert np.all(full.normal[2] > 0.7)  # gentle bumps
    assert len(set(texture.material_names)) == 5
    assert len(np.unique(full.material)) >= 3  # several materials visible
    rho = texture.diffuse_reflectance(full)
    assert rho.shape == (32, 48, 48) and rho.dtype == np.float32
    assert np.all(rho >= 0) and np.all(rho <= 1.2)


def test_sharp_and_smooth_boundaries(texture):
    big = spectral_texture(128, seed=3, n_materials=5)
    w = big.evaluate(slice(0, 128), slice(0, 128)).weights.max(axis=0)
    assert (w > 0.99).mean() > 0.2  # pure material areas (sharp boundaries between them)
    assert (w < 0.8).mean() > 0.05  # smooth transitions, where materials mix


def test_tiles_and_shifts_are_exact(texture):
    full = texture.evaluate(slice(0, 48), slice(0, 48))
    tile = texture.evaluate(slice(16, 32), slice(8, 40))
    np.testing.assert_allclose(tile.weights, full.weights[:, 16:32, 8:40], rtol=1e-5, atol=1e-6)
    # content shifted by (2, -3) px: pixel (y, x) shows texture point (y - 2, x + 3)
    shifted = texture.evaluate(slice(10, 30), slice(5, 25), shift=(2.0, -3.0))
    np.testing.assert_allclose(shifted.weights, full.weights[:, 8:28, 8:28], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(shifted.normal, full.normal[:, 8:28, 8:28], atol=1e-6)


def test_highlights_have_the_illuminants_spectrum(texture):
    ell = illuminant_spd()
    light, view = (40.0, 180.0), (40.0, 0.0)  # mirror configuration
    rad = render(texture, ell, theta_i=light[0], phi_i=light[1], theta_o=view[0], phi_o=view[1])
    assert rad.dims == ("wavelength", "y", "x") and rad.dtype == np.float32
    assert np.all(np.isfinite(rad)) and np.all(rad >= 0)
    tile = texture.evaluate(slice(0, 48), slice(0, 48))
    d, s = shading(
        tile.normal,
        direction(*light),
        direction(*view),
        specular_albedo=tile.specular_albedo,
        shininess=tile.shininess,
    )
    assert s.max() > 1.0  # a real highlight, brighter than a white diffuser
    y, x = np.unravel_index(np.argmax(s), s.shape)
    diffuse = ell.values * texture.diffuse_reflectance(tile)[:, y, x] * d[y, x]
    specular = rad.values[:, y, x] - diffuse
    np.testing.assert_allclose(specular / ell.values, s[y, x], rtol=1e-4)


def test_colour_checker_chart():
    chart = ColourCheckerChart(60, WAVELENGTHS)
    idx = chart.patch_index(slice(0, 60), slice(0, 60))
    assert set(np.unique(idx)) == set(range(-1, 24))
    rho = chart.diffuse_reflectance(idx)
    refl = colourchecker_reflectances()
    y, x = np.argwhere(idx == 6)[0]
    np.testing.assert_allclose(rho[:, y, x], refl.values[6], rtol=1e-6)


def test_spectral_scene():
    scene = spectral_scene(32, seed=1)
    assert scene.radiance.dims == ("wavelength", "y", "x")
    assert scene.radiance.attrs["units"] == "1"
    assert scene.material.shape == (32, 32)


def test_bad_texture_input():
    with pytest.raises(SimulationParameterError, match="size"):
        spectral_texture(2)
    with pytest.raises(SimulationParameterError, match="n_materials"):
        spectral_texture(32, n_materials=40)
    with pytest.raises(SimulationParameterError, match="strictly increasing"):
        spectral_texture(32, wavelength=[500, 490])
    tex = spectral_texture(16)
    with pytest.raises(ValueError, match="illuminant"):
        render(tex, np.ones(5), theta_i=0, phi_i=0, theta_o=0, phi_o=0)
