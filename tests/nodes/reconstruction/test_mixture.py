"""Tests of the endmember-mixture estimator and of ``mixture-prior-pcg`` (the default)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import nnls

from spectralize.nodes.reconstruction import (
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
    inputs_from_xarray,
    reconstruct,
)
from spectralize.nodes.reconstruction.estimators import endmember_mixture
from spectralize.nodes.reconstruction.estimators.endmember_mixture import (
    ABUNDANCE_RIDGE,
    SAMPLE_PIXELS,
    Endmembers,
    band_noise_sigma,
    chromaticity,
    local_correction,
    neighbourhood_candidates,
    rgb_abundances,
    sample_stride,
    set_endmembers,
)
from spectralize.nodes.reconstruction.solvers.spectral_prior import spectral_prior_term
from spectralize.schemas import ReconstructionError

from .conftest import smooth_spectra
from .test_material_prior import WAVELENGTH, C, _arrays
from .test_spectral_prior import sparse_set


def _blocks(seed: int, *, size: int = 32, n_material: int = 3, n_image: int = 1) -> np.ndarray:
    """Blocks of ``n_material`` spectra, shaded 0.5-1.5, with two-material mixtures along
    the block borders (as a pixel that straddles them integrates both)."""
    rng = np.random.default_rng(seed)
    spectra = smooth_spectra(rng, WAVELENGTH, n_material)
    label = np.repeat(np.repeat(rng.integers(0, n_material, size=(size // 8, size // 8)), 8, 0), 8, 1)
    pure = spectra[label].transpose(2, 0, 1)  # (w, y, x)
    shifted = np.roll(pure, 1, axis=2)
    mixed = np.where((np.arange(size) % 8 == 0)[None, None, :], 0.5 * (pure + shifted), pure)
    shade = rng.uniform(0.5, 1.5, size=(1, size, size))
    return np.stack([mixed * shade * (1.0 - 0.4 * m) for m in range(n_image)])


def test_chromaticity_ignores_brightness():
    rgb = np.random.default_rng(0).uniform(0.1, 1.0, size=(50, 3))
    b1, c1 = chromaticity(rgb, scale=np.ones(3))
    b2, c2 = chromaticity(3.7 * rgb, scale=np.ones(3))
    np.testing.assert_allclose(c1, c2)
    np.testing.assert_allclose(b2, 3.7 * b1)


def test_abundances_are_the_exact_non_negative_least_squares_solution():
    rng = np.random.default_rng(1)
    atoms = np.abs(rng.normal(size=(6, WAVELENGTH.size)))
    endmembers = Endmembers(atoms, rng.uniform(size=(5, 2)), np.ones(3))
    near = np.stack([rng.choice(5, size=3, replace=False) for _ in range(200)])
    near = np.hstack([near, np.full((200, 1), endmembers.highlight)])
    rgb = rng.normal(size=(200, 3)) + 2.0  # some reachable, some not: active constraints
    weights = rgb_abundances(endmembers, near, C, rgb)
    assert weights.min() >= 0
    for p in range(200):
        ca = (atoms[near[p]] @ C.T).T
        reference, _ = nnls(ca, rgb[p])
        np.testing.assert_allclose(
            np.linalg.norm(ca @ weights[p] - rgb[p]),
            np.linalg.norm(ca @ reference - rgb[p]),
            rtol=1e-4,
            atol=1e-4 * np.linalg.norm(rgb[p]),  # the ridge of 1e-6 x trace
        )


def test_abundances_with_a_candidate_proposed_twice_minimise_the_ridge_objective():
    rng = np.random.default_rng(2)
    atoms = np.abs(rng.normal(size=(5, WAVELENGTH.size)))
    endmembers = Endmembers(atoms, rng.uniform(size=(4, 2)), np.ones(3))
    near = np.stack([rng.choice(4, size=3, replace=False) for _ in range(100)])
    near = np.hstack([near, near[:, :1], np.full((100, 1), endmembers.highlight)])  # a repeat
    rgb = rng.normal(size=(100, 3)) + 2.0
    weights = rgb_abundances(endmembers, near, C, rgb)
    assert weights.min() >= 0
    for p in range(100):
        ca = (atoms[near[p]] @ C.T).T
        hessian = ca.T @ ca + ABUNDANCE_RIDGE * np.trace(ca.T @ ca) * np.eye(ca.shape[1])

        def objective(w, hessian=hessian, ca=ca, p=p):
            return 0.5 * w @ hessian @ w - (ca.T @ rgb[p]) @ w

        # the same problem as an ordinary NNLS: [C E; sqrt(ridge) I] w ~ [R; 0]
        root = np.sqrt(ABUNDANCE_RIDGE * np.trace(ca.T @ ca))
        augmented = np.vstack([ca, root * np.eye(ca.shape[1])])
        reference, _ = nnls(augmented, np.concatenate([rgb[p], np.zeros(ca.shape[1])]))
        assert objective(weights[p]) <= objective(reference) + 1e-9 * abs(objective(reference))


def test_exact_recovery_of_pure_and_mixed_pixels_from_noise_free_bands():
    truth = _blocks(2, size=64)  # enough pixels for an endmember per material
    rgb, bands, c = _arrays(truth, [0])
    out = reconstruct(rgb, bands, c, method="endmember-mixture").values
    assert out.min() >= 0
    error = np.abs(out - truth) / truth.max()
    assert np.median(error) < 1e-4  # float32 output, float64 inside
    assert np.percentile(error, 99) < 1e-3
    assert error.max() < 1e-2


def test_noise_averages_out_over_a_material():
    truth = _blocks(3, size=64)
    rgb, bands, c = _arrays(truth, [0])
    sigma = float(truth.mean())  # band SNR about 1 per pixel
    rng = np.random.default_rng(4)
    noisy = bands.copy(data=bands.values + rng.normal(scale=sigma, size=bands.shape).astype(np.float32))
    rms = {}
    for method in ("endmember-mixture", "filtered-projected"):
        out = reconstruct(rgb, noisy, c, method=method).values
        rms[method] = np.sqrt(np.mean((out - truth) ** 2)) / truth.mean()
    assert rms["endmember-mixture"] < 0.1  # per pixel and band the noise is 1.0
    assert rms["endmember-mixture"] < 0.5 * rms["filtered-projected"]


def test_images_without_bands_get_the_shared_endmembers_at_their_brightness():
    truth = _blocks(5, n_image=2)  # image 1: the same texels, 0.6 x as bright, no bands
    rgb, bands, c = _arrays(truth, [0])
    for method in ("endmember-mixture", DEFAULT_METHOD):
        out = reconstruct(rgb, bands, c, method=method).values
        error = np.abs(out[1] - truth[1]) / truth[1].max()
        assert np.median(error) < 0.01, method
        assert out.min() >= 0


def test_the_mixture_prior_exists_for_a_sparse_set_and_is_centred_on_the_estimate():
    _, problem = sparse_set(_blocks(6, n_image=3, size=24))
    inputs = problem.extras["inputs"]
    assert spectral_prior_term(problem, 0.01, 1.0, covariance_floor=1e-2, source="scene") is None
    term = spectral_prior_term(problem, 0.01, 1.0, covariance_floor=1e-2, source="mixture")
    assert term is not None
    np.testing.assert_allclose(term.centre, endmember_mixture(inputs).reshape(problem.shape))
    assert np.linalg.eigvalsh(term.precision).min() > 0


def test_default_is_the_mixture_prior_solver_and_beats_its_predecessor_on_noisy_bands():
    assert DEFAULT_METHOD == "natural-prior-pcg"  # the mixture preset plus the natural prior
    record = RECONSTRUCTION_METHODS[DEFAULT_METHOD]
    assert record.kind == "solver" and record.defaults()["appearance"] == "chromaticity-spatial"
    assert RECONSTRUCTION_METHODS["endmember-mixture"].kind == "estimator"
    truth = _blocks(8, size=40, n_material=5)
    rgb, bands, c = _arrays(truth, [0], filter_size=4.0)
    rng = np.random.default_rng(9)
    noisy = bands.copy(
        data=bands.values + rng.normal(scale=float(truth.mean()), size=bands.shape).astype(np.float32)
    )
    error = {}
    for method in (DEFAULT_METHOD, "spectral-prior-pcg"):
        out = reconstruct(rgb, noisy, c, method=method).values
        error[method] = np.median(np.sqrt(np.mean((out - truth) ** 2, axis=1))) / truth.mean()
        assert out.min() >= 0
    assert error[DEFAULT_METHOD] < 0.8 * error["spectral-prior-pcg"]


@pytest.mark.parametrize("seed", [0, 1])
def test_deterministic(seed):
    truth = _blocks(10)
    rgb, bands, c = _arrays(truth, [0])
    inputs = inputs_from_xarray(rgb, bands, c)
    np.testing.assert_array_equal(
        endmember_mixture(inputs, seed=seed), endmember_mixture(inputs, seed=seed)
    )


def test_neighbourhood_candidates_are_the_materials_around_a_pixel():
    truth = _blocks(12, size=16)
    rgb, bands, c = _arrays(truth, [0])
    inputs = inputs_from_xarray(rgb, bands, c)
    n = 16 * 16
    near = np.zeros((n, 2), dtype=np.intp)
    weights = np.zeros((n, 2))
    near[:, 0] = np.where(np.arange(n) % 16 < 8, 0, 1)  # left half atom 0, right half atom 1
    near[:, 1] = 3  # the highlight atom (the largest index) is never proposed
    weights[:, 0] = 1.0
    weights[:, 1] = 0.5
    chosen = neighbourhood_candidates(inputs, near, weights, 2)
    assert chosen.shape == (n, 2)
    left, right = np.arange(n) % 16 == 0, np.arange(n) % 16 == 15
    assert (chosen[left, 0] == 0).all() and (chosen[right, 0] == 1).all()
    assert not (chosen == 3).any()


# -- one dictionary for a whole set ------------------------------------------------------------
def test_a_dictionary_learnt_before_gives_the_same_mixture():
    truth = _blocks(13, size=48)
    rgb, bands, c = _arrays(truth, [0])
    rng = np.random.default_rng(14)
    noisy = bands.copy(data=bands.values + rng.normal(scale=0.5 * float(truth.mean()), size=bands.shape))
    inputs = inputs_from_xarray(rgb, noisy, c)
    endmembers = set_endmembers(inputs)
    np.testing.assert_array_equal(
        endmember_mixture(inputs, endmembers=endmembers), endmember_mixture(inputs)
    )


def test_a_dictionary_learnt_on_a_strided_sample_recovers_every_pixel():
    truth = _blocks(2, size=64)  # blocks of 8 px: a stride of 2 sees every material
    rgb, bands, c = _arrays(truth, [0])
    inputs = inputs_from_xarray(rgb, bands, c)
    grid = {"y": slice(None, None, 2), "x": slice(None, None, 2)}  # as tiling.sample_grid cuts
    sample = inputs_from_xarray(rgb.isel(grid), bands.isel(grid), c)
    assert sample.rgb.shape == (1, 32, 32, 3) and sample.band_data.shape[1:] == (32, 32)
    out = endmember_mixture(inputs, endmembers=set_endmembers(sample))
    error = np.abs(np.moveaxis(out, 0, 1) - truth) / truth.max()
    assert np.median(error) < 1e-4
    # measured 0.004 (every pixel: 0.0005): a quarter of the pixels learns 4 endmembers
    # instead of 16 (at least 256 pixels each), so the block-border mixtures fit less well
    assert np.percentile(error, 99) < 1e-2


def test_sample_stride_keeps_at_most_the_pixels_asked_for():
    assert sample_stride(20, 256, 256) == 1  # 1.3 Mpx: every pixel

    def kept(stride: int) -> int:
        return 20 * math.ceil(2048 / stride) ** 2

    stride = sample_stride(20, 2048, 2048)
    assert kept(stride) <= SAMPLE_PIXELS < kept(stride - 1)


def test_endmembers_on_other_wavelengths_are_an_error_naming_them():
    truth = _blocks(15, size=32)
    rgb, bands, c = _arrays(truth, [0])
    inputs = inputs_from_xarray(rgb, bands, c)
    endmembers = set_endmembers(inputs)
    short = Endmembers(endmembers.atoms[:, :-1], endmembers.centres, endmembers.scale)
    with pytest.raises(ReconstructionError, match=r"endmembers: expected atoms on the bands' \d+"):
        endmember_mixture(inputs, endmembers=short)
    with pytest.raises(ReconstructionError, match="only the 'mixture' prior source"):
        reconstruct(rgb, bands, c, method="spectral-prior-pcg", endmembers=endmembers)


def test_band_noise_sigma_is_the_noise_and_not_the_texture():
    """Fine texture (a new material and shading every pixel) is in the RGB too; the band
    noise is not: the estimate is the noise, where the high-pass part alone is not."""
    from scipy import ndimage

    rng = np.random.default_rng(12)
    size, sigma = 64, 0.02
    spectra = smooth_spectra(rng, WAVELENGTH, 4)
    share = rng.dirichlet(np.ones(4), size=(size, size))  # sub-pixel mixing, every pixel
    shade = rng.uniform(0.2, 1.8, size=(size, size))
    truth = (np.einsum("yxj,jw->wyx", share, spectra) * shade)[None]
    rgb, bands, c = _arrays(truth, [0])
    noisy = bands.copy(data=bands.values + rng.normal(scale=sigma, size=bands.shape).astype(np.float32))
    estimate = band_noise_sigma(inputs_from_xarray(rgb, noisy, c))
    np.testing.assert_allclose(estimate, sigma, rtol=0.12)
    plane = noisy.values[5].astype(np.float64)
    high_pass = np.sqrt(np.var(plane - ndimage.uniform_filter(plane, 3)) * 9 / 8)
    assert high_pass > 1.5 * sigma  # the texture is there to be mistaken for noise


def test_band_noise_sigma_is_computed_once_per_inputs():
    """The spectral prior's mixture, its band evidence and the set model each ask for the
    band noise of the same inputs: it is computed on the first call and kept on the inputs
    (each caller gets its own copy); new inputs compute their own."""
    import dataclasses

    from spectralize.nodes.reconstruction.estimators.endmember_mixture import _band_noise_sigma

    rng = np.random.default_rng(3)
    truth = smooth_spectra(rng, WAVELENGTH, 1)[0][:, None, None] * rng.uniform(0.5, 1.5, (24, 24))
    rgb, bands, c = _arrays(truth[None], [0])
    noisy = bands.copy(data=bands.values + rng.normal(scale=0.01, size=bands.shape).astype(np.float32))
    inputs = inputs_from_xarray(rgb, noisy, c)
    computed = []

    def counted(given):
        computed.append(given)
        return _band_noise_sigma(given)

    first = inputs.cached("band_noise_sigma", counted)
    first[:] = -1.0  # a caller's copy: the kept value does not change
    again = band_noise_sigma(inputs)
    assert computed == [inputs]
    assert np.array_equal(again, _band_noise_sigma(inputs))
    changed = dataclasses.replace(inputs, band_data=inputs.band_data * 2.0)
    np.testing.assert_allclose(band_noise_sigma(changed), 2.0 * again, rtol=1e-6)


def _spot_scene(seed: int):
    """One material; a 3 x 3 spot of its metamer (the same RGB, another spectrum) that the
    mixture took for the material: the truth, its noisy band shots, that mixture, the
    spot and the noise level. The RGB cannot place the spot, so only the window does."""
    rng = np.random.default_rng(seed)
    size = 48
    base, other = smooth_spectra(rng, WAVELENGTH, 2)
    black = other - C.T @ np.linalg.solve(C @ C.T, C @ other)  # C black = 0
    black *= 0.5 * base.mean() / np.sqrt(np.mean(black**2))
    shift = max(0.0, float(-(base + black).min()))  # keep the metamer non-negative
    base = base + shift
    truth = np.broadcast_to(base[:, None, None], (WAVELENGTH.size, size, size)).copy()
    inside = (slice(None), slice(22, 25), slice(22, 25))
    truth[inside] += black[:, None, None]
    truth = truth[None]
    rgb, bands, c = _arrays(truth, [0], filter_size=8.0)
    sigma = 0.05 * float(truth.mean())
    noisy = bands.copy(data=bands.values + rng.normal(scale=sigma, size=bands.shape).astype(np.float32))
    mixture = np.broadcast_to(base[:, None, None, None], (WAVELENGTH.size, 1, size, size)).copy()
    return truth.transpose(1, 0, 2, 3), inputs_from_xarray(rgb, noisy, c), mixture, inside, sigma


def test_local_correction_detail_layer_recovers_a_narrow_spot_and_leaves_noise_out():
    truth, inputs, mixture, inside, sigma = _spot_scene(13)
    coarse = local_correction(inputs, mixture.copy(), detail_scale=None)
    both = local_correction(inputs, mixture.copy())
    spot = (slice(None), 0) + inside[1:]

    def rms(cube, where):
        return float(np.sqrt(np.mean((cube[where] - truth[where]) ** 2)))

    # the coarse window spreads the spot's residual over about 5 px; the detail keeps it
    assert rms(both, spot) < 0.85 * rms(coarse, spot)
    assert rms(coarse, spot) < rms(mixture, spot)
    # where the mixture was right, neither adds more than a tenth of the band noise
    away = np.ones(truth.shape[2:], dtype=bool)
    away[18:29, 18:29] = False
    outside = (slice(None), 0, away)
    assert rms(both, outside) < 0.1 * sigma
    assert rms(both, outside) < 1.2 * rms(coarse, outside)
