"""Tests of the shared-texel refinement (per-texel shapes shared by a set's images)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction.estimators.shared_texel import (
    highlight_spectrum,
    rgb_misfit,
    shared_texel_refine,
)
from spectralize.nodes.reconstruction.inputs import ReconstructionInputs
from spectralize.schemas import ReconstructionError

from .conftest import camera_matrix_for, smooth_spectra

WAVELENGTH = np.arange(420.0, 701.0, 20.0)
C = camera_matrix_for(WAVELENGTH)


def _shared_set(seed: int = 0, *, n_image: int = 8, size: int = 6, with_bands: int = 4):
    """A set that follows the model exactly: every texel one shape, shaded and lit per image,
    plus a highlight ``h_m L``; every band shot once, round-robin over the first images."""
    rng = np.random.default_rng(seed)
    n_w = WAVELENGTH.size
    n = size * size
    shapes = smooth_spectra(rng, WAVELENGTH, n)  # (n, w)
    ell = np.exp(-0.5 * ((WAVELENGTH - 560.0) / 60.0) ** 2) + 0.2
    shade = rng.uniform(0.3, 1.5, size=(n_image, n))
    gloss = rng.uniform(0.0, 0.3, size=(n_image, n)) * (rng.random((n_image, n)) < 0.3)
    truth = shade[:, None, :] * shapes.T[None] + gloss[:, None, :] * ell[None, :, None]
    truth = truth.reshape(n_image, n_w, size, size)
    band = np.arange(n_w)
    image = band % with_bands
    inputs = ReconstructionInputs(
        rgb=np.einsum("cw,mwyx->myxc", C, truth),
        band_data=truth[image, band].astype(np.float32),
        band=band,
        image=image,
        filter_size=np.full(n_w, 1.0),
        camera_matrix=C,
        wavelength=WAVELENGTH,
    )
    return inputs, np.moveaxis(truth, 0, 1), ell  # truth as (w, m, y, x)


def _wrong_shapes(truth: np.ndarray, seed: int) -> np.ndarray:
    """The truth with every texel's shape distorted the same way in every image."""
    rng = np.random.default_rng(seed)
    tilt = 1.0 + 0.4 * rng.uniform(-1, 1, size=(truth.shape[0], 1, *truth.shape[2:]))
    return truth * tilt


def _error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per image, the median over texels of RMSE over wavelengths / the image's mean."""
    rmse = np.sqrt(np.mean((estimate - truth) ** 2, axis=0))
    return np.median(rmse.reshape(rmse.shape[0], -1), axis=1) / truth.mean(axis=(0, 2, 3))


def test_recovers_a_shared_shape_from_the_bands_of_some_images():
    inputs, truth, ell = _shared_set(0)
    initial = _wrong_shapes(truth, 1)
    sigma = np.full(inputs.band.size, 1e-3)
    out = shared_texel_refine(inputs, initial, ell, rank=1, misfit=None, rounds=40, band_sigma=sigma)
    before, after = _error(initial, truth), _error(out, truth)
    assert out.shape == truth.shape and np.all(out >= 0)
    assert np.all(after < 0.15 * before), (before, after)
    assert after.max() < 0.03
    # images without band shots get the shape from the others' shots through their RGB
    assert after[4:].max() < 1.5 * max(after[:4].max(), 1e-3)


def test_highlight_spectrum_is_the_direction_common_to_the_texels():
    _, truth, ell = _shared_set(2)
    found = highlight_spectrum(truth)
    cosine = found @ ell / np.linalg.norm(ell)
    assert cosine > 0.99


def test_rgb_misfit_is_zero_for_the_model_and_large_for_three_colours():
    inputs, _, _ = _shared_set(3)
    assert rgb_misfit(inputs, 1).max() < 1e-6
    rgb = inputs.rgb.copy()
    rgb[:3, 0, 0] = np.eye(3)  # three images of texel (0, 0) in three unrelated colours
    mixed = ReconstructionInputs(**{**inputs.__dict__, "rgb": rgb})
    assert rgb_misfit(mixed, 1)[0, 0] > 0.1


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"initial": np.zeros((3, 2, 6, 6))}, "initial: expected shape"),
        ({"initial": "nan"}, "initial: expected finite"),
        ({"highlight": np.zeros(WAVELENGTH.size)}, "highlight: expected a finite spectrum"),
        ({"highlight": np.ones(4)}, "highlight: expected shape"),
        ({"rank": 0}, "rank: expected 1 .. n_image=8"),
    ],
)
def test_bad_input_is_named(change, message):
    inputs, truth, ell = _shared_set(4)
    arguments = {"initial": truth.copy(), "highlight": ell, "rank": 1}
    arguments.update(change)
    if isinstance(arguments["initial"], str):
        arguments["initial"] = truth.copy()
        arguments["initial"][0, 0, 0, 0] = np.nan
    with pytest.raises(ReconstructionError, match=message):
        shared_texel_refine(inputs, **arguments)
