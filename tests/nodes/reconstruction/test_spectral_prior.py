"""Tests of the spectral prior: the per-pixel Gaussian spectral prior term and the prior
PCG that adds it (preset ``spectral-prior-pcg``)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import (
    RECONSTRUCTION_METHODS,
    build_problem,
    inputs_from_xarray,
    reconstruct,
)
from spectralize.nodes.reconstruction.solvers import (
    BlockJacobiPreconditioner,
    guided_initial,
    prior_pcg,
)
from spectralize.nodes.reconstruction.solvers.spectral_prior import (
    MAX_BRIGHTNESS,
    MIN_BRIGHTNESS,
    prior_brightness,
    spectral_prior_term,
)

from .conftest import smooth_spectra
from .test_material_prior import WAVELENGTH, _arrays

SPECTRAL = RECONSTRUCTION_METHODS["spectral-prior-pcg"].settings
"""The spectral-prior preset."""

SETUP_DEFAULTS = {name: SPECTRAL[name] for name in ("appearance", "scale_invariant", "k")}
"""Its problem set-up: neighbourhoods that separate materials."""

FLOOR = SPECTRAL["covariance_floor"]


def _mixed_truth(seed: int, n_image: int = 1, size: int = 16) -> np.ndarray:
    rng = np.random.default_rng(seed)
    spectra = smooth_spectra(rng, WAVELENGTH, 4)
    label = np.repeat(np.repeat(rng.integers(0, 4, size=(size // 4, size // 4)), 4, 0), 4, 1)
    base = spectra[label].transpose(2, 0, 1) * rng.uniform(0.5, 1.5, size=(1, size, size))
    return np.stack([base * (0.5 + 0.5 * m) for m in range(n_image)])


def _problem(truth: np.ndarray, with_bands: list[int], noise: float = 0.0):
    rgb, bands, c = _arrays(truth, with_bands)
    if noise:
        rng = np.random.default_rng(1)
        bands = bands.copy(
            data=bands.values + rng.normal(scale=noise, size=bands.shape).astype(np.float32)
        )
    inputs = inputs_from_xarray(rgb, bands, c)
    return (rgb, bands, c), build_problem(inputs, **SETUP_DEFAULTS, dtype=np.float64)


@pytest.mark.parametrize("source", ["scene", "training", "mixture"])
def test_prior_term_is_symmetric_positive_and_zero_at_its_centre(source):
    _, problem = _problem(_mixed_truth(0), [0])
    term = spectral_prior_term(problem, 0.01, 2.0, covariance_floor=FLOOR, source=source)
    assert term is not None
    rng = np.random.default_rng(2)
    x, y = rng.normal(size=(2,) + problem.shape)
    np.testing.assert_allclose(np.sum(term.apply(x) * y), np.sum(x * term.apply(y)), rtol=1e-10)
    assert np.linalg.eigvalsh(term.precision).min() > 0
    assert term.energy(term.centre) == pytest.approx(0.0, abs=1e-12)
    assert term.energy(term.centre + x) > 0
    # the diagonal the preconditioner takes is the operator's
    unit = np.zeros(problem.shape)
    unit[3, 0, 2, 5] = 1.0
    assert term.apply(unit)[3, 0, 2, 5] == pytest.approx(term.diagonal()[3, 0, 2, 5])
    # darker pixels are held more tightly (weight ~ 1 / brightness^2)
    brightness = np.asarray(problem.extras["inputs"].rgb).sum(axis=-1)
    order = np.argsort(brightness.ravel())
    assert term.weight.ravel()[order[0]] > term.weight.ravel()[order[-1]]
    with pytest.raises(ValueError, match="prior_source: expected one of"):
        spectral_prior_term(problem, 0.01, 2.0, covariance_floor=FLOOR, source="pca")


def test_solution_solves_the_regularised_normal_equations():
    _, problem = _problem(_mixed_truth(4), [0], noise=0.05)
    options = {"dtype": np.float64, "ridge": 0.0, "prior": 0.0, "projected_iterations": 0}
    options |= {"covariance_floor": FLOOR, "prior_source": "scene"}
    result = prior_pcg(problem, tolerance=1e-10, max_iterations=5000, spectral_prior=0.05, **options)
    mean_diagonal = BlockJacobiPreconditioner(problem, np.float64).mean_diagonal
    term = spectral_prior_term(problem, 0.05, mean_diagonal, covariance_floor=FLOOR, source="scene")
    x = result.cube
    residual = problem.normal(x) + term.apply(x) - problem.normal_rhs() - term.rhs()
    rhs = problem.normal_rhs() + term.rhs()
    assert np.linalg.norm(residual) / np.linalg.norm(rhs) < 1e-7
    # the term is active: without it the solution differs
    plain = prior_pcg(problem, tolerance=1e-10, max_iterations=5000, spectral_prior=0.0, **options)
    assert np.abs(plain.cube - x).max() > 1e-3 * np.abs(x).max()


def test_brightness_weighted_prior_solves_its_normal_equations():
    """``(A^T A + epsilon_p f_p M) S = A^T b + epsilon_p f_p M S_0`` with ``f_p`` the
    pixel's relative brightness: the per-pixel term, its right-hand side and its place in
    the preconditioner are those of one energy."""
    (rgb, _, _), problem = _problem(_mixed_truth(5), [0], noise=0.05)
    prior = 0.5
    exact = {
        "tolerance": 1e-10,
        "max_iterations": 5000,
        "dtype": np.float64,
        "ridge": 0.0,
        "prior": prior,
        "spectral_prior": 0.0,
        "projected_iterations": 0,
    }
    result = prior_pcg(problem, prior_weighting="brightness", **exact)
    mean_diagonal = BlockJacobiPreconditioner(problem, np.float64).mean_diagonal
    weight = prior * mean_diagonal * prior_brightness(rgb.values)[None]  # every band has a shot
    centre = guided_initial(problem)
    x = result.cube
    rhs = problem.normal_rhs() + weight * centre
    residual = problem.normal(x) + weight * x - rhs
    assert np.linalg.norm(residual) / np.linalg.norm(rhs) < 1e-7
    uniform = prior_pcg(problem, **exact)
    # the brightest pixels are held closer to the centre than with a uniform weight
    brightness = prior_brightness(rgb.values).ravel()
    bright = brightness >= np.quantile(brightness, 0.9)
    moved = {
        name: np.abs(cube - centre).reshape(problem.shape[0], -1)[:, bright].mean()
        for name, cube in (("brightness", x), ("uniform", uniform.cube))
    }
    assert moved["brightness"] < 0.9 * moved["uniform"]
    with pytest.raises(ValueError, match="prior_weighting: expected one of"):
        prior_pcg(problem, prior_weighting="luminance")


def test_prior_brightness_has_mean_one_and_is_clipped():
    rgb = np.ones((2, 4, 4, 3))
    rgb[0, 0, 0] = 1000.0  # a highlight
    rgb[1, 1:, :] = 1e-6  # a dark region
    f = prior_brightness(rgb)
    assert f.mean() == pytest.approx(1.0)
    relative = rgb.sum(axis=-1) / rgb.sum(axis=-1).mean(axis=(1, 2), keepdims=True)
    ratio = f / np.clip(relative, MIN_BRIGHTNESS, MAX_BRIGHTNESS)
    np.testing.assert_allclose(ratio, ratio.flat[0])  # one normalisation for all pixels
    # the highlight is held as a pixel MAX_BRIGHTNESS x its image's mean, the rest of its
    # image (at 0.016 x the mean) as MIN_BRIGHTNESS x
    assert relative[0, 0, 0] > MAX_BRIGHTNESS and relative[0, 1, 1] < MIN_BRIGHTNESS
    assert f[0, 0, 0] / f[0, 1, 1] == pytest.approx(MAX_BRIGHTNESS / MIN_BRIGHTNESS)


def test_exact_recovery_when_the_constraints_determine_the_answer():
    truth = np.broadcast_to(
        smooth_spectra(np.random.default_rng(3), WAVELENGTH, 1)[0][None, :, None, None],
        (1, WAVELENGTH.size, 20, 20),
    ).copy()
    rgb, bands, c = _arrays(truth, [0])
    out = reconstruct(rgb, bands, c, method="spectral-prior-pcg", spectral_prior=0.1, tolerance=1e-6)
    np.testing.assert_allclose(out.values, truth, rtol=2e-3, atol=2e-4)


def sparse_set(truth: np.ndarray):
    """RGB, band shots and C of a 3-image set in which every band has a shot but each image
    only of every third band; and its problem set up as the material prior's."""
    rgb, bands, c = _arrays(truth, [0, 1, 2])
    band = np.searchsorted(WAVELENGTH, bands.wavelength.values)
    sparse = bands.isel(shot=np.flatnonzero(band % 3 == bands.image.values))
    inputs = inputs_from_xarray(rgb, sparse, c)
    return (rgb, sparse, c), build_problem(inputs, **SETUP_DEFAULTS)


def test_sparse_set_gets_no_scene_prior_and_matches_the_prior_pcg_without_it():
    (rgb, sparse, c), problem = sparse_set(_mixed_truth(6, n_image=3))
    assert spectral_prior_term(problem, 0.01, 1.0, covariance_floor=FLOOR, source="scene") is None
    ours = reconstruct(rgb, sparse, c, method="spectral-prior-pcg", tolerance=1e-6).values
    theirs = reconstruct(
        rgb, sparse, c, method="spectral-prior-pcg", spectral_prior=0.0, tolerance=1e-6
    ).values
    np.testing.assert_allclose(ours, theirs, atol=1e-3 * np.abs(theirs).max())
    assert ours.min() >= 0


def test_registered_with_the_material_set_up():
    method = RECONSTRUCTION_METHODS["spectral-prior-pcg"]
    assert method.kind == "solver"
    defaults = method.defaults()
    assert defaults["appearance"] == "chromaticity-spatial" and defaults["scale_invariant"]
    assert defaults["spectral_prior"] > 0 and defaults["prior_source"] == "scene"
