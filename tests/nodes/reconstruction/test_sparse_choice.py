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
from spectralize.nodes.reconstruction.estimators.sparse_choice import (
    neighbour_candidates,
    rgb_similar_neighbours,
    sparse_choice,
)
from spectralize.nodes.reconstruction.inputs import ReconstructionInputs
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


def _metamer_set(rng: np.random.Generator) -> tuple[ReconstructionInputs, Endmembers, np.ndarray]:
    """A 7 x 7 set of 4 images: every texel holds material ``A``; the centre texel's band
    shots are those of ``B``, a metamer of ``A`` (the same RGB through ``C``), as noisy shots
    can make them. The library holds ``A``, ``B``, a third colour and the light."""
    n_wl, size, n_image = 8, 7, 4
    wavelength = np.linspace(450.0, 650.0, n_wl)
    camera = rng.uniform(0.1, 1.0, (3, n_wl))
    a = rng.uniform(0.4, 0.8, n_wl)
    null = np.linalg.svd(camera)[2][-1]
    b = a + 0.3 * null / np.abs(null).max()
    other = np.linspace(0.9, 0.1, n_wl)
    light = np.ones(n_wl)
    shade = np.array([1.0, 0.8, 0.6, 0.9])
    rgb = np.empty((n_image, size, size, 3))
    rgb[:] = (shade[:, None] * (camera @ a)[None])[:, None, None, :]
    rgb *= 1.0 + 1e-4 * rng.standard_normal(rgb.shape)
    band = np.tile(np.arange(n_wl), n_image)
    image = np.repeat(np.arange(n_image), n_wl)
    shots = shade[image][:, None, None] * a[band][:, None, None] * np.ones((1, size, size))
    shots[:, size // 2, size // 2] = shade[image] * b[band]
    shots *= 1.0 + 0.01 * rng.standard_normal(shots.shape)
    inputs = ReconstructionInputs(
        rgb=rgb,
        band_data=shots,
        band=band,
        image=image,
        filter_size=np.ones(band.size),
        camera_matrix=camera,
        wavelength=wavelength,
        illuminant=light,
    )
    atoms = np.vstack([a, b, other, light])
    library = Endmembers(atoms, np.zeros((3, 2)), np.ones(3))
    return inputs, library, atoms


def _nearer_to(cube: np.ndarray, y: int, x: int, atoms: np.ndarray) -> int:
    """The library atom whose shape is nearest the texel's spectrum in image 0."""
    s = cube[:, 0, y, x] / np.linalg.norm(cube[:, 0, y, x])
    shapes = atoms[:2] / np.linalg.norm(atoms[:2], axis=1, keepdims=True)
    return int(np.argmin(np.linalg.norm(shapes - s, axis=1)))


def test_rgb_similar_neighbours_overrule_a_texels_misleading_band_shots():
    inputs, library, atoms = _metamer_set(np.random.default_rng(3))
    alone = sparse_choice(inputs, endmembers=library)
    pooled = sparse_choice(inputs, endmembers=library, context=8, context_radius=1)
    # alone, the centre follows its own shots to the metamer B; its RGB-similar neighbours,
    # whose shots show A, take it back to A; the neighbours themselves keep A
    assert _nearer_to(alone, 3, 3, atoms) == 1
    assert _nearer_to(pooled, 3, 3, atoms) == 0
    assert all(_nearer_to(pooled, y, x, atoms) == 0 for y, x in [(2, 3), (3, 2), (0, 0), (6, 6)])
    # without context the option changes nothing
    np.testing.assert_array_equal(sparse_choice(inputs, endmembers=library, context=0), alone)


def test_rgb_similar_neighbours_come_from_the_window_and_stop_at_rgb_edges():
    rgb = np.ones((2, 4, 4, 3))
    rgb[:, :, 2:] = 2.0  # an RGB edge between columns 1 and 2
    variance = np.full((2, 16), 1e-2)
    flat = rgb.reshape(2, 16, 3)
    index, distance = rgb_similar_neighbours(flat, variance, 4, 4, count=3, radius=1)
    # texel (1, 1) finds three of its same-side neighbours, none across the edge
    assert set(index[5]) <= {0, 1, 4, 8, 9} and np.all(distance[5] == 0)
    index, distance = rgb_similar_neighbours(flat, variance, 4, 4, count=5, radius=1)
    # texel (0, 1) at the edge: its three same-side neighbours first, then the two across
    assert set(index[1, :3]) == {0, 4, 5} and np.all(distance[1, :3] == 0)
    assert set(index[1, 3:]) == {2, 6} and np.all(distance[1, 3:] > 0)
    # the corner (0, 0) has three neighbours in its window; the missing two are itself at inf
    assert set(index[0, :3]) == {1, 4, 5} and np.all(np.isinf(distance[0, 3:]))
    assert np.all(index[0, 3:] == 0)


def test_neighbour_candidates_add_the_atoms_the_neighbours_chose():
    # 3 texels, atoms 0..5 and the light 6; each texel's own ranking (2 own + 2 spare) then light
    ranked = np.array([[0, 1, 2, 3, 6], [2, 3, 0, 1, 6], [0, 1, 3, 4, 6]])
    support = np.array([[0, 0], [4, 5], [0, 1]])  # the first pass: texel 1 chose 4 and 5
    index = np.array([[1, 2], [0, 2], [1, 0]])
    weight = np.array([[0.9, 0.1], [0.5, 0.5], [0.8, 0.2]])
    near = neighbour_candidates(ranked, 2, support, index, weight, 2)
    # texel 0: its neighbour 1's atoms 4 and 5 join (atom 1 of texel 2 is its own already)
    assert near[0].tolist() == [0, 1, 4, 5, 6]
    # texel 1: neighbours chose 0 and 1 (0 twice over); no duplicates of its own 2, 3
    assert near[1].tolist() == [2, 3, 0, 1, 6]
    # texel 2: neighbour 1 offers 4 and 5 (0 and 1 are its own)
    assert near[2].tolist() == [0, 1, 4, 5, 6]
    # where the neighbours offer fewer than asked, the texel's own next ranks fill the places
    few = neighbour_candidates(ranked, 2, np.zeros((3, 2), dtype=int), index, weight, 2)
    assert few[0].tolist() == [0, 1, 2, 3, 6] and few[1].tolist() == [2, 3, 0, 1, 6]


def test_borrowed_endmembers_pay_the_candidate_penalty(woven):
    _, inputs, library, _ = woven
    settings = {"endmembers": library, "candidates": 2, "context": 2, "context_radius": 1}
    first = sparse_choice(inputs, **settings)
    free = sparse_choice(inputs, **settings, context_candidates=2, context_candidate_penalty=0.0)
    barred = sparse_choice(inputs, **settings, context_candidates=2, context_candidate_penalty=1e12)
    # free, the neighbours' endmembers change some texels' choice; at a prohibitive cost none
    # is taken and the choice is the first pass's
    assert not np.array_equal(free, first)
    np.testing.assert_array_equal(barred, first)
