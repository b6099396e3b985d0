"""Tests of the material-separating terms: chromaticity-spatial neighbourhoods, the
scale-invariant coupling, the prior PCG on them without the spectral prior (S >= 0) and the
confidence output."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from scipy.stats import spearmanr

from spectralize.nodes.reconstruction import DEFAULT_METHOD, reconstruct
from spectralize.nodes.reconstruction.confidence import neighbourhood_spread
from spectralize.nodes.reconstruction.neighbourhoods import (
    NeighbourGraph,
    appearance_features,
    appearance_neighbours,
    brightness_ratios,
)
from spectralize.nodes.simulation.scenes import SCENES, get_scene

from .conftest import camera_matrix_for, smooth_spectra

WAVELENGTH = np.arange(420.0, 701.0, 20.0)
C = camera_matrix_for(WAVELENGTH)

MATERIAL_PRIOR = {"method": "spectral-prior-pcg", "spectral_prior": 0.0}
"""The prior PCG on material neighbourhoods with the guided prior alone (the retired
``material-prior-pcg``)."""


def _arrays(truth: np.ndarray, with_bands: list[int], filter_size: float = 3.0):
    """Noise-free RGB and band shots of ``truth`` (image, wavelength, y, x)."""
    n_image, n_wl = truth.shape[:2]
    rgb = np.einsum("cw,mwyx->myxc", C, truth)
    shots = [(m, b) for m in with_bands for b in range(n_wl)]
    bands = xr.DataArray(
        np.stack([truth[m, b] for m, b in shots]).astype(np.float32),
        dims=("shot", "y", "x"),
        coords={
            "wavelength": ("shot", WAVELENGTH[[b for _, b in shots]]),
            "image": ("shot", [m for m, _ in shots]),
            "filter_size": ("shot", np.full(len(shots), filter_size)),
        },
    )
    rgb_da = xr.DataArray(
        rgb.astype(np.float32), dims=("image", "y", "x", "channel"), coords={"image": np.arange(n_image)}
    )
    c_da = xr.DataArray(C, dims=("channel", "wavelength"), coords={"wavelength": WAVELENGTH})
    return rgb_da, bands, c_da


def test_scaled_neighbour_term_adjoint_and_laplacian():
    rng = np.random.default_rng(0)
    neighbours = appearance_neighbours(rng.random((50, 3)), k=4)
    ratios = rng.uniform(0.2, 5.0, size=neighbours.shape)
    graph = NeighbourGraph(neighbours, np.float64, ratios)
    x, y = rng.normal(size=(3, 50)), rng.normal(size=(3, 200))
    np.testing.assert_allclose(
        np.sum(graph.differences(x) * y), np.sum(x * graph.differences_adjoint(y))
    )
    np.testing.assert_allclose(graph.laplacian_apply(x), graph.differences_adjoint(graph.differences(x)))
    np.testing.assert_allclose(
        graph.degree, np.asarray((graph.difference_operator**2).sum(axis=0)).ravel()
    )
    # a spectrum scaled by the ratios has no neighbour energy
    brightness = rng.uniform(0.5, 2.0, size=50)
    rgb = np.vstack([brightness, brightness, brightness])
    exact = NeighbourGraph(neighbours, np.float64, brightness_ratios(rgb, neighbours))
    shape = rng.random((3, 1)) * brightness[None]
    assert np.abs(exact.differences(shape)).max() < 1e-12


def test_chromaticity_features_ignore_brightness_and_see_position():
    rgb = np.array([[1.0, 4.0, 1.0], [2.0, 8.0, 2.0], [3.0, 12.0, 3.0]])  # 3 px: the same colour
    features = appearance_features(rgb, (1, 1, 3), space="chromaticity-spatial", brightness_scale=0.0)
    np.testing.assert_allclose(features[:, :2], features[[0], :2].repeat(3, 0))
    assert features[2, 4] > features[0, 4]  # x position
    with pytest.raises(ValueError, match="chromaticity-spatial"):
        appearance_features(rgb, (1, 1, 3), space="lab")


def test_exact_recovery_when_the_constraints_determine_the_answer():
    truth = np.broadcast_to(
        smooth_spectra(np.random.default_rng(3), WAVELENGTH, 1)[0][None, :, None, None],
        (1, WAVELENGTH.size, 20, 20),
    ).copy()
    rgb, bands, c = _arrays(truth, [0])
    out = reconstruct(rgb, bands, c, **MATERIAL_PRIOR, tolerance=1e-6)
    np.testing.assert_allclose(out.values, truth, rtol=2e-3, atol=2e-4)


def test_metamers_placed_apart_are_separated():
    rng = np.random.default_rng(5)
    a = smooth_spectra(rng, WAVELENGTH, 1)[0]
    black = rng.normal(size=WAVELENGTH.size)
    black -= np.linalg.pinv(C) @ (C @ black)
    b = a + 0.5 * np.min(a) / np.abs(black).max() * black  # same RGB, other spectrum
    np.testing.assert_allclose(C @ a, C @ b, atol=1e-12)
    truth = np.empty((1, WAVELENGTH.size, 24, 24))
    truth[0, :, :, :12] = a[:, None, None]
    truth[0, :, :, 12:] = b[:, None, None]
    rgb, bands, c = _arrays(truth, [0], filter_size=2.5)
    errors = {}
    for name, options in (
        ("material prior", MATERIAL_PRIOR),
        (DEFAULT_METHOD, {"method": DEFAULT_METHOD}),
        ("block-jacobi-pcg", {"method": "block-jacobi-pcg", "k": 6, "gamma_hat": 5.0}),
    ):
        out = reconstruct(rgb, bands, c, **options).values
        inner = np.r_[0:4, 20:24]  # away from the boundary, beyond any filter's reach
        errors[name] = np.abs(out[0][:, :, inner] - truth[0][:, :, inner]).max() / np.abs(a - b).max()
    assert errors["material prior"] < 0.1 and errors[DEFAULT_METHOD] < 0.1
    assert errors["block-jacobi-pcg"] > 2 * errors["material prior"]  # RGB neighbours mix them


def test_texel_shape_carried_to_an_image_without_bands_at_another_brightness():
    rng = np.random.default_rng(7)
    spectra = smooth_spectra(rng, WAVELENGTH, 4)
    label = np.repeat(np.repeat(rng.integers(0, 4, size=(4, 4)), 5, 0), 5, 1)
    base = spectra[label].transpose(2, 0, 1)
    truth = np.stack([base, 0.3 * base])  # image 1: the same texels, 0.3 x as bright
    rgb, bands, c = _arrays(truth, [0])
    out = reconstruct(rgb, bands, c, **MATERIAL_PRIOR, tolerance=1e-5).values
    error = np.abs(out[1] - truth[1]) / truth[1].max()
    assert error.max() < 0.05 and error.mean() < 0.01
    assert out.min() >= 0


def test_confidence_is_higher_where_the_error_is_higher():
    rng = np.random.default_rng(11)
    spectra = smooth_spectra(rng, WAVELENGTH, 6)
    label = np.repeat(np.repeat(rng.integers(0, 6, size=(8, 8)), 4, 0), 4, 1)
    truth = spectra[label].transpose(2, 0, 1)[None] * rng.uniform(0.5, 1.5, size=(1, 1, 32, 32))
    rgb, bands, c = _arrays(truth, [0], filter_size=4.0)
    noisy = bands.copy(data=bands.values + rng.normal(scale=0.3, size=bands.shape).astype(np.float32))
    result = reconstruct(rgb, noisy, c, method="block-jacobi-pcg", full_output=True)
    error = np.sqrt(np.mean((result.spectra.values - truth) ** 2, axis=1)).ravel()
    assert result.confidence.dims == ("image", "y", "x")
    rho = spearmanr(result.confidence.values.ravel(), error).statistic
    assert rho > 0.3
    direct = neighbourhood_spread(np.moveaxis(result.spectra.values, 1, 0), rgb.values)
    np.testing.assert_allclose(direct, result.confidence.values)


@pytest.mark.parametrize("scene", list(SCENES))
def test_the_default_confidence_ranks_its_errors_on_the_hard_scenes(scene):
    """Rank correlation of the default's confidence with its per-pixel error on each hard
    scene (48^2, one seed; measured 0.37-0.74)."""
    capture = get_scene(scene, size=48, n_images=1, seed=0)
    result = reconstruct(capture.rgb, capture.bands, capture.camera_matrix, full_output=True)
    truth = capture.truth.transpose("image", "wavelength", "y", "x").values
    spectra = result.spectra.transpose("image", "wavelength", "y", "x").values
    error = np.sqrt(np.mean((spectra - truth) ** 2, axis=1)).ravel()
    assert spearmanr(result.confidence.values.ravel(), error).statistic > 0.3
