"""Solvers: exact recovery, agreement of the fast solver with the paper's CG, propagation."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import (
    RECONSTRUCTION_METHODS,
    build_problem,
    inputs_from_xarray,
    reconstruct,
)
from spectralize.nodes.reconstruction.baselines import guided_filtered_projected
from spectralize.nodes.reconstruction.solvers import (
    BlockJacobiPreconditioner,
    block_jacobi_pcg,
    paper_cg,
)
from spectralize.schemas.errors import ParameterError

GUIDED = RECONSTRUCTION_METHODS["guided-prior-pcg"].settings
"""The guided-prior preset: eq. 1's PCG with its prior."""


def _problem(scene, **options):
    return build_problem(inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix), **options)


def _relative_error(estimate, truth) -> float:
    return float(np.linalg.norm(estimate - truth) / np.linalg.norm(truth))


@pytest.mark.parametrize("method", ["paper-cg", "block-jacobi-pcg"])
def test_exact_recovery_of_a_noise_free_scene(scene_factory, method):
    """Flat materials with distinct RGB, exact bands: the truth has zero energy and the
    constraints determine it, so both solvers must find it."""
    scene = scene_factory(size=24, n_wavelength=8, n_materials=3, noise=0.0, filter_size=3.0)
    problem = _problem(scene)
    truth = np.moveaxis(scene.truth, 1, 0)  # (wavelength, image, y, x)
    assert problem.energy(truth) == pytest.approx(0.0, abs=1e-20)
    options = {"dtype": np.float64, "ridge": 0.0, "prior": 0.0} if method == "block-jacobi-pcg" else {}
    result = RECONSTRUCTION_METHODS[method].function(
        problem, tolerance=1e-10, max_iterations=3000, **options
    )
    assert result.converged
    assert _relative_error(result.cube, truth) < 1e-6


def test_fast_solver_agrees_with_paper_cg(scene_factory):
    scene = scene_factory(
        size=24, n_wavelength=6, n_materials=3, shading=True, noise=0.05, rgb_noise=1e-3, filter_size=3.0
    )
    problem = _problem(scene)
    reference = paper_cg(problem, tolerance=1e-9, max_iterations=5000)
    assert reference.converged
    exact = block_jacobi_pcg(
        problem, tolerance=1e-9, max_iterations=5000, dtype=np.float64, ridge=0.0, prior=0.0
    )
    assert exact.converged
    assert _relative_error(exact.cube, reference.cube) < 1e-6
    # eq. 1 alone (prior=0): float32, ridge, default tolerance, far fewer iterations, same
    # energy
    fast = block_jacobi_pcg(problem, prior=0.0)
    assert fast.converged and fast.cube.dtype == np.float32
    assert _relative_error(fast.cube, reference.cube) < 2e-2
    assert fast.iterations < reference.iterations / 3
    assert problem.energy(fast.cube.astype(np.float64)) == pytest.approx(
        problem.energy(reference.cube), rel=2e-3
    )


def test_the_one_pcg_loop_solves_with_and_without_the_preconditioner(scene_factory):
    """Both PCG solvers run one loop; without the preconditioner (a measurement mode) it
    reaches the same solution, in more iterations; a precondition that is not a bool is
    refused (the scalar "jacobi" mode is gone)."""
    scene = scene_factory(size=20, n_wavelength=5, shading=True, noise=0.02, rgb_noise=1e-3)
    problem = _problem(scene)
    options = {"tolerance": 1e-9, "max_iterations": 5000, "dtype": np.float64, "ridge": 0.0}
    preconditioned = block_jacobi_pcg(problem, **options)
    plain = block_jacobi_pcg(problem, precondition=False, **options)
    assert preconditioned.converged and plain.converged
    assert preconditioned.iterations < plain.iterations
    assert _relative_error(plain.cube, preconditioned.cube) < 1e-6
    assert plain.info["precondition"] is False
    with pytest.raises(ParameterError, match="precondition: expected True"):
        block_jacobi_pcg(problem, precondition="jacobi")


