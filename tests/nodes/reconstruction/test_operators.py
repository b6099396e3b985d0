"""Operators of eq. 1: filter placement, adjoints, normal operator, energy."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import (
    FilterConstraints,
    NeighbourGraph,
    appearance_neighbours,
    build_problem,
    filter_centres,
    gaussian_filter_matrix,
    inputs_from_xarray,
)
from spectralize.nodes.reconstruction.operators import rgb_adjoint, rgb_forward


def _inner(a, b) -> float:
    return float(np.sum(np.asarray(a, np.float64) * np.asarray(b, np.float64)))


# -- filter placement ---------------------------------------------------------------------
@pytest.mark.parametrize(
    ("length", "size", "spacing"), [(64, 10.0, 2.5), (100, 25.0, 2.5), (31, 5.0, 2.5), (50, 7.3, 1.0)]
)
def test_filter_centres_keep_border_distance_and_spacing(length, size, spacing):
    centres = filter_centres(length, size, centre_spacing=spacing)
    assert centres[0] == pytest.approx(size)
    assert centres[-1] == pytest.approx(length - 1 - size)
    assert np.all(centres >= size - 1e-12)
    assert np.all(centres <= length - 1 - size + 1e-12)
    gaps = np.diff(centres)
    assert np.all(gaps <= spacing + 1e-9)
    # the fewest centres that keep every gap <= d
    assert len(centres) == int(np.ceil((length - 1 - 2 * size) / spacing - 1e-9)) + 1


def test_filter_centre_count_example():
    # 64 px, s = 10: centres from 10 to 53 (43 px), every <= 2.5 px: 19 centres
    assert len(filter_centres(64, 10.0)) == 19
    # exactly one centre when the filter just fits
    assert len(filter_centres(21, 10.0)) == 1


def test_filter_centres_reject_filters_larger_than_the_axis():
    with pytest.raises(ValueError, match="no filter centre"):
        filter_centres(20, 10.0)


def test_gaussian_filter_rows_are_normalised_gaussians_inside_the_image():
    matrix = gaussian_filter_matrix(80, 15.0).toarray()
    centres = filter_centres(80, 15.0)
    np.testing.assert_allclose(matrix.sum(axis=1), 1.0, rtol=1e-12)
    pixels = np.arange(80)
    for row, centre in zip(matrix, centres, strict=True):
        mean = row @ pixels
        var = row @ (pixels - mean) ** 2
        assert mean == pytest.approx(centre, abs=1e-4)  # truncation at 5 sigma
        assert np.sqrt(var) == pytest.approx(15.0 / 5, rel=0.01)  # sigma = s / 5
        support = pixels[row > 0]
        assert support.min() >= 0 and support.max() <= 79
        assert np.all(np.abs(support - centre) <= 15.0)


def _random_filters(rng, shape=(4, 2, 23, 19)):
    n_wavelength, n_image, height, width = shape
    band = np.array([0, 1, 3, 3, 2])
    image = np.array([0, 1, 1, 0, 0])
    size = np.array([3.0, 5.5, 2.0, 4.0, 8.0])
    return FilterConstraints(shape, band, image, size, centre_spacing=2.5)


def test_filter_operator_adjoint_and_count():
    rng = np.random.default_rng(1)
    filters = _random_filters(rng)
    x = rng.normal(size=filters.shape)
    forward = filters.forward(x)
    y = [rng.normal(size=r.shape) for r in forward]
    lhs = sum(_inner(a, b) for a, b in zip(forward, y, strict=True))
    rhs = _inner(x, filters.adjoint(y))
    assert lhs == pytest.approx(rhs, rel=1e-12)
    assert filters.count == sum(r.size for r in forward)
    assert filters.count == sum(ny * nx for ny, nx in filters.centre_grid)


def test_filter_normal_and_diagonal_match_the_dense_operator():
    rng = np.random.default_rng(2)
    shape = (2, 1, 11, 9)
    filters = FilterConstraints(
        shape, np.array([0, 1, 1]), np.array([0, 0, 0]), np.array([2.0, 3.0, 2.5])
    )
    n = int(np.prod(shape))
    dense = np.zeros((filters.count, n))
    for j in range(n):
        unit = np.zeros(n)
        unit[j] = 1.0
        dense[:, j] = np.concatenate([r.ravel() for r in filters.forward(unit.reshape(shape))])
    x = rng.normal(size=shape)
    np.testing.assert_allclose(filters.normal(x).ravel(), dense.T @ dense @ x.ravel(), atol=1e-12)
    np.testing.assert_allclose(filters.normal_diagonal().ravel(), np.diag(dense.T @ dense), atol=1e-12)


@pytest.mark.parametrize("height", [40, 120])  # below and above DENSE_AXIS_BELOW (96)
def test_filter_responses_are_the_sparse_filter_matrices_products(height):
    """Short axes keep their filter matrices dense (a tiny tile's fixed cost), long ones
    sparse: either way one shot's responses are ``G_y X G_x^T`` and its adjoint ``G_y^T R G_x``."""
    rng = np.random.default_rng(3)
    width = 90
    filters = FilterConstraints((1, 1, height, width), np.array([0]), np.array([0]), np.array([7.0]))
    g_y = gaussian_filter_matrix(height, 7.0).toarray()
    g_x = gaussian_filter_matrix(width, 7.0).toarray()
    plane = rng.normal(size=(height, width))
    responses = filters.apply_plane(0, plane)
    np.testing.assert_allclose(responses, g_y @ plane @ g_x.T, rtol=1e-12, atol=1e-12)
    back = rng.normal(size=responses.shape)
    np.testing.assert_allclose(
        filters.adjoint_plane(0, back), g_y.T @ back @ g_x, rtol=1e-12, atol=1e-12
    )


def test_rgb_operator_adjoint():
    rng = np.random.default_rng(3)
    c = rng.normal(size=(3, 6))
    x = rng.normal(size=(6, 2, 5, 4))
    y = rng.normal(size=(3, 40))
    assert _inner(rgb_forward(x, c), y) == pytest.approx(
        _inner(x, rgb_adjoint(y, c, x.shape)), rel=1e-12
    )


def test_neighbour_operator_adjoint_and_laplacian():
    rng = np.random.default_rng(4)
    points = rng.normal(size=(50, 3))
    graph = NeighbourGraph(appearance_neighbours(points, k=3))
    x = rng.normal(size=(5, 50))
    y = rng.normal(size=(5, graph.n_pairs))
    assert _inner(graph.differences(x), y) == pytest.approx(
        _inner(x, graph.differences_adjoint(y)), rel=1e-12
    )
    np.testing.assert_allclose(
        graph.laplacian_apply(x, scale=2.5),
        2.5 * graph.differences_adjoint(graph.differences(x)),
        atol=1e-12,
    )
    # degree = out-degree (k) + in-degree
    in_degree = np.bincount(graph.neighbours.ravel(), minlength=50)
    np.testing.assert_allclose(graph.degree, 3 + in_degree)
    assert graph.n_pairs == 150


@pytest.fixture
def problem(scene_factory):
    scene = scene_factory(
        size=20, n_wavelength=5, n_images=2, shading=True, noise=0.05, shots={0: [0, 1, 2, 3, 4], 1: [2]}
    )
    return build_problem(inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix))


