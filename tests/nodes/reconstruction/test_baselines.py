"""Baselines: each does what its name says on data where the answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import BASELINE_METHODS, inputs_from_xarray
from spectralize.nodes.reconstruction.baselines import (
    filtered_bands,
    guided_filtered_bands,
    project_onto_rgb,
    training_reflectances,
)


@pytest.fixture
def inputs(scene_factory):
    scene = scene_factory(
        size=20,
        n_wavelength=8,
        n_images=2,
        shading=True,
        noise=0.05,
        shots={0: list(range(8)), 1: [0, 3]},
    )
    return inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)


def _rgb_of(cube, inputs):
    return np.einsum("cw,wmyx->myxc", inputs.camera_matrix, cube)


@pytest.mark.parametrize(
    "method", ["pseudo-inverse", "mallett2019", "filtered-projected", "guided-projected"]
)
def test_rgb_consistent_baselines_reproduce_the_rgb(inputs, method):
    cube = BASELINE_METHODS[method].function(inputs)
    assert cube.shape == inputs.cube_shape
    np.testing.assert_allclose(_rgb_of(cube, inputs), inputs.rgb, rtol=1e-8, atol=1e-10)


def test_wiener_nearly_reproduces_the_rgb_and_is_linear_in_it(inputs):
    cube = BASELINE_METHODS["wiener"].function(inputs)
    np.testing.assert_allclose(
        _rgb_of(cube, inputs), inputs.rgb, rtol=1e-2, atol=1e-3 * np.abs(inputs.rgb).max()
    )
    # linear: the estimate of R1 + R2 at two pixels is the sum of the estimates
    flat = cube.reshape(cube.shape[0], -1)
    rgb = inputs.rgb_pixels()
    combo = np.linalg.lstsq(rgb[:, :50].T, flat[:, :50].T, rcond=None)[0]
    np.testing.assert_allclose(combo.T @ rgb[:, 100], flat[:, 100], rtol=1e-6)


def test_pseudo_inverse_is_the_minimum_norm_rgb_solution(inputs):
    cube = BASELINE_METHODS["pseudo-inverse"].function(inputs)
    null = np.linalg.svd(inputs.camera_matrix)[2][3:]  # basis of null(C)
    # no component in the null space of C
    assert np.abs(null @ cube.reshape(cube.shape[0], -1)).max() < 1e-10


def test_filtered_bands_of_a_constant_image_are_that_constant(scene_factory):
    scene = scene_factory(size=20, n_wavelength=4, n_materials=1, filter_size=5.0)
    inputs = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    np.testing.assert_allclose(filtered_bands(inputs), np.moveaxis(scene.truth, 1, 0), rtol=1e-12)


def test_missing_bands_are_predicted_from_rgb(scene_factory):
    # flat materials: every band is a linear function of RGB, so the fit is exact
    scene = scene_factory(
        size=20,
        n_wavelength=6,
        n_images=2,
        n_materials=3,
        filter_size=2.0,
        shots={0: list(range(6)), 1: [1]},
    )
    inputs = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    cube = filtered_bands(inputs)
    truth = np.moveaxis(scene.truth, 1, 0)
    interior = (slice(None), 1, slice(None), slice(4, 5))  # inside one stripe
    np.testing.assert_allclose(cube[interior], truth[interior], rtol=1e-6)
    assert np.abs(cube[:, 1] - truth[:, 1]).max() < 0.5 * np.abs(truth).max()


def test_projection_changes_spectra_as_little_as_possible():
    rng = np.random.default_rng(0)
    c = rng.normal(size=(3, 7))
    b = rng.normal(size=(7, 5))
    r = rng.normal(size=(3, 5))
    s = project_onto_rgb(b, c, r)
    np.testing.assert_allclose(c @ s, r, atol=1e-12)
    # the change lies in the row space of C (orthogonal to its null space)
    null = np.linalg.svd(c)[2][3:]
    np.testing.assert_allclose(null @ (s - b), 0.0, atol=1e-12)


def test_training_reflectances_from_colour_science():
    wavelength = np.arange(410.0, 721.0, 10.0)
    reflectances = training_reflectances(wavelength)
    assert reflectances.shape == (32, 190)
    assert 0.0 <= reflectances.min() and reflectances.max() <= 1.2


def test_guided_filter_keeps_detail_that_is_linear_in_rgb(scene_factory):
    """One shaded material: every band is a linear function of RGB, so the guided filter
    reproduces the noise-free bands (up to its small ridge) where a Gaussian filter blurs
    the shading; with band noise it still beats the Gaussian filter."""
    scene = scene_factory(size=24, n_wavelength=6, n_materials=1, shading=True, filter_size=10.0)
    inputs = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    truth = np.moveaxis(scene.truth, 1, 0)
    guided = guided_filtered_bands(inputs)
    assert np.abs(guided - truth).max() < 1e-3 * np.abs(truth).max()
    assert np.abs(filtered_bands(inputs) - truth).max() > 1e-2 * np.abs(truth).max()
    noisy = scene_factory(
        size=24, n_wavelength=6, n_materials=1, shading=True, filter_size=10.0, noise=0.1
    )
    inputs = inputs_from_xarray(noisy.rgb, noisy.bands, noisy.camera_matrix)
    assert np.linalg.norm(guided_filtered_bands(inputs) - truth) < 0.5 * np.linalg.norm(
        filtered_bands(inputs) - truth
    )


def test_guided_filter_fills_bands_without_a_shot_like_the_filtered_bands(inputs):
    cube = guided_filtered_bands(inputs)
    np.testing.assert_allclose(cube[1, 1], filtered_bands(inputs)[1, 1])


@pytest.mark.parametrize("sigma", [2.0, 3.3, 7.5, 15.0])
def test_box_windows_have_the_gaussian_variance_and_keep_the_mass(sigma):
    from spectralize.nodes.reconstruction.baselines.guided_filter import _box_widths, gaussian_window

    widths = _box_widths(sigma)
    assert all(w % 2 == 1 for w in widths)
    assert np.sqrt(sum((w * w - 1) / 12 for w in widths)) == pytest.approx(sigma, rel=0.1)
    impulse = np.zeros((1, 121, 121))
    impulse[0, 60, 60] = 1.0
    window = gaussian_window(impulse, sigma)[0]
    assert window.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(window, window[::-1, ::-1], atol=1e-12)  # symmetric
    y = np.arange(121) - 60
    variance = float((window.sum(axis=1) * y**2).sum())
    assert np.sqrt(variance) == pytest.approx(sigma, rel=0.1)
