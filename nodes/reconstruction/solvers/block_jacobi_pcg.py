"""Solver ``"block-jacobi-pcg"``: eq. 1 alone, solved fast (the default).

Conjugate gradients on ``A^T A`` applied directly (one pass of each term instead of ``A``
then ``A^T``), preconditioned by the exact inverse of the per-pixel
``n_wavelength x n_wavelength`` diagonal blocks of ``A^T A`` (block Jacobi, applied in
closed form with a 3 x 3 Woodbury solve per pixel), float32, started from the filtered
bands projected onto the RGB constraint, with a tiny ridge towards that start that only
acts on directions eq. 1 leaves undetermined. Reaches the paper-CG's solution.

The same iteration with ``prior > 0`` adds a Tikhonov prior towards the RGB-guided filtered
bands; :mod:`.guided_prior_pcg` is that method.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization", and section 6
   (convergence speed with large filters as the main limitation).
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM
   (preconditioned CG, algorithm 9.1).
"""

from __future__ import annotations

import time
from functools import cached_property

import numpy as np

from ..baselines import filtered_bands_projected, guided_filtered_projected
from ..operators import PixelOrder, ReconstructionProblem
from .common import (
    COMPILED,
    DEFAULT_MAX_ITERATIONS,
    DEFAULT_TOLERANCE,
    Callback,
    SolverResult,
    needs_cube,
    preconditioned_cg,
)

__all__ = [
    "block_jacobi_pcg",
    "BlockJacobiPreconditioner",
    "normal_mean_diagonal",
    "projected_filtered_initial",
    "guided_initial",
    "DEFAULT_RIDGE",
]

DEFAULT_RIDGE = 1e-4
"""Ridge towards the starting cube, relative to the mean diagonal of ``A^T A``."""

_CHUNK = 1 << 16
"""Pixels per chunk of the preconditioner's 3 x 3 inverses (bounds their float64 temporaries)."""


def normal_mean_diagonal(problem: ReconstructionProblem) -> float:
    """The mean of the diagonal of ``A^T A`` (the unit of relative ridges and priors), from
    sums of its terms: ``alpha F^T F`` (separable filters), ``gamma L`` (the degrees) and
    ``beta C^T C``."""
    w = problem.weights
    n_wavelength = problem.shape[0]
    degree = problem.neighbours.degree
    c = problem.camera_matrix.astype(np.float64)
    total = w.alpha * problem.filters.normal_diagonal_total()
    total += w.gamma * n_wavelength * float(degree.sum(dtype=np.float64))
    return total / (n_wavelength * degree.size) + w.beta * float(np.sum(c * c)) / n_wavelength


