"""Tests of the ``"sparse-choice"`` estimator: a texel's materials chosen over its set."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import RECONSTRUCTION_METHODS, inputs_from_xarray, reconstruct
from spectralize.nodes.reconstruction.estimators.endmember_mixture import (
    Endmembers,
    chromaticity,
    endmember_mixture,
)
from spectralize.nodes.reconstruction.estimators.sparse_choice import sparse_choice
from spectralize.nodes.simulation.scenes import get_scene
from spectralize.nodes.simulation.scenes.materials import sharp_led
from spectralize.schemas import ReconstructionError


@pytest.fixture(scope="module")
def woven():
    """A 10-image woven-fabric set (16^2), its inputs with the LED, its TRUE endmembers (each
    material's reflectance under the LED, the LED last) as a library, and the sparse choice
    with them."""
    capture = get_scene("woven-fabric", size=16, seed=0, n_images=10)
    led = sharp_led(capture.camera_matrix["wavelength"].values)
    inputs = inputs_from_xarray(capture.rgb, capture.bands, capture.camera_matrix, illuminant=led)
    atoms = np.vstack([capture.layout.reflectance * led[None], led[None]])
    rgb = inputs.rgb_pixels().T
    scale = np.abs(rgb.mean(axis=0))
    _, centres = chromaticity(atoms[:-1] @ inputs.camera_matrix.T, scale)
    library = Endmembers(atoms, centres, scale)
    return capture, inputs, library, sparse_choice(inputs, endmembers=library)


def _median_nrmse(cube: np.ndarray, capture) -> float:
    truth = capture.truth.values.astype(np.float64)
    estimate = np.moveaxis(cube, 0, 1)
    rmse = np.sqrt(np.mean((estimate - truth) ** 2, axis=1))
    return float(np.median(rmse / truth.mean(axis=(1, 2, 3))[:, None, None]))


def test_the_choice_over_the_set_beats_the_chromaticity_choice_with_the_same_library(woven):
    capture, inputs, library, chosen = woven
    nearest = endmember_mixture(inputs, endmembers=library, local=False)
    assert chosen.shape == inputs.cube_shape and chosen.min() >= 0
    # the same exact spectra: only the choice of each texel's materials differs
    assert _median_nrmse(chosen, capture) < 0.5 * _median_nrmse(nearest, capture)


def test_sparse_choice_is_a_method_that_takes_a_library(woven):
    capture, inputs, library, chosen = woven
    assert RECONSTRUCTION_METHODS["sparse-choice"].kind == "estimator"
    led = inputs.illuminant
    out = reconstruct(
        capture.rgb,
        capture.bands,
        capture.camera_matrix,
        method="sparse-choice",
        illuminant=led,
        endmembers=library,
    )
    np.testing.assert_allclose(np.moveaxis(out.values, 1, 0), chosen)


def test_sparse_choice_refuses_a_library_on_other_wavelengths_and_bad_settings(woven):
    _, inputs, library, _ = woven
    short = Endmembers(library.atoms[:, :-1], library.centres, library.scale)
    with pytest.raises(ReconstructionError, match="endmembers"):
        sparse_choice(inputs, endmembers=short)
    with pytest.raises(ReconstructionError, match="max_support"):
        sparse_choice(inputs, endmembers=library, candidates=2, max_support=4)