def test_residual_history_and_stopping(scene_factory):
    scene = scene_factory(size=20, n_wavelength=5, shading=True, noise=0.02)
    problem = _problem(scene)
    result = paper_cg(problem, tolerance=1e-4, max_iterations=500)
    history = result.residual_history
    assert len(history) == result.iterations + 1
    assert history[0] == pytest.approx(1.0)  # from zero: the residual is A^T b itself
    assert history[-1] <= 1e-4 < history[-2]
    limited = paper_cg(problem, tolerance=1e-12, max_iterations=7)
    assert limited.iterations == 7 and not limited.converged


def test_block_jacobi_preconditioner_inverts_the_pixel_blocks(scene_factory):
    scene = scene_factory(size=16, n_wavelength=5, shading=True, filter_size=3.0)
    problem = _problem(scene)
    preconditioner = BlockJacobiPreconditioner(problem, dtype=np.float64)
    n_wavelength, _, height, width = problem.shape
    rng = np.random.default_rng(0)
    w = problem.weights
    diagonal = (
        w.alpha * problem.filters.normal_diagonal().reshape(n_wavelength, -1)
        + w.gamma * problem.neighbours.degree[None, :]
    )
    c = problem.camera_matrix
    for pixel in [0, 37, height * width - 1]:
        block = np.diag(diagonal[:, pixel]) + w.beta * c.T @ c
        # the block is the diagonal block of A^T A at this pixel
        unit = np.zeros(problem.shape)
        unit.reshape(n_wavelength, -1)[2, pixel] = 1.0
        column = problem.normal(unit).reshape(n_wavelength, -1)[:, pixel]
        np.testing.assert_allclose(column, block[:, 2], rtol=1e-6, atol=1e-9)
        r = np.zeros(problem.shape)
        values = rng.normal(size=n_wavelength)
        r.reshape(n_wavelength, -1)[:, pixel] = values
        applied = preconditioner(r).reshape(n_wavelength, -1)[:, pixel]
        np.testing.assert_allclose(
            applied, np.linalg.solve(block, values), rtol=1e-5, atol=1e-9 * np.abs(applied).max()
        )


def test_an_image_without_bands_gets_spectra_through_its_neighbours(scene_factory):
    """Paper sec. 5, sparsely measured: image 1 has no band shot but shows the same
    materials (mirrored layout); its spectra come from image 0 through the appearance
    neighbourhoods. The paper's CG starts from zero, so nothing but eq. 1 brings them."""
    scene = scene_factory(
        size=24,
        n_wavelength=8,
        n_images=2,
        n_materials=3,
        noise=0.0,
        rgb_noise=1e-4,
        filter_size=3.0,
        mirror_odd=True,
        shots={0: list(range(8))},
    )
    truth = scene.truth
    spectra = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="paper-cg", tolerance=1e-6
    ).values
    error_without_bands = _relative_error(spectra[1], truth[1])
    assert error_without_bands < 1e-3
    # without the neighbour term the same solver leaves image 1 at the minimum-norm spectra
    lone = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="paper-cg", gamma_hat=1e-9, tolerance=1e-6
    ).values
    assert _relative_error(lone[1], truth[1]) > 0.1
    # the fast default agrees
    fast = reconstruct(scene.rgb, scene.bands, scene.camera_matrix).values
    assert _relative_error(fast[1], truth[1]) < 1e-2


def test_warm_start_from_the_answer_stops_at_once(scene_factory):
    scene = scene_factory(size=20, n_wavelength=5, shading=True, noise=0.02)
    # eq. 1 alone (block-jacobi-pcg) from an explicit initial guess
    start = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method="filtered-projected")
    first = reconstruct(
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        method="block-jacobi-pcg",
        tolerance=1e-5,
        initial=start,
        full_output=True,
    )
    again = reconstruct(
        scene.rgb,
        scene.bands,
        scene.camera_matrix,
        method="block-jacobi-pcg",
        tolerance=1e-3,
        initial=first.spectra,
        full_output=True,
    )
    assert again.iterations <= 1
    np.testing.assert_allclose(
        again.spectra.values,
        first.spectra.values,
        rtol=1e-3,
        atol=1e-4 * float(np.abs(first.spectra).max()),
    )


