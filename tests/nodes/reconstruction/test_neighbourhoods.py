"""Appearance neighbourhoods N_p: k nearest neighbours in RGB over all images of a set."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import appearance_neighbours, build_problem, inputs_from_xarray
from spectralize.nodes.reconstruction.neighbourhoods import appearance_order


def test_neighbours_are_the_k_nearest_other_pixels():
    rng = np.random.default_rng(0)
    points = rng.normal(size=(200, 3))
    found = appearance_neighbours(points, k=3)
    assert found.shape == (200, 3)
    distances = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(distances, np.inf)
    expected = np.argsort(distances, axis=1)[:, :3]
    np.testing.assert_array_equal(np.sort(found, axis=1), np.sort(expected, axis=1))


def test_a_pixel_is_never_its_own_neighbour_even_among_duplicates():
    points = np.zeros((10, 3))  # all identical: every other pixel ties
    found = appearance_neighbours(points, k=3)
    assert found.shape == (10, 3)
    assert not np.any(found == np.arange(10)[:, None])
    assert all(len(set(row)) == 3 for row in found.tolist())


def test_k_is_clipped_to_the_number_of_other_pixels():
    assert appearance_neighbours(np.eye(3), k=5).shape == (3, 2)
    assert appearance_neighbours(np.zeros((1, 3)), k=3).shape == (1, 0)


def test_neighbour_graph_spans_all_images_of_a_set(scene_factory):
    # image 1 shows the same materials twice as bright: its nearest RGB neighbours are in
    # image 1 itself, except where a brighter/darker copy matches across images
    scene = scene_factory(
        size=12,
        n_wavelength=4,
        n_images=3,
        shading=True,
        brightness=[1.0, 1.02, 0.98],
        shots={0: [0, 1, 2, 3]},
    )
    inputs = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    problem = build_problem(inputs, k=3)
    neighbours = problem.neighbours.neighbours
    n_per_image = 12 * 12
    assert neighbours.shape == (3 * n_per_image, 3)
    image_of_pixel = np.arange(3 * n_per_image) // n_per_image
    image_of_neighbour = image_of_pixel[neighbours]
    crossing = image_of_neighbour != image_of_pixel[:, None]
    assert crossing.any(), "the graph must link pixels of different images"
    # every pair found is among the true k nearest over the whole set
    rgb = inputs.rgb_pixels().T
    for p in [0, 5, n_per_image + 7, 2 * n_per_image + 100]:
        d = np.linalg.norm(rgb - rgb[p], axis=1)
        d[p] = np.inf
        assert np.sort(d[neighbours[p]]).max() <= np.sort(d)[2] + 1e-12


def test_neighbour_pixel_order_matches_the_cube_layout(scene_factory):
    """Pixel q of the graph is image q // (h w), row (q % (h w)) // w, column q % w."""
    scene = scene_factory(
        size=6, n_wavelength=4, n_images=2, shading=True, filter_size=2.0, shots={0: [0, 1, 2, 3]}
    )
    inputs = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    rgb = inputs.rgb_pixels()
    q = 36 + 2 * 6 + 5
    np.testing.assert_allclose(rgb[:, q], scene.rgb.values[1, 2, 5])
    with pytest.raises(AssertionError):
        np.testing.assert_allclose(rgb[:, q], scene.rgb.values[0, 2, 5])


@pytest.mark.parametrize("scale_invariant", [False, True])
def test_the_laplacian_is_d_transpose_d(scale_invariant):
    from spectralize.nodes.reconstruction.neighbourhoods import NeighbourGraph

    rng = np.random.default_rng(5)
    n, k = 40, 4
    neighbours = (np.arange(n)[:, None] + rng.integers(1, n, size=(n, k))) % n  # never itself
    neighbours[0, 0], neighbours[1, 0] = 1, 0  # a mutual pair, summed from both sides
    neighbours[:, 1] = np.where(neighbours[:, 1] == n - 1, 0, neighbours[:, 1])  # n - 1: fewer in
    ratios = rng.uniform(0.5, 2.0, size=(n, k)) if scale_invariant else None
    graph = NeighbourGraph(neighbours, np.float64, ratios)
    d = graph.difference_operator.toarray()
    np.testing.assert_allclose(graph.laplacian.toarray(), d.T @ d, atol=1e-12)
    assert graph.laplacian.has_canonical_format
    np.testing.assert_allclose(graph.degree, np.diag(d.T @ d))


