"""The non-negativity refinement: its compiled steps are the numpy algorithm's, and it
solves the bound-constrained problem."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

from spectralize.nodes.reconstruction.solvers import projected_refinement
from spectralize.nodes.reconstruction.solvers.projected_refinement import MAX_STEP, MIN_STEP


def _problem(seed: int, n_pixels: int = 300, n_wavelength: int = 6, dtype=np.float64):
    """A pixel-major SPD operator ``H = B^T B`` (one block per pixel), ``rhs`` whose
    unconstrained minimiser has negative values, and the Jacobi scaling ``1 / diag H``."""
    rng = np.random.default_rng(seed)
    blocks = rng.normal(size=(n_pixels, n_wavelength + 2, n_wavelength))
    hessian = np.einsum("pkw,pkv->pwv", blocks, blocks)
    target = rng.normal(size=(n_pixels, n_wavelength + 2))
    rhs = np.einsum("pkw,pk->pw", blocks, target)

    def operator(x: np.ndarray, out: np.ndarray) -> np.ndarray:
        out[...] = np.einsum("pwv,pv->pw", hessian, x)
        return out

    scale = 1.0 / np.einsum("pww->pw", hessian)
    return operator, rhs.astype(dtype), scale.astype(dtype), blocks, target


def _numpy_refinement(operator, rhs, scale, x, iterations):
    """The same projected gradient written with numpy temporaries (the reference)."""
    x = np.maximum(x, 0)
    g = operator(x, np.empty_like(x)) - rhs
    step = 1.0
    for _ in range(iterations):
        new = np.maximum(x - x.dtype.type(step) * scale * g, 0)
        new_g = operator(new, np.empty_like(x)) - rhs
        s, y = (new - x).ravel().astype(np.float64), (new_g - g).ravel().astype(np.float64)
        sy = float(s @ y)
        step = float(s @ (s / scale.ravel())) / sy if sy > 0 else step
        step = min(max(step, MIN_STEP), MAX_STEP)
        x, g = new, new_g
    return x


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_compiled_refinement_is_the_numpy_algorithm(dtype):
    operator, rhs, scale, _, _ = _problem(0, dtype=dtype)
    start = np.random.default_rng(1).normal(size=rhs.shape).astype(dtype)
    reference = _numpy_refinement(operator, rhs, scale, start.copy(), 15)
    compiled = projected_refinement(operator, rhs, scale, start.copy(), 15)
    tolerance = 1e-10 if dtype == np.float64 else 2e-4
    np.testing.assert_allclose(
        compiled, reference, rtol=tolerance, atol=tolerance * np.abs(reference).max()
    )


def test_refinement_solves_the_bound_constrained_problem():
    """Per pixel ``min ||B x - t||^2 s.t. x >= 0`` is the refinement's problem: many steps
    reach scipy's NNLS."""
    operator, rhs, scale, blocks, target = _problem(2, n_pixels=40)
    x = projected_refinement(operator, rhs, scale, np.zeros_like(rhs), 3000)
    assert x.min() >= 0
    expected = np.stack([nnls(b, t)[0] for b, t in zip(blocks, target, strict=True)])
    np.testing.assert_allclose(x, expected, atol=1e-5 * np.abs(expected).max())