def test_default_prior_pulls_towards_the_guided_estimate_and_helps(scene_factory):
    """The default solves eq. 1 plus ``epsilon ||S - S_0||^2`` towards the guided-filter
    estimate ``S_0``: its solution lies between eq. 1's and ``S_0``, it is the exact
    minimiser of that energy, and on shaded materials (spectra linear in RGB per material)
    with noisy bands it is more accurate than eq. 1 alone."""
    scene = scene_factory(
        size=32, n_wavelength=8, n_materials=3, shading=True, noise=0.1, rgb_noise=1e-3, filter_size=4.0
    )
    problem = _problem(scene)
    truth = np.moveaxis(scene.truth, 1, 0)
    guided = guided_filtered_projected(problem.extras["inputs"])
    plain = block_jacobi_pcg(problem, prior=0.0, tolerance=1e-8, max_iterations=3000, dtype=np.float64)
    with_prior = block_jacobi_pcg(
        problem, prior=GUIDED["prior"], tolerance=1e-8, max_iterations=3000, dtype=np.float64
    )
    assert with_prior.info["prior"] == GUIDED["prior"] > 0
    assert problem.energy(plain.cube) <= problem.energy(with_prior.cube)
    # stationary point of E(S) + epsilon ||S - S_0||^2 (every band has a shot here)
    epsilon = BlockJacobiPreconditioner(
        problem, np.float64, ridge=GUIDED["ridge"] + GUIDED["prior"]
    ).ridge
    gradient = (
        problem.normal(with_prior.cube) - problem.normal_rhs() + epsilon * (with_prior.cube - guided)
    )
    assert np.linalg.norm(gradient) < 1e-6 * np.linalg.norm(problem.normal_rhs())
    assert _relative_error(with_prior.cube, guided) < _relative_error(plain.cube, guided)
    assert _relative_error(with_prior.cube, truth) < 0.9 * _relative_error(plain.cube, truth)


def test_prior_centre_stays_the_guided_estimate_under_a_warm_start(scene_factory):
    """A warm start (the BTF flow's sets) changes where CG starts, not what it solves."""
    scene = scene_factory(
        size=24, n_wavelength=6, n_materials=3, shading=True, noise=0.1, filter_size=4.0
    )
    problem = _problem(scene)
    options = {"tolerance": 1e-9, "max_iterations": 4000, "dtype": np.float64, "ridge": 0.0}
    cold = block_jacobi_pcg(problem, prior=GUIDED["prior"], **options)
    warm = block_jacobi_pcg(problem, prior=GUIDED["prior"], initial=np.zeros(problem.shape), **options)
    assert warm.method == cold.method == "block_jacobi_pcg"
    np.testing.assert_allclose(
        warm.cube, cold.cube, rtol=1e-5, atol=1e-6 * float(np.abs(cold.cube).max())
    )
    plain = block_jacobi_pcg(problem, prior=0.0, initial=np.zeros(problem.shape), **options)
    assert _relative_error(plain.cube, cold.cube) > 1e-3  # the prior did change the answer


def test_the_prior_is_reachable_from_reconstruct_and_changes_the_result(scene_factory):
    """``prior`` is the guided prior's weight: 0 is eq. 1 alone (``block-jacobi-pcg``'s
    default), 0.1 the ``guided-prior-pcg`` default; a larger weight pulls the result
    further towards the guided estimate."""
    scene = scene_factory(
        size=24, n_wavelength=6, n_materials=3, shading=True, noise=0.1, filter_size=4.0
    )
    options = {"tolerance": 1e-7, "max_iterations": 3000}
    guided = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method="guided-projected").values
    default = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="guided-prior-pcg", **options
    )
    assert default.attrs["prior"] == 0.1
    strong = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="guided-prior-pcg", prior=1.0, **options
    )
    assert strong.attrs["prior"] == 1.0
    none = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="guided-prior-pcg", prior=0.0, **options
    )
    plain = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="block-jacobi-pcg", **options
    )
    assert _relative_error(strong.values, default.values) > 1e-3
    assert (
        _relative_error(strong.values, guided)
        < _relative_error(default.values, guided)
        < _relative_error(none.values, guided)
    )
    # prior=0 is eq. 1 alone, whatever the start
    assert _relative_error(none.values, plain.values) < 1e-3
    with_prior = reconstruct(
        scene.rgb, scene.bands, scene.camera_matrix, method="block-jacobi-pcg", prior=0.1, **options
    )
    np.testing.assert_allclose(
        with_prior.values, default.values, rtol=1e-5, atol=1e-5 * float(np.abs(default).max())
    )
