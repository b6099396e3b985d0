"""Eq. 4: alpha = a M / K, beta = b M / 3P, gamma = g M / sum |N_p|, M = K + 3P + sum |N_p|."""

from __future__ import annotations

import pytest

from spectralize.nodes.reconstruction import build_problem, inputs_from_xarray, term_weights
from spectralize.nodes.reconstruction.weights import default_gamma_hat


def test_eq4_values():
    w = term_weights(1000, 400, 1200, alpha_hat=2.0, beta_hat=0.5, gamma_hat=20.0)
    m = 1000 + 3 * 400 + 1200
    assert w.n_equations == m
    assert w.alpha == pytest.approx(2.0 * m / 1000)
    assert w.beta == pytest.approx(0.5 * m / 1200)
    assert w.gamma == pytest.approx(20.0 * m / 1200)


def test_equal_hats_weight_every_term_equally():
    w = term_weights(500, 100, 300)
    # alpha K = beta 3P = gamma sum|N_p| = M
    assert w.alpha * 500 == pytest.approx(w.beta * 300)
    assert w.beta * 300 == pytest.approx(w.gamma * 300)
    assert w.alpha * 500 == pytest.approx(w.n_equations)


def test_terms_without_equations_get_zero_weight_and_bad_values_fail():
    assert term_weights(0, 10, 30).alpha == 0.0
    with pytest.raises(ValueError, match="gamma_hat"):
        term_weights(10, 10, 30, gamma_hat=-1.0)
    with pytest.raises(ValueError, match="at least one equation"):
        term_weights(0, 0, 0)


def test_paper_gamma_hat_defaults():
    assert default_gamma_hat(1) == 1.0
    assert default_gamma_hat(20) == 20.0


def test_problem_weights_follow_eq4_counts(scene_factory):
    scene = scene_factory(
        size=16, n_wavelength=4, n_images=2, filter_size=3.0, shots={0: [0, 1], 1: [2, 3]}
    )
    problem = build_problem(
        inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix), k=3, beta_hat=2.0
    )
    w = problem.weights
    p = 2 * 16 * 16
    # 16 px, s = 3: centres 3..12, every <= 2.5 px -> 5 per axis; 4 shots
    assert w.n_filters == 4 * 5 * 5 == problem.filters.count
    assert w.n_pixels == p
    assert w.n_neighbour_pairs == 3 * p
    m = w.n_filters + 3 * p + 3 * p
    assert w.alpha == pytest.approx(m / w.n_filters)
    assert w.beta == pytest.approx(2.0 * m / (3 * p))
    assert w.gamma == pytest.approx(20.0 * m / (3 * p))  # a set: gamma_hat = 20
