"""Tests of the natural-spectra prior (its statistics, the band evidence that weighs it per
pixel) and of the prior PCG with it (preset ``natural-prior-pcg``, the default)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import (
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
    build_problem,
    inputs_from_xarray,
    reconstruct,
)
from spectralize.nodes.reconstruction.baselines import wiener_estimation
from spectralize.nodes.reconstruction.solvers.band_evidence import band_evidence
from spectralize.nodes.reconstruction.solvers.natural_prior import (
    natural_prior,
    natural_statistics,
)
from spectralize.nodes.reconstruction.solvers.spectral_prior import spectral_prior_term

from .test_material_prior import _arrays
from .test_spectral_prior import _mixed_truth

NATURAL = "natural-prior-pcg"
SETUP = {k: RECONSTRUCTION_METHODS[NATURAL].settings[k] for k in ("appearance", "scale_invariant", "k")}


def _nrmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean((estimate - truth) ** 2)) / np.mean(np.abs(truth)))


def test_the_default_is_the_natural_prior():
    assert DEFAULT_METHOD == NATURAL
    settings = RECONSTRUCTION_METHODS[NATURAL].settings
    assert settings["prior_source"] == "natural" and settings["natural_prior"] > 0


def test_statistics_of_known_spectra():
    spectra = np.array([[1.0, 3.0], [2.0, 2.0]])  # two samples of two wavelengths
    stats = natural_statistics(spectra)
    np.testing.assert_allclose(stats.mean, [2.0, 2.0])
    np.testing.assert_allclose(stats.covariance, [[1.0, 0.0], [0.0, 0.0]])
    np.testing.assert_allclose(stats.second_moment, [[5.0, 4.0], [4.0, 4.0]])
    rng = np.random.default_rng(0)
    many = rng.normal(size=(5, 400)) * np.arange(1, 6)[:, None] + 3.0
    stats = natural_statistics(many)
    np.testing.assert_allclose(stats.covariance, np.cov(many, bias=True), rtol=1e-12)
    np.testing.assert_allclose(stats.second_moment, many @ many.T / 400, rtol=1e-12)
    with pytest.raises(ValueError, match="n_samples >= 2"):
        natural_statistics(np.ones((5, 1)))
    with pytest.raises(ValueError, match="finite"):
        natural_statistics(np.array([[1.0, np.nan], [0.0, 1.0]]))


def test_the_prior_given_rgb_is_the_wiener_baseline():
    rgb, bands, c = _arrays(_mixed_truth(0), [0])
    inputs = inputs_from_xarray(rgb, bands, c)
    centre, stats = natural_prior(inputs)
    np.testing.assert_allclose(centre, wiener_estimation(inputs), rtol=1e-10, atol=1e-12)
    # the prior is about radiances: positive mean, K = Sigma + mu mu^T
    assert (stats.mean > 0).all()
    np.testing.assert_allclose(
        stats.second_moment, stats.covariance + np.outer(stats.mean, stats.mean), rtol=1e-12
    )


def test_band_evidence_picks_the_estimate_the_shots_confirm():
    truth = _mixed_truth(0, n_image=2)  # image 1: the same materials, no shots
    rgb, bands, c = _arrays(truth, [0])
    rng = np.random.default_rng(3)
    bands = bands.copy(data=bands.values + rng.normal(scale=0.01, size=bands.shape).astype(np.float32))
    inputs = inputs_from_xarray(rgb, bands, c)
    cube = np.moveaxis(truth, 1, 0)
    sigma = np.full(len(inputs.band), 0.01)
    right = band_evidence(inputs, cube, 1.3 * cube, sigma=sigma)
    wrong = band_evidence(inputs, 1.3 * cube, cube, sigma=sigma)
    assert right[0].min() > 0.99 and wrong[0].max() < 0.01
    # the image without shots takes the evidence of the pixels that look alike
    assert np.median(right[1]) > 0.99 and np.median(wrong[1]) < 0.01
    # equal estimates: no evidence either way, even odds where the shots are informative
    np.testing.assert_allclose(band_evidence(inputs, cube, cube, sigma=sigma)[0], 0.5, atol=1e-3)
    with pytest.raises(ValueError, match="natural: expected shape"):
        band_evidence(inputs, cube[:, :1], cube, sigma=sigma)


def _noisy_problem(truth: np.ndarray, noise: float):
    rgb, bands, c = _arrays(truth, [0])
    rng = np.random.default_rng(1)
    bands = bands.copy(
        data=(bands.values + rng.normal(scale=noise, size=bands.shape)).astype(np.float32)
    )
    inputs = inputs_from_xarray(rgb, bands, c)
    return inputs, build_problem(inputs, **SETUP, dtype=np.float64)


def test_pure_noise_bands_centre_the_prior_on_the_wiener_estimate():
    truth = _mixed_truth(0)
    # the band shots: the signal under noise a thousand times stronger
    inputs, problem = _noisy_problem(truth, noise=1000.0 * float(truth.mean()))
    term = spectral_prior_term(
        problem, 0.003, 1.0, covariance_floor=0.01, source="natural", natural_prior=0.001
    )
    mixture = spectral_prior_term(problem, 0.003, 1.0, covariance_floor=0.01, source="mixture")
    wiener = wiener_estimation(inputs)
    assert _nrmse(term.centre, wiener) < 0.05 * _nrmse(mixture.centre, wiener)
    # the natural prior's weight joins the mixture's
    assert (term.weight > mixture.weight).all()


def test_clean_bands_centre_the_prior_on_the_mixture():
    truth = _mixed_truth(0)
    inputs, problem = _noisy_problem(truth, noise=1e-4 * float(truth.mean()))
    term = spectral_prior_term(
        problem, 0.003, 1.0, covariance_floor=0.01, source="natural", natural_prior=0.001
    )
    mixture = spectral_prior_term(problem, 0.003, 1.0, covariance_floor=0.01, source="mixture")
    cube = np.moveaxis(truth, 1, 0)
    assert _nrmse(term.centre, cube) < 1.05 * _nrmse(mixture.centre, cube)
    assert _nrmse(term.centre, cube) < 0.5 * _nrmse(wiener_estimation(inputs), cube)


def test_clean_bands_are_followed():
    truth = _mixed_truth(0)
    rgb, bands, c = _arrays(truth, [0])
    spectra = reconstruct(rgb, bands, c, method=NATURAL).values
    wiener = wiener_estimation(inputs_from_xarray(rgb, bands, c))
    wiener_error = _nrmse(np.moveaxis(wiener, 1, 0), truth)
    assert wiener_error > 0.05  # the training set does not know these spectra
    assert _nrmse(spectra, truth) < 0.25 * wiener_error
