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


def _mixed_set(rng: np.random.Generator) -> tuple[ReconstructionInputs, np.ndarray, np.ndarray]:
    """A 5 x 5 set of 3 images whose RGB are mixtures of library atoms with some negative
    weights (so that many unconstrained fits go negative), band shots in no image order;
    the atoms (the light last) and each texel's candidates (two materials and the light)."""
    n_wl, size, n_image, n_atoms = 6, 5, 3, 6
    camera = rng.uniform(0.1, 1.0, (3, n_wl))
    atoms = rng.uniform(0.05, 1.0, (n_atoms, n_wl))
    n_texel = size * size
    picks = np.stack([rng.choice(n_atoms - 1, 2, replace=False) for _ in range(n_texel)])
    candidates = np.hstack([picks, np.full((n_texel, 1), n_atoms - 1)]).astype(np.int64)
    weights = rng.uniform(-0.4, 1.0, (n_image, n_texel, 3))
    rgb = np.einsum("mpa,paw,cw->mpc", weights, atoms[candidates], camera)
    rgb += 0.05 * rng.standard_normal(rgb.shape)
    image = np.array([2, 0, 2, 1, 0, 2])
    band = rng.integers(0, n_wl, image.size)
    spectra = np.einsum("mpa,paw->mpw", weights, atoms[candidates])
    shots = spectra[image, :, band] + 0.01 * rng.standard_normal((image.size, n_texel))
    inputs = ReconstructionInputs(
        rgb=rgb.reshape(n_image, size, size, 3),
        band_data=shots.reshape(image.size, size, size),
        band=band,
        image=image,
        filter_size=np.ones(image.size),
        camera_matrix=camera,
        wavelength=np.linspace(450.0, 650.0, n_wl),
        illuminant=atoms[-1],
    )
    return inputs, atoms, candidates


def _nnls_costs(inputs: ReconstructionInputs, atoms: np.ndarray, candidates: np.ndarray):
    """Reference step 2: per image and support the best feasible (all weights >= 0) of all
    its sub-supports by RGB cost, the empty one included, found by enumerating them with
    plain least squares; its rgb + band cost summed over the images ``(n_subset, n_texel)``,
    the supports, and how many (support, texel, image) triples of a support of 2 and 3 atoms
    took a sub-support of each smaller size (``taken[support size - 2, sub-support size]``)."""
    from itertools import combinations

    from spectralize.nodes.reconstruction.estimators.endmember_mixture import band_noise_sigma
    from spectralize.nodes.reconstruction.estimators.sparse_choice import _rgb_variance

    rgb = inputs.rgb.reshape(inputs.n_image, -1, 3)
    variance = _rgb_variance(rgb, 0.03)
    shots = inputs.band_data.reshape(inputs.band_data.shape[0], -1)
    shot_variance = band_noise_sigma(inputs) ** 2
    subsets = [s for k in (1, 2, 3) for s in combinations(range(3), k)]
    total = np.zeros((len(subsets), candidates.shape[0]))
    taken = np.zeros((2, 3), dtype=int)
    for m in range(inputs.n_image):
        mine = np.flatnonzero(inputs.image == m)
        for p in range(candidates.shape[0]):
            for s, subset in enumerate(subsets):
                best = (np.sum(rgb[m, p] ** 2) / variance[m, p], np.zeros(0), ())
                for k in range(1, len(subset) + 1):
                    for sub in combinations(subset, k):
                        a = atoms[candidates[p, list(sub)]]
                        w = np.linalg.lstsq((a @ inputs.camera_matrix.T).T, rgb[m, p], rcond=None)[0]
                        fit = np.sum((rgb[m, p] - w @ a @ inputs.camera_matrix.T) ** 2) / variance[m, p]
                        if (w >= 0).all() and fit < best[0]:
                            best = (fit, w, sub)
                fit, w, sub = best
                predicted = w @ atoms[candidates[p, list(sub)]][:, inputs.band[mine]] if sub else 0.0
                spread = shot_variance[mine] + (0.1 * predicted) ** 2
                total[s, p] += fit + np.sum((predicted - shots[mine, p]) ** 2 / spread)
                if len(subset) > 1 and len(sub) < len(subset):
                    taken[len(subset) - 2, len(sub)] += 1
    return total, subsets, taken