def test_stacked_operator_adjoint(problem):
    rng = np.random.default_rng(5)
    x = rng.normal(size=problem.shape)
    applied = problem.apply(x)
    y = (
        [rng.normal(size=r.shape) for r in applied[0]],
        rng.normal(size=applied[1].shape),
        rng.normal(size=applied[2].shape),
    )
    lhs = (
        sum(_inner(a, b) for a, b in zip(applied[0], y[0], strict=True))
        + _inner(applied[1], y[1])
        + _inner(applied[2], y[2])
    )
    assert lhs == pytest.approx(_inner(x, problem.apply_adjoint(y)), rel=1e-11)


def test_normal_operator_is_a_transpose_a(problem):
    rng = np.random.default_rng(6)
    x = rng.normal(size=problem.shape)
    np.testing.assert_allclose(
        problem.normal(x), problem.apply_adjoint(problem.apply(x)), rtol=1e-10, atol=1e-10
    )
    np.testing.assert_allclose(
        problem.normal_rhs(), problem.apply_adjoint(problem.target()), rtol=1e-10, atol=1e-12
    )
    # symmetric positive semi-definite
    z = rng.normal(size=problem.shape)
    assert _inner(problem.normal(x), z) == pytest.approx(_inner(x, problem.normal(z)), rel=1e-10)
    assert _inner(problem.normal(x), x) > 0


def test_energy_is_the_sum_of_the_three_terms(problem):
    rng = np.random.default_rng(7)
    x = rng.normal(size=problem.shape)
    w = problem.weights
    filt = sum(
        float(np.sum((a - t) ** 2))
        for a, t in zip(problem.filters.forward(x), problem.filter_targets, strict=True)
    )
    rgb = float(np.sum((rgb_forward(x, problem.camera_matrix) - problem.rgb) ** 2))
    nbr = float(np.sum(problem.neighbours.differences(x.reshape(x.shape[0], -1)) ** 2))
    expected = w.alpha * filt + w.beta * rgb + w.gamma * nbr
    assert problem.energy(x) == pytest.approx(expected, rel=1e-10)
    # the energy's gradient is 2 (A^T A x - A^T b)
    d = rng.normal(size=problem.shape)
    eps = 1e-6
    numeric = (problem.energy(x + eps * d) - problem.energy(x - eps * d)) / (2 * eps)
    analytic = 2 * _inner(problem.normal(x) - problem.normal_rhs(), d)
    assert numeric == pytest.approx(analytic, rel=1e-5)


def test_float32_problem_matches_float64(problem):
    rng = np.random.default_rng(8)
    x = rng.normal(size=problem.shape)
    single = problem.astype(np.float32)
    assert single.dtype == np.float32
    result = single.normal(x.astype(np.float32))
    assert result.dtype == np.float32
    np.testing.assert_allclose(
        result, problem.normal(x), rtol=1e-3, atol=1e-4 * np.abs(problem.normal(x)).max()
    )
