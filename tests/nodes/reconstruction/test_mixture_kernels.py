"""The compiled passes of the endmember mixture and of the guided filter equal the numpy
code they replace (kept here as the reference)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from spectralize.nodes.reconstruction import inputs_from_xarray
from spectralize.nodes.reconstruction.baselines import guided_filter
from spectralize.nodes.reconstruction.baselines.guided_filter import (
    _box_widths,
    _symmetric_inverse,
    gaussian_window,
    guided_filtered_stacks,
)
from spectralize.nodes.reconstruction.estimators.endmember_mixture import (
    Endmembers,
    neighbourhood_candidates,
)
from spectralize.nodes.reconstruction.kernels import mix_atoms

from .test_material_prior import _arrays
from .test_mixture import _blocks


def _numpy_candidates(centres: np.ndarray, chroma: np.ndarray, k: int) -> np.ndarray:
    """The numpy candidate search replaced by ``nearest_centres`` (distances, stable sort)."""
    d2 = ((chroma[:, None, :] - centres[None]) ** 2).sum(axis=-1)
    return np.argsort(d2, axis=1, kind="stable")[:, :k]


@pytest.mark.parametrize("k", [1, 3, 5])
def test_nearest_centres_are_the_sorted_distances(k):
    rng = np.random.default_rng(k)
    centres = rng.uniform(size=(5, 2))
    chroma = rng.uniform(size=(400, 2))
    chroma[:5] = centres  # a pixel on a centre, and
    chroma[5] = 0.5 * (centres[0] + centres[1])  # one half-way between two
    near = Endmembers(np.zeros((6, 4)), centres, np.ones(3)).candidates(chroma, k)
    assert near.shape == (400, k + 1) and (near[:, k] == 5).all()
    np.testing.assert_array_equal(near[:, :k], _numpy_candidates(centres, chroma, k))


def _numpy_neighbourhood(inputs, near, weights, count, sigma=1.5):
    """The per-atom numpy loop replaced by ``share_planes``/``top_planes``."""
    n_atoms = int(near.max()) + 1
    shape = (inputs.n_image, inputs.height, inputs.width)
    share = weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
    best = np.full((near.shape[0], count), -1.0)
    index = np.zeros((near.shape[0], count), dtype=np.intp)
    for j in range(n_atoms - 1):
        plane = np.zeros(near.shape[0])
        for a in range(near.shape[1]):
            plane += np.where(near[:, a] == j, share[:, a], 0.0)
        plane = ndimage.gaussian_filter(plane.reshape(shape), (0, sigma, sigma), mode="reflect").ravel()
        for c in range(count):
            better = plane > best[:, c]
            if c + 1 < count:
                best[better, c + 1 :] = best[better, c:-1]
                index[better, c + 1 :] = index[better, c:-1]
            best[better, c] = plane[better]
            index[better, c] = j
            plane = np.where(better, -1.0, plane)
    return index


def test_compiled_neighbourhood_candidates_equal_the_per_atom_loop():
    truth = _blocks(3, size=24, n_image=2)
    rgb, bands, c = _arrays(truth, [0])
    inputs = inputs_from_xarray(rgb, bands, c)
    rng = np.random.default_rng(1)
    n = inputs.n_image * 24 * 24
    near = np.column_stack([rng.integers(0, 6, size=(n, 3)), np.full(n, 6)])
    weights = rng.uniform(size=(n, 4)) * (rng.uniform(size=(n, 4)) > 0.3)
    weights[:7] = 0.0  # pixels without abundance
    for count in (1, 2, 3):
        np.testing.assert_array_equal(
            neighbourhood_candidates(inputs, near, weights, count),
            _numpy_neighbourhood(inputs, near, weights, count),
        )


def test_mix_atoms_equals_the_gathered_einsum():
    rng = np.random.default_rng(2)
    atoms = rng.uniform(size=(7, 11))
    near = rng.integers(0, 7, size=(150, 5))
    weights = rng.uniform(size=(150, 5)) * (rng.uniform(size=(150, 5)) > 0.4)
    cube = np.empty((11, 150))
    mix_atoms(weights, near, atoms, cube)
    np.testing.assert_allclose(cube, np.einsum("pk,pkw->wp", weights, atoms[near]), rtol=1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("sigma", [2.0, 3.7, 11.0])
def test_compiled_box_windows_equal_scipy_running_means(dtype, sigma):
    rng = np.random.default_rng(3)
    planes = rng.normal(size=(2, 3, 23, 31)).astype(dtype)
    before = planes.copy()
    expected = planes
    for width in _box_widths(sigma):
        for axis in (-2, -1):
            expected = ndimage.uniform_filter1d(expected, width, axis=axis, mode="reflect")
    found = gaussian_window(planes, sigma)
    np.testing.assert_array_equal(planes, before)  # the input is left alone
    assert found.dtype == dtype and found.shape == planes.shape
    np.testing.assert_allclose(found, expected, atol=1e-6 if dtype == np.float32 else 1e-13)


def test_adjugate_inverse_equals_the_lu_inverse():
    rng = np.random.default_rng(4)
    factor = rng.normal(size=(5, 7, 3, 3))
    matrices = factor @ np.swapaxes(factor, -1, -2) + 0.1 * np.eye(3)
    planes = {(c, d): matrices[..., c, d] for c in range(3) for d in range(c, 3)}
    inverse = _symmetric_inverse(planes)
    expected = np.linalg.inv(matrices)
    for n, (c, d) in enumerate(zip(*np.triu_indices(3), strict=True)):
        np.testing.assert_allclose(inverse[n], expected[..., c, d], rtol=2e-5, atol=1e-6)


@pytest.mark.parametrize("window_scale", [1.0, 3.0])  # Gaussian windows, then box windows
def test_guided_filter_of_shots_in_one_pass_equals_it_shot_by_shot(monkeypatch, window_scale):
    truth = _blocks(3, size=24, n_image=3)
    rgb, bands, c = _arrays(truth, [0, 1, 2])
    sizes = np.resize([3.0, 5.0, 7.0, 9.0, 11.0], bands.sizes["shot"])  # several windows
    inputs = inputs_from_xarray(rgb, bands.assign_coords(filter_size=("shot", sizes)), c)
    rng = np.random.default_rng(5)
    stacks = [inputs.band_data, rng.normal(size=inputs.band_data.shape)]
    assert len(np.unique(inputs.filter_size)) > 1 and len(inputs.band) > 3 * inputs.n_image
    together = guided_filtered_stacks(inputs, stacks, window_scale=window_scale)
    monkeypatch.setattr(guided_filter, "GUIDED_CHUNK_PIXELS", 1)  # one shot per pass
    alone = guided_filtered_stacks(inputs, stacks, window_scale=window_scale)
    for a, b in zip(together, alone, strict=True):
        assert a.dtype == np.float32 and np.isfinite(a).all()
        np.testing.assert_array_equal(a, b)