def test_the_compiled_support_costs_are_the_exact_nnls_over_the_sub_supports():
    from spectralize.nodes.reconstruction.estimators.sparse_choice import support_costs

    inputs, atoms, candidates = _mixed_set(np.random.default_rng(5))
    expected, subsets, taken = _nnls_costs(inputs, atoms, candidates)
    # the case has 2- and 3-atom supports whose best fits have each fewer number of atoms
    assert (taken[0, :2] > 0).all() and (taken[1] > 0).all()
    found, found_subsets = support_costs(inputs, atoms, candidates, max_support=3)
    assert found_subsets == subsets
    # the fits' small ridge moves the costs of near-singular supports a little
    np.testing.assert_allclose(found, expected, rtol=1e-5)


def test_the_compiled_support_costs_and_choice_are_the_numpy_fits():
    from spectralize.nodes.reconstruction.estimators.sparse_choice import (
        _choose,
        _Evidence,
        _subsets,
        support_costs,
    )

    inputs, atoms, candidates = _mixed_set(np.random.default_rng(6))
    subsets, children = _subsets(3, 3)
    expected = np.zeros((len(subsets), candidates.shape[0]))
    for rgb_cost, band_cost in _Evidence.of(inputs, 0.03).image_costs(
        inputs, atoms, candidates, subsets, children, 0.1
    ):
        expected += rgb_cost + band_cost
    found = support_costs(inputs, atoms, candidates, max_support=3)
    np.testing.assert_allclose(found[0], expected, rtol=1e-10)
    for penalty in (0.0, 3.0, 30.0):
        np.testing.assert_array_equal(
            _choose(candidates, found, penalty, 3), _choose(candidates, (expected, subsets), penalty, 3)
        )


def _dichromatic_reference(atoms_rgb, rgb, variance, count):
    """Step 1 with numpy: every material's two-atom NNLS with the light, per image."""
    n_atoms = atoms_rgb.shape[1]
    cost = np.zeros((n_atoms - 1, rgb.shape[1]))
    for m in range(rgb.shape[0]):
        light = atoms_rgb[m, -1]
        h = np.maximum(rgb[m] @ light / (light @ light), 0.0)
        light_only = ((rgb[m] - h[:, None] * light) ** 2).sum(-1)
        for j in range(n_atoms - 1):
            pair = np.stack([atoms_rgb[m, j], light])
            w = np.linalg.solve(pair @ pair.T, pair @ rgb[m].T).T
            both = ((rgb[m] - w @ pair) ** 2).sum(-1)
            e = atoms_rgb[m, j]
            alone = np.maximum(rgb[m] @ e / (e @ e), 0.0)
            material_only = ((rgb[m] - alone[:, None] * e) ** 2).sum(-1)
            cost[j] += (
                np.where((w >= 0).all(-1), both, np.minimum(material_only, light_only)) / variance[m]
            )
    near = np.argsort(cost, axis=0, kind="stable")[:count].T
    return np.hstack([near, np.full((near.shape[0], 1), n_atoms - 1)])


def test_the_compiled_dichromatic_candidates_are_the_numpy_ranking():
    from spectralize.nodes.reconstruction.estimators.sparse_choice import (
        _rgb_variance,
        dichromatic_candidates,
    )

    inputs, atoms, _ = _mixed_set(np.random.default_rng(7))
    rgb = inputs.rgb.reshape(inputs.n_image, -1, 3)
    atoms_rgb = np.einsum("aw,cw->ac", atoms, inputs.camera_matrix)[None].repeat(inputs.n_image, 0)
    variance = _rgb_variance(rgb, 0.03)
    for count in (1, 3, 5):
        np.testing.assert_array_equal(
            dichromatic_candidates(atoms_rgb, rgb, variance, count),
            _dichromatic_reference(atoms_rgb, rgb, variance, count),
        )
