"""The block-Jacobi preconditioner of the normal equations of eq. 1.

The exact inverse of the per-pixel ``n_wavelength x n_wavelength`` diagonal blocks of
``A^T A`` plus a ridge (the priors' diagonals), applied in closed form with a 3 x 3 Woodbury
solve per pixel: the filter and neighbour terms are diagonal in the wavelength, the RGB
term is a rank-3 block. Both PCG solvers (:mod:`.block_jacobi_pcg`, :mod:`.prior_pcg`) and
the non-negativity refinement (its scalar diagonal, :mod:`.projected_refinement`) use it.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization", and section 6
   (convergence speed with large filters as the main limitation).
.. [2] Saad, Y. (2003). Iterative Methods for Sparse Linear Systems, 2nd ed., SIAM
   (block Jacobi, section 10.2).
"""

from __future__ import annotations

import numpy as np

from ..operators import PixelOrder, ReconstructionProblem

__all__ = ["BlockJacobiPreconditioner", "normal_mean_diagonal"]


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
    # one C_m per image (3-D): every image has as many pixels, so the mean over images
    c_energy = float(np.sum(c * c)) if c.ndim == 2 else float(np.sum(c * c, axis=(1, 2)).mean())
    return total / (n_wavelength * degree.size) + w.beta * c_energy / n_wavelength


class BlockJacobiPreconditioner:
    """Exact inverse of the per-pixel diagonal blocks of ``A^T A + epsilon I``.

    The block of pixel ``p`` is ``diag(a_p) + beta C^T C`` (``C``: its image's ``C_m``
    where every image has its own) with
    ``a_p(b) = alpha (F^T F)_{pp,b} + gamma L_pp + epsilon`` (filter and neighbour terms are
    diagonal in the wavelength). Its inverse follows from the Woodbury identity with one
    3 x 3 solve per pixel: ``M^-1 r = u - a^-1 C^T (I / beta + C a^-1 C^T)^-1 C u`` with
    ``u = r / a``.

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
        ridge: float | np.ndarray = 0.0,
        order: PixelOrder | None = None,
    ) -> None:
        # Built pixel-major in ``dtype`` and in chunks: about 1.2 vectors of the cube beside
        # what it keeps (no dense float64 diagonal cube, no permuted copies).
        w = problem.weights
        n_wavelength, n_image = problem.shape[:2]
        self.dtype = np.dtype(dtype)
        self.order = problem.pixel_order("natural") if order is None else order
        self.shape = problem.shape
        blocks, self.camera_index = problem.camera_blocks()
        c = blocks.astype(np.float64)  # (n_camera, 3, n_wavelength): one C, or one per camera
        degree = problem.neighbours.degree
        n_pixels = degree.size
        mean_diagonal = normal_mean_diagonal(problem)
        #: mean of the diagonal of ``A^T A``, the unit of relative ridges
        self.mean_diagonal = mean_diagonal
        # the ridge, or a far tinier one, keeps blocks without filter and neighbours invertible
        floor = max(1e-9 * mean_diagonal, 1e-300)
        ridge_shape = np.shape(ridge)
        self.ridge: np.ndarray | None
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
        # (I / beta + C a^-1 C^T)^-1 per pixel, (n_pixels, 3, 3): one compiled pass, each
        # 3 x 3 in float64 (closed form)
        from ..kernels import block_jacobi_setup

        self.small_inverse = np.empty((n_pixels, 3, 3), dtype=self.dtype)
        block_jacobi_setup(
            self.inverse_diagonal,
            np.ascontiguousarray(c),
            np.ascontiguousarray(self.camera_index[self.order.image]),
            float(max(w.beta, 1e-300)),
            self.small_inverse,
        )
        #: the distinct camera matrices ``(n_camera, 3, n_wavelength)`` in ``dtype``
        self.camera_matrix = np.ascontiguousarray(c.astype(self.dtype))
        self._beta = w.beta

    def inverse_scalar_diagonal_pixels(self) -> np.ndarray:
        """``1 / diag(A^T A + epsilon)``, pixel-major ``(n_pixels, n_wavelength)`` in
        :attr:`order` (the scaling of the non-negativity refinement,
        :mod:`.projected_refinement`)."""
        c = self.camera_matrix.astype(np.float64)
        full = np.divide(1.0, self.inverse_diagonal, dtype=self.dtype)  # one buffer, in place
        rgb_diagonal = (self._beta * np.sum(c * c, axis=1)).astype(self.dtype)  # (n_camera, w)
        if c.shape[0] == 1:
            full += rgb_diagonal[0][None, :]
        else:
            full += rgb_diagonal[self.camera_index[self.order.image]]
        return np.divide(1.0, full, out=full)

    def ridge_of(self, relative: float) -> float:
        """Absolute ``epsilon`` of a ridge given relative to the mean diagonal of ``A^T A``."""
        return float(relative) * self.mean_diagonal

    def apply_pixels(self, residual: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``M^-1 r`` on a pixel-major residual ``(n_pixels, n_wavelength)`` in :attr:`order`,
        one compiled pass (:func:`~..kernels.block_jacobi_pixels`)."""
        from ..kernels import block_jacobi_pixels

        if out is None:
            out = np.empty_like(residual)
        block_jacobi_pixels(
            residual,
            self.inverse_diagonal,
            self.camera_matrix,
            self.camera_index,
            self.order.image,
            self.small_inverse,
            out,
        )
        return out

    def step_pixels(
        self, x: np.ndarray, r: np.ndarray, p: np.ndarray, q: np.ndarray, step: float
    ) -> tuple[float, float]:
        """CG's update and this preconditioner in one compiled pass
        (:func:`~..kernels.cg_step_block_jacobi`): ``x += step p``, ``r -= step q``, then
        ``q = M^-1 r``; returns ``(r . r, r . M^-1 r)``. Pixel-major arrays in :attr:`order`."""
        from ..kernels import cg_step_block_jacobi

        rr, rz = cg_step_block_jacobi(
            x,
            r,
            p,
            q,
            x.dtype.type(step),
            self.inverse_diagonal,
            self.camera_matrix,
            self.camera_index,
            self.order.image,
            self.small_inverse,
        )
        return float(rr), float(rz)

    def __call__(self, residual: np.ndarray) -> np.ndarray:
        """``M^-1 r`` for a residual of the problem's :attr:`shape`."""
        pixels = self.order.to_pixels(np.asarray(residual, dtype=self.dtype).reshape(self.shape))
        return self.order.to_cube(self.apply_pixels(pixels))