def _scipy_laplacian(graph):
    """``diag(degree) - (W + W^T)`` by scipy's sparse sums, in the graph's dtype, canonical."""
    import scipy.sparse as sp

    n, k = graph.neighbours.shape
    pointer = np.arange(0, n * k + 1, k)
    weights = sp.csr_array((graph._ratios(), graph.neighbours.ravel(), pointer), shape=(n, n))
    laplacian = (sp.diags_array(graph.degree, format="csr") - (weights + weights.T)).tocsr()
    laplacian = laplacian.astype(graph.dtype)
    laplacian.sum_duplicates()
    laplacian.sort_indices()
    return laplacian


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_laplacian_is_scipys_sparse_sums_bit_for_bit(dtype):
    """The Laplacian assembled row by row in a compiled pass has the entries, the order and
    the values of ``diag - (W + W^T)`` summed by scipy, bit for bit (the solvers' results do
    not change): mutual pairs, a neighbour listed twice, a pixel its own neighbour, pairs of
    ratio 0 (entries that cancel are left out), in float32 and float64."""
    from spectralize.nodes.reconstruction.neighbourhoods import NeighbourGraph

    rng = np.random.default_rng(11)
    n, k = 60, 5
    neighbours = rng.integers(0, n, size=(n, k))
    neighbours[0, :2] = 7  # listed twice
    neighbours[3, 0] = 3  # its own neighbour
    neighbours[4, 0], neighbours[5, 0] = 5, 4  # a mutual pair
    ratios = rng.uniform(0.2, 3.0, size=(n, k))
    ratios[rng.random((n, k)) < 0.2] = 0.0
    for given in (None, ratios):
        graph = NeighbourGraph(neighbours, dtype, given)
        built, expected = graph.laplacian, _scipy_laplacian(graph)
        assert built.shape == expected.shape and built.dtype == expected.dtype
        for name in ("indptr", "indices", "data"):
            assert np.array_equal(getattr(built, name), getattr(expected, name)), name


def test_neighbours_of_some_pixels_are_their_rows_of_all_pixels():
    rng = np.random.default_rng(3)
    points = np.round(rng.normal(size=(300, 3)), 1)  # coarse: many ties among duplicates
    queries = np.array([5, 0, 299, 17, 5, 120])
    every = appearance_neighbours(points, k=4)
    np.testing.assert_array_equal(appearance_neighbours(points, k=4, queries=queries), every[queries])


def test_the_query_order_runs_through_every_feature():
    # pixels alike in their first three features, apart in the fifth (a position)
    points = np.zeros((6, 5))
    points[:, 4] = [5.0, 1.0, 4.0, 0.0, 3.0, 2.0]
    assert appearance_order(points).tolist() == list(range(6))  # the storage order: 3 features
    assert appearance_order(points, features=5).tolist() == [3, 1, 5, 4, 2, 0]


def test_neighbours_come_back_as_contiguous_intp_rows_in_the_asked_order():
    # the tree answers in its compact index type and in the query order: both are undone
    rng = np.random.default_rng(5)
    points = np.round(rng.normal(size=(400, 3)), 1)  # duplicates: some rows take the tie path
    queries = np.array([399, 3, 250, 3, 0])
    for asked in (None, queries):
        found = appearance_neighbours(points, k=3, queries=asked)
        assert found.dtype == np.intp and found.flags.c_contiguous
        rows = np.arange(400) if asked is None else queries
        distances = np.linalg.norm(points[rows][:, None] - points[None], axis=-1)
        distances[np.arange(rows.size), rows] = np.inf
        nearest = np.sort(distances, axis=1)[:, :3]
        np.testing.assert_allclose(np.take_along_axis(distances, found, axis=1), nearest, atol=1e-12)