class BlockJacobiPreconditioner:
    """Exact inverse of the per-pixel diagonal blocks of ``A^T A + epsilon I``.

    The block of pixel ``p`` is ``diag(a_p) + beta C^T C`` with
    ``a_p(b) = alpha (F^T F)_{pp,b} + gamma L_pp + epsilon`` (filter and neighbour terms are
    diagonal in the wavelength). Its inverse follows from the Woodbury identity with one
    3 x 3 solve per pixel: ``M^-1 r = u - a^-1 C^T (I / beta + C a^-1 C^T)^-1 C u`` with
    ``u = r / a``. :meth:`jacobi` applies the plain scalar diagonal instead.

    Parameters
    ----------
    problem
        The problem whose normal operator is preconditioned.
    dtype
        Floating dtype of the application.
    ridge
        ``epsilon`` relative to the mean diagonal of ``A^T A``: a number, or an array that
        broadcasts to the cube's shape (per band and image, or per pixel); the absolute
        value is :attr:`ridge` after construction (``None`` for a per-pixel ridge, which is
        not kept: a cube).
    order
        Pixel-major storage order of the residuals :meth:`apply_pixels` takes (default: the
        problem's ``"natural"`` order).
    """

    def __init__(
        self,
        problem: ReconstructionProblem,
        dtype: np.dtype | type = np.float32,
        ridge: float = 0.0,
        order: PixelOrder | None = None,
    ):
        # Built pixel-major in ``dtype`` and in chunks: about 1.2 vectors of the cube beside
        # what it keeps (a dense float64 diagonal cube and its permuted copies were 7).
        w = problem.weights
        n_wavelength, n_image = problem.shape[:2]
        self.dtype = np.dtype(dtype)
        self.order = problem.pixel_order("natural") if order is None else order
        self.shape = problem.shape
        c = problem.camera_matrix.astype(np.float64)
        degree = problem.neighbours.degree
        n_pixels = degree.size
        mean_diagonal = normal_mean_diagonal(problem)
        #: mean of the diagonal of ``A^T A``, the unit of relative ridges
        self.mean_diagonal = mean_diagonal
        # the ridge, or a far tinier one, keeps blocks without filter and neighbours invertible
        floor = max(1e-9 * mean_diagonal, 1e-300)
        ridge_shape = np.shape(ridge)
        if not ridge_shape or ridge_shape[-2:] == (1, 1):  # per band and image
            #: ``epsilon`` of a ridge ``epsilon I`` added to ``A^T A`` (absolute); None for a
            #: per-pixel ridge (a cube, not kept)
            self.ridge = np.asarray(ridge, dtype=np.float64) * mean_diagonal
            table = np.broadcast_to(self.ridge, (n_wavelength, n_image, 1, 1))[:, :, 0, 0]
            diagonal = np.maximum(table, floor).T.astype(self.dtype)[self.order.image]
        else:  # per pixel, in the working dtype (no float64 cube)
            self.ridge = None
            per_pixel = np.broadcast_to(np.asarray(ridge, dtype=self.dtype), problem.shape)
            diagonal = self.order.to_pixels(per_pixel)  # a new pixel-major array
            diagonal *= self.dtype.type(mean_diagonal)
            np.maximum(diagonal, self.dtype.type(floor), out=diagonal)
        # a_p(b) = alpha (F^T F)_pp,b + gamma L_pp + epsilon, pixel-major in ``order``
        diagonal += (w.gamma * degree[self.order.order]).astype(self.dtype)[:, None]
        problem.filters.add_normal_diagonal(diagonal, w.alpha, self.order.positions)
        self.inverse_diagonal = np.divide(1.0, diagonal, out=diagonal)
        # (I / beta + C a^-1 C^T)^-1 per pixel, (n_pixels, 3, 3), in float64 chunks
        self.small_inverse = np.empty((n_pixels, 3, 3), dtype=self.dtype)
        identity = np.eye(3) / max(w.beta, 1e-300)
        for start in range(0, n_pixels, _CHUNK):
            inverse = self.inverse_diagonal[start : start + _CHUNK].astype(np.float64)
            small = np.einsum("cw,pw,dw->pcd", c, inverse, c, optimize=True) + identity
            self.small_inverse[start : start + _CHUNK] = np.linalg.inv(small)
        self.camera_matrix = np.ascontiguousarray(c.astype(self.dtype))
        self._beta = w.beta

    def inverse_scalar_diagonal_pixels(self) -> np.ndarray:
        """``1 / diag(A^T A + epsilon)``, pixel-major ``(n_pixels, n_wavelength)`` in
        :attr:`order` (plain Jacobi scaling of the compiled solvers)."""
        c = self.camera_matrix.astype(np.float64)
        full = np.divide(1.0, self.inverse_diagonal, dtype=self.dtype)  # one buffer, in place
        full += (self._beta * np.sum(c * c, axis=0)).astype(self.dtype)[None, :]
        return np.divide(1.0, full, out=full)

    @cached_property
    def inverse_scalar_diagonal(self) -> np.ndarray:
        """``1 / diag(A^T A + epsilon)``, ``(n_wavelength, n_pixels)`` in (image, y, x) order,
        for plain Jacobi preconditioning (computed when first asked for)."""
        pixels = self.inverse_scalar_diagonal_pixels()
        return self.order.to_cube(pixels).reshape(self.shape[0], -1)

    def jacobi(self, residual: np.ndarray) -> np.ndarray:
        """Plain (scalar) Jacobi: ``r / diag(A^T A)``."""
        n_wavelength = self.shape[0]
        return (residual.reshape(n_wavelength, -1) * self.inverse_scalar_diagonal).reshape(self.shape)

    def ridge_of(self, relative: float) -> float:
        """Absolute ``epsilon`` of a ridge given relative to the mean diagonal of ``A^T A``."""
        return float(relative) * self.mean_diagonal

    def apply_pixels(self, residual: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``M^-1 r`` on a pixel-major residual ``(n_pixels, n_wavelength)`` in :attr:`order`,
        one compiled pass (:func:`~..kernels.block_jacobi_pixels`)."""
        from ..kernels import block_jacobi_pixels

        if out is None:
            out = np.empty_like(residual)
        block_jacobi_pixels(residual, self.inverse_diagonal, self.camera_matrix, self.small_inverse, out)
        return out

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        """``M^-1 r`` for a residual of the problem's :attr:`shape`."""
        pixels = self.order.to_pixels(np.asarray(residual, dtype=self.dtype).reshape(self.shape))
        return self.order.to_cube(self.apply_pixels(pixels))


def projected_filtered_initial(problem: ReconstructionProblem) -> np.ndarray:
    """Initial guess: the filtered bands projected onto ``C S = R`` (baseline
    ``"filtered-projected"``); zeros for a problem built without its inputs."""
    inputs = problem.extras.get("inputs")
    if inputs is None:
        return np.zeros(problem.shape, dtype=problem.dtype)
    return filtered_bands_projected(inputs)


def guided_initial(problem: ReconstructionProblem) -> np.ndarray:
    """Initial guess and prior ``S_0``: the RGB-guided filtered bands projected onto
    ``C S = R`` (baseline ``"guided-projected"``); zeros for a problem built without its
    inputs."""
    inputs = problem.extras.get("inputs")
    if inputs is None:
        return np.zeros(problem.shape, dtype=problem.dtype)
    return guided_filtered_projected(inputs)


def _prior_mask(problem: ReconstructionProblem) -> np.ndarray:
    """``(n_wavelength, n_image, 1, 1)``: 1 where the band and image have a shot, else 0."""
    mask = np.zeros(problem.shape[:2] + (1, 1))
    mask[problem.filters.band, problem.filters.image] = 1.0
    return mask


def block_jacobi_pcg(
    problem: ReconstructionProblem,
    *,
    initial: np.ndarray | None = None,
    tolerance: float = DEFAULT_TOLERANCE,
    max_iterations: int = DEFAULT_MAX_ITERATIONS,
    callback: Callback | None = None,
    dtype: np.dtype | type = np.float32,
    ridge: float = DEFAULT_RIDGE,
    prior: float = 0.0,
    precondition: bool | str = True,
) -> SolverResult:
    """Block-Jacobi preconditioned CG on the normal equations, float32, warm-started.

    Minimises eq. 1 plus ``epsilon_r ||S - S_start||^2 + epsilon_p M ||S - S_0||^2``:
    ``epsilon_r = ridge * mean(diag A^T A)`` towards the starting cube, ``epsilon_p = prior *
    mean(diag A^T A)`` towards the guided estimate ``S_0`` (:func:`guided_initial`) on the
    bands and images ``M`` that have a shot.

    The tiny ``ridge`` leaves every direction that eq. 1 determines unchanged (to about
    ``epsilon / lambda``) and keeps the spectra of directions it does not determine at all
    (e.g. a neighbourhood component of an image without bands that no filter sees) at the
    initial guess, instead of letting rounding errors of a float32 CG drift along them.
    ``prior`` is a real Tikhonov prior (0 here; method ``"guided-prior-pcg"``,
    :func:`~spectralize.nodes.reconstruction.solvers.guided_prior_pcg.guided_prior_pcg`, sets
    it and says why); ``ridge=0, prior=0`` solves eq. 1 exactly.

    Parameters
    ----------
    problem
        Eq. 1 set up by :func:`~spectralize.nodes.reconstruction.operators.build_problem`.
    initial
        Starting cube (a warm start); default :func:`guided_initial` when ``prior > 0``,
        else :func:`projected_filtered_initial`.
    tolerance
        Relative normal-equation residual to stop at.
    max_iterations
        Iteration limit.
    callback
        Called as ``callback(iteration, cube)`` after every iteration.
    dtype
        Working precision (float32 halves memory traffic; float64 for checks).
    ridge
        Ridge towards the start, relative to the mean diagonal of ``A^T A``.
    prior
        Weight of the prior towards :func:`guided_initial`, relative to the mean diagonal
        of ``A^T A``, on the bands and images that have a shot (0: eq. 1 alone).
    precondition
        ``True``: block Jacobi; ``"jacobi"``: the scalar diagonal; ``False``: none (the
        last two for measurements).

    Returns
    -------
    SolverResult
        ``method="block-jacobi-pcg"``; the cube is in ``dtype``; ``info`` records the
        absolute ridge, the prior and the preconditioner.

    References
    ----------
    .. [1] Saad (2003), algorithm 9.1; Fast Capture of Spectral Image Series, section 6
       (eq. 1).
    .. [2] He, Sun and Tang (2013), Guided Image Filtering (the prior's estimate).
    """
    started = time.perf_counter()
    dtype = np.dtype(dtype)
    work = problem.astype(dtype)
    relative_ridge: float | np.ndarray = ridge
    centre = None
    if prior > 0:
        centre = np.asarray(guided_initial(problem), dtype=dtype).reshape(work.shape)
        relative_ridge = ridge + prior * _prior_mask(problem)
    if initial is None:
        initial = centre if centre is not None else projected_filtered_initial(problem)
    # the iteration runs on pixel-major vectors stored in appearance order (:mod:`..kernels`)
    order = work.pixel_order("appearance")
    x = order.to_pixels(np.asarray(initial, dtype=dtype).reshape(work.shape))
    del initial  # the caller's start is the caller's; one computed here is not kept
    preconditioner = BlockJacobiPreconditioner(work, dtype, ridge=relative_ridge, order=order)
    epsilon = preconditioner.ridge.astype(dtype)
    regularised = bool(np.any(epsilon > 0))
    rhs = order.to_pixels(work.normal_rhs())
    if regularised:  # epsilon_r S_start + epsilon_p M S_0
        towards = dtype.type(preconditioner.ridge_of(ridge))
        rhs += towards * x
        if centre is not None:
            ridge_cube = np.broadcast_to(epsilon, work.shape) - towards
            rhs += order.to_pixels(ridge_cube * centre)
            del centre, ridge_cube
    ridge_argument = epsilon if regularised else 0.0
    rhs_norm = np.sqrt(COMPILED.dot(rhs, rhs)) or 1.0
    r = rhs - work.normal_pixels(x, order=order, epsilon=ridge_argument)
    del rhs
    if precondition == "jacobi":
        scalar = order.to_pixels(preconditioner.inverse_scalar_diagonal.reshape(work.shape))

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return residual * scalar

    elif precondition:
        z = np.empty_like(x)  # CG consumes M^-1 r before asking for the next one

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return preconditioner.apply_pixels(residual, out=z)

    else:

        def apply_preconditioner(residual: np.ndarray) -> np.ndarray:
            return residual.copy()

    q = np.empty_like(x)  # CG consumes A^T A p before asking for the next one

    def operator(direction: np.ndarray) -> np.ndarray:
        return work.normal_pixels(direction, order=order, epsilon=ridge_argument, out=q)

    def band_major_callback(iteration: int, cube: np.ndarray) -> None:
        callback(iteration, order.to_cube(cube) if cube_wanted else None)

    cube_wanted = needs_cube(callback)

    x, history, iterations = preconditioned_cg(
        operator,
        x,
        r,
        rhs_norm,
        apply_preconditioner,
        tolerance=tolerance,
        max_iterations=max_iterations,
        dtype=dtype,
        callback=None if callback is None else band_major_callback,
        vectors=COMPILED,
    )
    x = order.to_cube(x)
    return SolverResult(
        x,
        iterations,
        np.asarray(history),
        history[-1] <= tolerance,
        time.perf_counter() - started,
        "block-jacobi-pcg",
        {"ridge": float(np.min(epsilon)), "prior": float(prior), "precondition": precondition},
    )
