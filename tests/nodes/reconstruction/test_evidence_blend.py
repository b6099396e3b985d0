"""The evidence blend of a set's two estimates (default and material choice) per texel."""

from dataclasses import replace

import numpy as np
import pytest

from spectralize.nodes.reconstruction import inputs_from_xarray, reconstruct
from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers
from spectralize.nodes.reconstruction.estimators.evidence_blend import (
    DEFAULT_PRIOR_LOG_ODDS,
    choice_log_odds,
    evidence_blend,
    material_choice_blend,
    set_appearance_bins,
)
from spectralize.schemas.errors import ReconstructionError

from .conftest import make_scene
from .test_material_prior import _arrays
from .test_set_model import _light, _wavelength
from .test_spectral_prior import _mixed_truth


def _set(n_image: int, noise: float, seed: int = 0):
    """A set of ``n_image`` images of one sample (the right half's materials tilted across
    wavelength: other colours than the left's), band shots of every wavelength in image 0
    with white noise ``noise`` x the mean; the inputs, the truth ``(wavelength, image, y,
    x)`` and the shots' sigma."""
    truth = _mixed_truth(seed, n_image=n_image)
    tilt = np.linspace(0.2, 1.8, truth.shape[1])[None, :, None, None]
    truth[..., truth.shape[-1] // 2 :] *= tilt
    rgb, bands, c = _arrays(truth, [0])
    sigma = noise * float(truth.mean())
    rng = np.random.default_rng(seed + 7)
    bands = bands.copy(
        data=(bands.values + rng.normal(scale=sigma, size=bands.shape)).astype(np.float32)
    )
    inputs = inputs_from_xarray(rgb, bands, c)
    return inputs, np.moveaxis(truth, 1, 0), np.full(len(inputs.band), sigma)


def _error(cube: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean((cube - truth) ** 2)) / np.mean(truth))


def test_each_texel_follows_the_estimate_its_band_shots_confirm():
    inputs, truth, sigma = _set(3, noise=0.01)
    left = (np.arange(truth.shape[-1]) < truth.shape[-1] // 2)[None, None, None, :]
    default = truth * np.where(left, 1.3, 1.0)  # wrong on the left half
    choice = truth * np.where(left, 1.0, 1.3)  # wrong on the right half
    blended, pi = evidence_blend(inputs, default, choice, sigma=sigma)
    # either estimate alone is 10-15 % off; the blend takes the right one per texel, in the
    # images without band shots too (the weight is the texel's, over its set)
    assert min(_error(default, truth), _error(choice, truth)) > 0.1
    assert _error(blended, truth) < 0.01 * _error(default, truth)
    assert pi[:, left[0, 0, 0]].max() < 1e-6 and pi[:, ~left[0, 0, 0]].min() > 1 - 1e-6


def test_without_evidence_the_default_keeps_its_prior_odds():
    inputs, truth, sigma = _set(2, noise=1000.0)  # shots that are all noise
    choice = 1.3 * truth
    blended, pi = evidence_blend(inputs, truth, choice, sigma=sigma)
    expected = 1.0 / (1.0 + np.exp(-DEFAULT_PRIOR_LOG_ODDS))
    np.testing.assert_allclose(pi, expected, atol=1e-3)
    # equal estimates: no evidence, the prior odds alone
    np.testing.assert_allclose(
        choice_log_odds(inputs, truth, truth, sigma=sigma), -DEFAULT_PRIOR_LOG_ODDS
    )
    # the blend is the posterior mean of the two
    np.testing.assert_allclose(blended, pi * truth + (1.0 - pi) * choice, rtol=1e-12)


def test_shapes_and_a_wrong_estimate_shape():
    inputs, truth, sigma = _set(2, noise=0.01)
    blended, pi = evidence_blend(inputs, truth, 1.1 * truth, sigma=sigma)
    assert blended.shape == inputs.cube_shape and blended.dtype == np.float64
    assert pi.shape == (inputs.height, inputs.width) and ((pi >= 0) & (pi <= 1)).all()
    bins = set_appearance_bins(inputs.rgb)
    assert bins.shape == pi.shape and bins.dtype.kind == "i"
    with pytest.raises(ReconstructionError, match="choice: expected shape"):
        evidence_blend(inputs, truth, truth[:, :1], sigma=sigma)


def test_one_image_and_no_band_shots():
    inputs, truth, sigma = _set(1, noise=0.01)
    wrong = 1.3 * truth
    blended, pi = evidence_blend(inputs, wrong, truth, sigma=sigma)
    assert blended.shape == truth.shape and pi.max() < 1e-6  # one image: texel = pixel
    assert _error(blended, truth) < 1e-6
    none = replace(
        inputs,
        band_data=inputs.band_data[:0],
        band=inputs.band[:0],
        image=inputs.image[:0],
        filter_size=inputs.filter_size[:0],
    )
    kept, pi = evidence_blend(none, wrong, truth)
    np.testing.assert_array_equal(kept, wrong)
    np.testing.assert_array_equal(pi, 1.0)


def test_the_defaults_set_step_weighs_in_the_choice_from_the_runs_library():
    scene = make_scene(size=14, n_wavelength=6, n_images=3, shading=True, noise=0.1, seed=3)
    args = (scene.rgb, scene.bands, scene.camera_matrix)
    light = _light(_wavelength(scene))
    inputs = inputs_from_xarray(*args, illuminant=light)
    library = set_endmembers(inputs, n_endmembers=4)  # stands for the run's library
    pooled = reconstruct(*args, illuminant=light, set_model="material-pooled", endmembers=library)
    blended = reconstruct(*args, illuminant=light, endmembers=library)
    assert blended.attrs["set_model"] == "evidence-blend"
    expected = material_choice_blend(inputs, np.moveaxis(pooled.values, 0, 1).copy(), library)
    np.testing.assert_allclose(np.moveaxis(blended.values, 0, 1), expected, rtol=1e-6, atol=1e-7)
    assert not np.array_equal(blended.values, pooled.values)
    # without the run's library the pooled refit is kept, and recorded so
    own = reconstruct(*args, illuminant=light)
    assert own.attrs["set_model"] == "material-pooled"
    np.testing.assert_array_equal(
        own.values, reconstruct(*args, illuminant=light, set_model="material-pooled").values
    )
    # one image: no set step, the solve as it is
    single = (scene.rgb.isel(image=[0]), scene.bands.where(scene.bands["image"] == 0, drop=True))
    one = reconstruct(*single, scene.camera_matrix, illuminant=light, endmembers=library)
    alone = reconstruct(
        *single, scene.camera_matrix, illuminant=light, endmembers=library, set_model="independent"
    )
    assert one.sizes["image"] == 1
    np.testing.assert_array_equal(one.values, alone.values)
