"""The compiled pixel-major passes agree with the operators they replace, in any pixel order."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import build_problem, inputs_from_xarray
from spectralize.nodes.reconstruction.neighbourhoods import appearance_order
from spectralize.nodes.reconstruction.solvers import BlockJacobiPreconditioner, block_jacobi_pcg
from spectralize.nodes.reconstruction.solvers.common import counting_iterations


@pytest.fixture
def problem(scene_factory):
    scene = scene_factory(
        size=20, n_wavelength=5, n_images=3, shading=True, noise=0.05, shots={0: [0, 1, 2, 3, 4], 1: [2]}
    )
    return build_problem(inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix))


def test_appearance_order_is_a_permutation_that_groups_alike_pixels():
    rng = np.random.default_rng(0)
    colours = rng.random((6, 3))
    pixels = colours[rng.integers(0, 6, 600)] + rng.normal(scale=1e-4, size=(600, 3))
    order = appearance_order(pixels)
    assert np.array_equal(np.sort(order), np.arange(600))
    # stored in that order, pixels of one colour are contiguous runs: 6 runs, 5 changes
    labels = np.argmin(((pixels[order, None, :] - colours[None]) ** 2).sum(-1), axis=1)
    assert np.count_nonzero(np.diff(labels)) == 5


@pytest.mark.parametrize("kind", ["natural", "appearance"])
def test_normal_pixels_equals_the_stacked_operator_in_every_order(problem, kind):
    rng = np.random.default_rng(1)
    cube = rng.normal(size=problem.shape)
    epsilon = rng.uniform(0, 0.3, size=problem.shape[:2] + (1, 1))
    order = problem.pixel_order(kind)
    pixels = order.to_pixels(cube)
    result = order.to_cube(problem.normal_pixels(pixels, order=order, epsilon=epsilon))
    expected = problem.apply_adjoint(problem.apply(cube)) + epsilon * cube
    np.testing.assert_allclose(result, expected, rtol=1e-9, atol=1e-9)
    assert np.array_equal(order.to_cube(order.to_pixels(cube)), cube)


def test_block_jacobi_inverts_the_per_pixel_blocks_in_appearance_order(problem):
    order = problem.pixel_order("appearance")
    preconditioner = BlockJacobiPreconditioner(problem, np.float64, ridge=1e-3, order=order)
    n_wavelength = problem.shape[0]
    # apply the block diagonal of A^T A + epsilon to a cube, then its inverse: identity
    rng = np.random.default_rng(2)
    cube = rng.normal(size=problem.shape)
    w = problem.weights
    diagonal = w.alpha * problem.filters.normal_diagonal().reshape(n_wavelength, -1)
    diagonal += w.gamma * problem.neighbours.degree[None, :] + preconditioner.ridge
    flat = cube.reshape(n_wavelength, -1)
    c = problem.camera_matrix
    blocks = diagonal * flat + w.beta * c.T @ (c @ flat)
    recovered = preconditioner(blocks.reshape(problem.shape))
    np.testing.assert_allclose(recovered, cube, rtol=1e-8, atol=1e-8)


def test_an_iteration_counter_gets_no_cube_and_a_curve_gets_the_band_major_cube(problem):
    counted, shapes = [], []
    block_jacobi_pcg(
        problem, max_iterations=5, tolerance=1e-12, callback=counting_iterations(counted.append)
    )
    block_jacobi_pcg(
        problem, max_iterations=5, tolerance=1e-12, callback=lambda i, cube: shapes.append(cube.shape)
    )
    assert counted == [1, 2, 3, 4, 5]
    assert shapes == [problem.shape] * 5


def test_the_default_solver_holds_a_handful_of_cube_vectors(scene_factory):
    """Memory of a tile is bounded by what PCG needs (x, r, z, p, A p, M^-1) plus small
    tables: the preconditioner is built pixel-major in float32 without a dense float64
    diagonal, and the iteration reuses its buffers (it held about 13 vectors before)."""
    import tracemalloc

    scene = scene_factory(
        size=64,
        n_wavelength=32,
        n_images=4,
        shading=True,
        noise=0.05,
        shots={0: list(range(0, 32, 2)), 1: list(range(1, 32, 2))},
    )
    problem = build_problem(
        inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix), dtype=np.float32
    )
    vector = np.prod(problem.shape) * 4  # one float32 cube
    block_jacobi_pcg(problem, max_iterations=2)  # compiled kernels loaded, order cached
    tracemalloc.start()
    try:
        held = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        result = block_jacobi_pcg(
            problem, max_iterations=30, tolerance=1e-9, callback=counting_iterations(lambda i: None)
        )
        peak = tracemalloc.get_traced_memory()[1] - held
    finally:
        tracemalloc.stop()
    assert result.iterations == 30
    assert peak / vector < 9.0, f"peak {peak / vector:.1f} cube vectors"


def test_projected_step_and_its_dots_equal_numpy():
    from spectralize.nodes.reconstruction.kernels import projected_step, step_dots

    rng = np.random.default_rng(3)
    x, g, new_g = (rng.normal(size=(500, 7)).astype(np.float32) for _ in range(3))
    scale = rng.uniform(0.5, 2.0, size=(500, 7)).astype(np.float32)
    new = np.empty_like(x)
    projected_step(x, g, scale, 0.7, new)
    np.testing.assert_allclose(new, np.maximum(x - 0.7 * scale * g, 0), rtol=1e-6, atol=1e-7)
    assert new.min() == 0 and (new > 0).any()
    s, y = new.astype(np.float64) - x, new_g.astype(np.float64) - g
    sy, ss = step_dots(new, x, new_g, g, scale)
    np.testing.assert_allclose([sy, ss], [np.sum(s * y), np.sum(s * s / scale)], rtol=1e-6)


def test_prior_normal_pass_equals_its_terms_one_by_one_and_returns_the_curvature(problem):
    # the fused pass of prior_pcg: A^T A + ridge + w_p Q + f_p M_m, minus a vector
    order = problem.pixel_order("appearance")
    rng = np.random.default_rng(3)
    n_wavelength, n_image = problem.shape[:2]
    pixels = order.to_pixels(rng.normal(size=problem.shape))
    epsilon = rng.uniform(0, 0.3, size=(n_wavelength, n_image, 1, 1))
    root = rng.normal(size=(n_wavelength, n_wavelength))
    precision = root @ root.T
    weight = rng.uniform(0.5, 2.0, size=pixels.shape[0])
    brightness = rng.uniform(0.1, 3.0, size=pixels.shape[0])
    shots = rng.uniform(0, 1, size=(n_image, n_wavelength))
    subtract = rng.normal(size=pixels.shape)
    expected = problem.normal_pixels(pixels, order=order, epsilon=epsilon)
    expected += weight[:, None] * (pixels @ precision)
    expected += brightness[:, None] * shots[order.image] * pixels
    terms = {"precision": precision, "weight": weight, "brightness": brightness, "shots": shots}
    out = np.empty_like(pixels)
    curvature = problem.prior_normal_pixels(pixels, order=order, epsilon=epsilon, out=out, **terms)
    np.testing.assert_allclose(out, expected, rtol=1e-9, atol=1e-9)
    assert curvature == pytest.approx(float(np.sum(pixels * expected)), rel=1e-9)
    problem.prior_normal_pixels(
        pixels, order=order, epsilon=epsilon, out=out, subtract=subtract, **terms
    )
    np.testing.assert_allclose(out, expected - subtract, rtol=1e-9, atol=1e-9)


def test_fused_cg_step_equals_the_step_then_the_preconditioner(problem):
    from spectralize.nodes.reconstruction.kernels import cg_step

    order = problem.pixel_order("appearance")
    preconditioner = BlockJacobiPreconditioner(problem, np.float64, ridge=1e-3, order=order)
    rng = np.random.default_rng(4)
    x, r, p, q = (order.to_pixels(rng.normal(size=problem.shape)) for _ in range(4))
    x_ref, r_ref = x.copy(), r.copy()
    rr_ref = cg_step(x_ref, r_ref, p, q.copy(), 0.3)
    z_ref = preconditioner.apply_pixels(r_ref)
    rr, rz = preconditioner.step_pixels(x, r, p, q, 0.3)
    np.testing.assert_allclose(x, x_ref, rtol=1e-12)
    np.testing.assert_allclose(r, r_ref, rtol=1e-12)
    np.testing.assert_allclose(q, z_ref, rtol=1e-10, atol=1e-12)
    assert rr == pytest.approx(rr_ref, rel=1e-10)
    assert rz == pytest.approx(float(np.sum(r_ref * z_ref)), rel=1e-10)


@pytest.mark.parametrize("per_image", [False, True])
def test_one_pass_projection_equals_alternating_passes(per_image):
    from spectralize.nodes.reconstruction.baselines.projection import project_onto_rgb
    from spectralize.nodes.reconstruction.kernels import project_rgb_nonnegative

    rng = np.random.default_rng(5)
    n_wavelength, n_image, n_pixels = 7, 3, 50
    cube = rng.normal(size=(n_wavelength, n_image, n_pixels))
    rgb = rng.uniform(0, 1, size=(n_image, n_pixels, 3))
    c = rng.uniform(0, 1, size=(n_image, 3, n_wavelength) if per_image else (3, n_wavelength))
    expected = cube.copy()
    for _ in range(4):
        project_onto_rgb(expected, c, np.moveaxis(rgb, -1, 0), overwrite=True)
        np.maximum(expected, 0, out=expected)
    cameras = c if per_image else c[None]
    transposed = np.transpose(cameras, (0, 2, 1))
    pseudo = np.ascontiguousarray(transposed @ np.linalg.inv(cameras @ transposed))
    index = np.arange(n_image) if per_image else np.zeros(n_image, dtype=np.intp)
    project_rgb_nonnegative(cube, np.ascontiguousarray(cameras), pseudo, index, rgb, 4)
    np.testing.assert_allclose(cube, expected, rtol=1e-12, atol=1e-12)


def test_a_pixel_order_keeps_its_laplacian_not_a_permuted_copy_of_the_graph(problem):
    """The appearance order's Laplacian is the permuted graph's, bit for bit, built once per
    dtype; the order holds the problem's own graph, not a permuted copy of its neighbour
    lists (they would stay beside the problem's for the whole solve)."""
    from spectralize.nodes.reconstruction.neighbourhoods import NeighbourGraph

    order = problem.pixel_order("appearance")
    expected = problem.neighbours.permuted(order.order).laplacian
    built = order.laplacian(problem.dtype)
    for name in ("indptr", "indices", "data"):
        assert np.array_equal(getattr(built, name), getattr(expected, name)), name
    assert order.laplacian(problem.dtype) is built  # once per dtype
    graphs = [value for value in vars(order).values() if isinstance(value, NeighbourGraph)]
    assert graphs == [problem.neighbours]


@pytest.mark.parametrize("method", ["natural-prior-pcg", "block-jacobi-pcg"])
def test_a_solve_leaves_no_pixel_orders_in_its_problem(scene_factory, method):
    """The solve's pixel orders (index arrays, Laplacian) are not kept in the problem after
    it (the set model and the confidence run next); a second solve builds them again and
    gives the same bits."""
    from spectralize.nodes.reconstruction import reconstruct

    scene = scene_factory(size=16, n_wavelength=5, n_images=2, noise=0.05, shots={0: [0, 1, 2, 3, 4]})
    first = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method=method, full_output=True)
    assert first.problem is not None and not first.problem.extras.get("pixel_orders")
    again = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method=method)
    assert np.array_equal(again.values, first.spectra.values)
