"""Matrix-free operators of the reconstruction energy (eq. 1).

The unknown spectral cube ``S`` of a set of images is held as one array of shape
``(n_wavelength, n_image, height, width)``; pixel ``q = image * height * width + y * width + x``
of ``S.reshape(n_wavelength, -1)`` is the paper's pixel ``p`` running over *all* pixels of
all images of the set.

Eq. 1 is a sum of three least-squares terms, so it is ``||A S - b||^2`` with a stacked,
weighted operator ``A``:

* the filter constraints ``F_i`` (:class:`FilterConstraints`): one Gaussian filter per
  filter centre of every band shot, applied to the unknown band image ``S_{b_i}``;
* the RGB term ``C S(p)`` (:func:`rgb_forward`, :func:`rgb_adjoint`);
* the appearance-neighbourhood term ``S(p) - S(n), n in N_p``
  (:class:`~spectralize.nodes.reconstruction.neighbourhoods.NeighbourGraph`).

:class:`ReconstructionProblem` stacks them with the weights of eq. 4 and provides ``A``,
``A^T``, the normal operator ``A^T A`` and its right-hand side ``A^T b``; nothing large is
ever stored as a matrix.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1 and "Filter Placement").
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
import scipy.sparse as sp

from spectralize.nodes.filter_size import filter_radius, filter_sigma
from spectralize.schemas.errors import ReconstructionError

from .inputs import ReconstructionInputs, camera_blocks
from .neighbourhoods import (
    NeighbourGraph,
    appearance_features,
    appearance_neighbours,
    appearance_order,
    brightness_ratios,
)
from .weights import TermWeights, default_gamma_hat, term_weights

__all__ = [
    "filter_centres",
    "gaussian_filter_matrix",
    "FilterConstraints",
    "PixelOrder",
    "rgb_forward",
    "rgb_adjoint",
    "ReconstructionProblem",
    "camera_scale",
    "build_problem",
]


def _einsum(subscripts: str, *operands: np.ndarray) -> np.ndarray:
    """Products with the 3 x n_wavelength camera matrix without BLAS.

    numpy's own single-threaded einsum loops are as fast here as BLAS and avoid the
    oversubscription of a threaded BLAS that waits for cores other work holds (tiles and
    sets are solved side by side).
    """
    return np.einsum(subscripts, *operands, optimize=False)


def filter_centres(length: int, filter_size: float, *, centre_spacing: float = 2.5) -> np.ndarray:
    """Filter-centre positions along one image axis (paper section 3, "Filter Placement").

    Centres keep a distance of at least ``filter_size`` (``s_i``) from the first and the
    last pixel and are spread evenly, at most ``centre_spacing`` (``d``) pixels apart.

    Parameters
    ----------
    length
        Number of pixels along the axis.
    filter_size
        Filter size ``s_i`` in pixels (eq. 3).
    centre_spacing
        Largest distance ``d`` between neighbouring centres in pixels (paper: 2.5).

    Returns
    -------
    numpy.ndarray
        Centre positions in pixel coordinates (pixel ``j`` is at ``j``), increasing, float64.

    Raises
    ------
    ReconstructionError
        When ``centre_spacing <= 0`` or no centre fits, i.e. ``2 * filter_size > length - 1``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filter Placement".
    """
    if not centre_spacing > 0:
        raise ReconstructionError(f"centre_spacing: expected a number > 0, found {centre_spacing!r}")
    low, high = float(filter_size), float(length - 1) - float(filter_size)
    if high < low:
        raise ReconstructionError(
            f"filter_size {filter_size:g} px leaves no filter centre inside an axis of "
            f"{length} px: centres keep s_i from both borders, so s_i <= {(length - 1) / 2:g}"
        )
    count = int(np.ceil((high - low) / centre_spacing - 1e-9)) + 1
    return np.linspace(low, high, count)


@lru_cache(maxsize=256)
def _filter_matrix_cached(
    length: int, filter_size: float, centre_spacing: float, dtype_name: str
) -> sp.csr_array:
    centres = filter_centres(length, filter_size, centre_spacing=centre_spacing)
    sigma = filter_sigma(filter_size)
    radius = filter_radius(filter_size)  # = s_i: a kernel centred s_i from a border stays inside
    first = np.maximum(np.ceil(centres - radius).astype(int), 0)
    last = np.minimum(np.floor(centres + radius).astype(int), length - 1)
    counts = last - first + 1
    rows = np.repeat(np.arange(len(centres)), counts)
    cols = np.concatenate([np.arange(a, b + 1) for a, b in zip(first, last, strict=True)])
    offsets = (cols - centres[rows]) / max(sigma, 1e-12)
    values = np.exp(-0.5 * offsets**2)
    sums = np.bincount(rows, weights=values, minlength=len(centres))
    values /= sums[rows]
    matrix = sp.csr_array((values.astype(dtype_name), (rows, cols)), shape=(len(centres), length))
    matrix.sort_indices()
    return matrix


def gaussian_filter_matrix(
    length: int, filter_size: float, *, centre_spacing: float = 2.5, dtype: np.dtype | type = np.float64
) -> sp.csr_array:
    """One axis of the separable filter operator: Gaussian weights at the filter centres.

    Row ``j`` holds the 1-D Gaussian with ``sigma = filter_size / 5`` centred at
    ``filter_centres(...)[j]``, truncated at ``filter_size`` (5 sigma) and normalised to sum 1.
    The 2-D filter response of a band image ``X`` at all centres is
    ``G_y @ X @ G_x.T`` (blur then sample at the centres); its adjoint is
    ``G_y.T @ R @ G_x`` (scatter to the centres then blur).

    Parameters
    ----------
    length
        Pixels along the axis.
    filter_size
        ``s_i`` in pixels (eq. 3).
    centre_spacing
        ``d`` in pixels.
    dtype
        Floating dtype of the matrix.

    Returns
    -------
    scipy.sparse.csr_array
        Shape ``(n_centres, length)``; the cached matrix, do not modify it.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filtering" and
       "Filter Placement".
    """
    return _filter_matrix_cached(
        int(length), float(filter_size), float(centre_spacing), np.dtype(dtype).name
    )


DENSE_AXIS_BELOW = 96
"""Axes shorter than this many pixels keep their filter matrices dense: on tiny tiles a
sparse product's fixed cost per call outweighs its arithmetic (the same products,
summed in another order: equal within float rounding)."""


@dataclass(frozen=True)
class _Axis:
    forward: sp.csr_array | np.ndarray  # (n_centres, length); dense below DENSE_AXIS_BELOW
    adjoint: sp.csr_array | np.ndarray  # (length, n_centres)
    diagonal: np.ndarray  # column sums of forward**2, (length,)


@dataclass
class FilterConstraints:
    """The filter term of eq. 1: all filter centres of all band shots, matrix-free.

    Shot ``i`` is the noisy band image ``D_i`` of wavelength index ``band[i]`` paired with
    image ``image[i]``. Its filters ``F`` are Gaussians (``sigma = s_i / 5``) centred on the
    grid of :func:`filter_centres` along ``y`` and ``x``; one filter constraint is
    ``sum_p F(p) (S_b(p) - D(p))`` (eq. 1, first term) and ``K`` counts them all.

    Parameters
    ----------
    shape
        ``(n_wavelength, n_image, height, width)`` of the unknown cube.
    band, image
        Per shot: wavelength index and image index, int arrays of length ``n_shot``.
    filter_size
        Per shot ``s_i`` in pixels.
    centre_spacing
        ``d`` in pixels.
    dtype
        Floating dtype the operator works in.
    """

    shape: tuple[int, int, int, int]
    band: np.ndarray
    image: np.ndarray
    filter_size: np.ndarray
    centre_spacing: float = 2.5
    dtype: np.dtype = field(default_factory=lambda: np.dtype(np.float64))
    _rows: list[_Axis] = field(init=False, repr=False)
    _cols: list[_Axis] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.dtype = np.dtype(self.dtype)
        self.band = np.asarray(self.band, dtype=np.intp)
        self.image = np.asarray(self.image, dtype=np.intp)
        self.filter_size = np.asarray(self.filter_size, dtype=np.float64)
        _, _, height, width = self.shape
        cache: dict[tuple[int, float], _Axis] = {}

        def axis(length: int, size: float) -> _Axis:
            key = (length, size)
            if key not in cache:
                forward = gaussian_filter_matrix(
                    length, size, centre_spacing=self.centre_spacing, dtype=self.dtype
                )
                diagonal = np.asarray((forward.multiply(forward)).sum(axis=0)).ravel()
                if length < DENSE_AXIS_BELOW:
                    dense = forward.toarray()
                    cache[key] = _Axis(dense, np.ascontiguousarray(dense.T), diagonal)
                else:
                    cache[key] = _Axis(forward, forward.T.tocsr(), diagonal)
            return cache[key]

        self._rows = [axis(height, s) for s in self.filter_size]
        self._cols = [axis(width, s) for s in self.filter_size]

    @property
    def n_shots(self) -> int:
        """Number of band shots."""
        return len(self.band)

    @property
    def centre_grid(self) -> list[tuple[int, int]]:
        """Per shot ``(n_centres_y, n_centres_x)``."""
        return [
            (r.forward.shape[0], c.forward.shape[0]) for r, c in zip(self._rows, self._cols, strict=True)
        ]

    @property
    def count(self) -> int:
        """``K``, the number of filter constraints over all shots (eq. 4)."""
        return int(sum(ny * nx for ny, nx in self.centre_grid))

    def apply_plane(self, shot: int, plane: np.ndarray) -> np.ndarray:
        """Filter responses of one band image at the centres of ``shot``: ``G_y X G_x^T``."""
        rows, cols = self._rows[shot], self._cols[shot]
        partial = rows.forward @ plane  # (n_cy, width)
        return np.ascontiguousarray((cols.forward @ partial.T).T)  # (n_cy, n_cx)

    def adjoint_plane(self, shot: int, responses: np.ndarray) -> np.ndarray:
        """Adjoint of :meth:`apply_plane`: ``G_y^T R G_x``, shape ``(height, width)``."""
        rows, cols = self._rows[shot], self._cols[shot]
        partial = (cols.adjoint @ responses.T).T  # (n_cy, width)
        return rows.adjoint @ np.ascontiguousarray(partial)

    def forward(self, cube: np.ndarray) -> list[np.ndarray]:
        """``F S``: the responses of every shot's filters to the cube, one array per shot."""
        return [self.apply_plane(i, cube[self.band[i], self.image[i]]) for i in range(self.n_shots)]

    def adjoint(self, responses: list[np.ndarray], out: np.ndarray | None = None) -> np.ndarray:
        """``F^T r``: scatter every shot's responses back into a cube of :attr:`shape`."""
        if out is None:
            out = np.zeros(self.shape, dtype=self.dtype)
        for i, response in enumerate(responses):
            out[self.band[i], self.image[i]] += self.adjoint_plane(i, response)
        return out

    def normal(
        self,
        cube: np.ndarray,
        out: np.ndarray | None = None,
        scale: float = 1.0,
        *,
        positions: np.ndarray | None = None,
    ) -> np.ndarray:
        """``scale * F^T F S`` (added to ``out`` when given), one shot at a time.

        With ``positions`` (:attr:`PixelOrder.positions`), ``cube`` and ``out`` are
        pixel-major ``(n_pixels, n_wavelength)`` in that pixel order instead of :attr:`shape`.
        """
        if out is None:
            out = np.zeros(cube.shape, dtype=self.dtype)
        self.add_normal(cube, out, scale, positions=positions)
        return out

    def add_normal(
        self, cube: np.ndarray, out: np.ndarray, scale: float, *, positions: np.ndarray | None = None
    ) -> float:
        """Add ``scale * F^T F S`` to ``out`` as :meth:`normal` does; returns ``S . (scale
        F^T F S) = scale ||F S||^2`` (float64), from the filter responses (no pass over the
        cube)."""
        factor = self.dtype.type(scale)
        plane_shape = self.shape[2:]
        total = 0.0
        if positions is not None:  # pixel-major: each image's bands gathered in one pass
            from .kernels import gather_bands, scatter_add_bands

            for m in np.unique(self.image):
                shots = np.flatnonzero(self.image == m)
                bands = np.ascontiguousarray(self.band[shots])
                where = positions[m]
                planes = np.empty((shots.size, where.size), dtype=cube.dtype)
                gather_bands(cube, where, bands, planes)
                for j, i in enumerate(shots.tolist()):
                    responses = self.apply_plane(i, planes[j].reshape(plane_shape))
                    total += float(scale) * float(
                        np.einsum("ij,ij->", responses, responses, dtype=np.float64)
                    )
                    if scale != 1.0:
                        responses *= factor
                    planes[j] = self.adjoint_plane(i, responses).ravel()
                scatter_add_bands(out, where, bands, planes)
            return total
        for i in range(self.n_shots):
            b, m = self.band[i], self.image[i]
            index = (b, m) if positions is None else (positions[m], b)
            responses = self.apply_plane(i, cube[index].reshape(plane_shape))
            total += float(scale) * float(np.einsum("ij,ij->", responses, responses, dtype=np.float64))
            if scale != 1.0:
                responses *= factor
            adjoint = self.adjoint_plane(i, responses)
            out[index] += adjoint if positions is None else adjoint.ravel()
        return total

    def normal_diagonal(self) -> np.ndarray:
        """Diagonal of ``F^T F`` as a cube of :attr:`shape` (separable: an outer product)."""
        out = np.zeros(self.shape, dtype=np.float64)
        for i in range(self.n_shots):
            out[self.band[i], self.image[i]] += np.outer(self._rows[i].diagonal, self._cols[i].diagonal)
        return out

    def add_normal_diagonal(self, out: np.ndarray, scale: float, positions: np.ndarray) -> None:
        """Add ``scale`` times the diagonal of ``F^T F`` to a pixel-major ``out``
        ``(n_pixels, n_wavelength)`` stored in the order of ``positions``
        (:attr:`PixelOrder.positions`), one shot plane at a time: the dense diagonal cube
        of :meth:`normal_diagonal` is never formed (it is zero on every band and image
        without a shot)."""
        for i in range(self.n_shots):
            plane = np.outer(self._rows[i].diagonal, self._cols[i].diagonal).ravel()
            out[positions[self.image[i]], self.band[i]] += (scale * plane).astype(out.dtype)

    def normal_diagonal_total(self) -> float:
        """The sum of the diagonal of ``F^T F`` (the sum of :meth:`normal_diagonal`)."""
        return float(
            sum(
                r.diagonal.sum(dtype=np.float64) * c.diagonal.sum(dtype=np.float64)
                for r, c in zip(self._rows, self._cols, strict=True)
            )
        )

    def astype(self, dtype: np.dtype | type) -> FilterConstraints:
        """The same constraints in another floating dtype."""
        return FilterConstraints(
            self.shape, self.band, self.image, self.filter_size, self.centre_spacing, np.dtype(dtype)
        )


_BANDS_PER_GATHER = 4
"""Bands :meth:`PixelOrder.to_pixels` gathers at once (a few band rows of gathered pixels
beside the result, not a second cube)."""

_PIXELS_PER_SCATTER = 65536
"""Positions :meth:`PixelOrder.to_cube` scatters at once."""


@dataclass
class PixelOrder:
    """A pixel-major storage order of a set's cube for the compiled solvers.

    The cube ``(n_wavelength, n_image, height, width)`` is stored as ``(n_pixels,
    n_wavelength)`` with pixel ``order[i]`` (index into (image, y, x) order) at position
    ``i``.

    Attributes
    ----------
    order
        Position -> pixel.
    positions
        ``(n_image, height * width)``: pixel -> position, per image.
    image
        ``(n_pixels,)`` int32: the image of the pixel at each position.
    graph
        The neighbour graph on pixels (the problem's, in (image, y, x) order).
    shape
        The cube's ``(n_wavelength, n_image, height, width)``.
    natural
        Whether ``order`` is the (image, y, x) order itself.
    """

    order: np.ndarray
    positions: np.ndarray
    image: np.ndarray
    graph: NeighbourGraph
    shape: tuple[int, int, int, int]
    natural: bool = False
    _laplacians: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(
        cls, order: np.ndarray, shape: tuple[int, int, int, int], graph: NeighbourGraph
    ) -> PixelOrder:
        """The storage ``order`` of a cube of ``shape`` whose neighbour graph is ``graph``."""
        order = np.asarray(order, dtype=np.intp)
        n_image = shape[1]
        position = np.empty_like(order)
        position[order] = np.arange(order.size)
        return cls(
            order,
            position.reshape(n_image, -1),
            (order // (shape[2] * shape[3])).astype(np.int32),
            graph,
            shape,
            bool(np.array_equal(order, np.arange(order.size))),
        )

    def laplacian(self, dtype: np.dtype) -> sp.csr_array:
        """The neighbour Laplacian on positions, in ``dtype``, built once per dtype.

        In a permuted order it is assembled from the graph moved to positions
        (:meth:`~.neighbourhoods.NeighbourGraph.permuted`), which is not kept: the solvers
        read only its Laplacian, and its neighbour lists would stay beside the problem's own
        for the whole solve."""
        if self.natural:
            return self.graph.astype(dtype).laplacian
        key = np.dtype(dtype).name
        if key not in self._laplacians:
            self._laplacians[key] = self.graph.permuted(self.order).astype(dtype).laplacian
        return self._laplacians[key]

    def to_pixels(self, cube: np.ndarray) -> np.ndarray:
        """``(n_wavelength, n_image, height, width)`` -> C-contiguous ``(n_pixels, n_wavelength)``
        in this order.

        A few bands at a time: each band's pixels are gathered along its own contiguous row
        (a pixel's values taken straight from the cube lie a whole band apart), then written
        into their columns of the result."""
        flat = cube.reshape(self.shape[0], -1)
        out = np.empty((flat.shape[1], flat.shape[0]), dtype=flat.dtype)
        for first in range(0, flat.shape[0], _BANDS_PER_GATHER):
            bands = slice(first, first + _BANDS_PER_GATHER)
            out[:, bands] = np.take(flat[bands], self.order, axis=1).T
        return out

    def to_cube(self, pixels: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_pixels`: a run of positions at a time, each scattered to
        its pixels in every band (the transpose of a run is small enough to stay in cache)."""
        pixels = pixels.reshape(-1, self.shape[0])
        out = np.empty((self.shape[0], pixels.shape[0]), dtype=pixels.dtype)
        for start in range(0, pixels.shape[0], _PIXELS_PER_SCATTER):
            run = slice(start, start + _PIXELS_PER_SCATTER)
            out[:, self.order[run]] = pixels[run].T
        return out.reshape(self.shape)


def rgb_forward(cube: np.ndarray, camera_matrix: np.ndarray) -> np.ndarray:
    """``C S(p)`` for every pixel: ``(3, n_pixels)`` from a cube ``(n_wavelength, ...)``.

    ``camera_matrix`` is ``C`` ``(3, n_wavelength)``, or one ``C_m`` per image
    ``(n_image, 3, n_wavelength)``: then the cube's pixels are ``n_image`` equal runs
    (image by image, as :attr:`ReconstructionProblem.shape` lays them out) and each run is
    mapped by its image's ``C_m``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1, second term.
    """
    n_wavelength = cube.shape[0]
    if camera_matrix.ndim == 3:
        n_image = camera_matrix.shape[0]
        per_image = _einsum("mcw,wmn->cmn", camera_matrix, cube.reshape(n_wavelength, n_image, -1))
        return per_image.reshape(3, -1)
    return _einsum("cw,wn->cn", camera_matrix, cube.reshape(n_wavelength, -1))


def rgb_adjoint(rgb: np.ndarray, camera_matrix: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """``C^T r`` for every pixel, shaped like the cube (``shape``); per image ``C_m^T r``
    for a 3-D ``camera_matrix`` (see :func:`rgb_forward`)."""
    if camera_matrix.ndim == 3:
        n_image = camera_matrix.shape[0]
        return _einsum("mcw,cmn->wmn", camera_matrix, rgb.reshape(3, n_image, -1)).reshape(shape)
    return _einsum("cw,cn->wn", camera_matrix, rgb).reshape(shape)


_PixelTerms = tuple[
    np.ndarray,  # camera blocks (n_camera, 3, n_wavelength)
    np.ndarray,  # each image's camera index
    np.floating,  # beta
    np.ndarray,  # the neighbour Laplacian, CSR: indptr
    np.ndarray,  # indices
    np.ndarray,  # data
    np.floating,  # gamma
    np.ndarray,  # the ridge per image and wavelength
    np.ndarray,  # each pixel's image
]
"""The compiled pixel passes' leading arguments (:meth:`ReconstructionProblem._pixel_terms`)."""


@dataclass
class ReconstructionProblem:
    """Eq. 1 as a weighted linear least-squares problem ``min ||A S - b||^2``.

    ``A S = [sqrt(alpha) F S; sqrt(beta) C S; sqrt(gamma) D S]`` and
    ``b = [sqrt(alpha) F D; sqrt(beta) R; 0]``, where ``F`` are the filter constraints,
    ``C`` the camera matrix, ``R`` the RGB radiance and ``D`` the neighbour differences.

    Parameters
    ----------
    filters
        The filter constraints.
    filter_targets
        Per shot the filter responses of the noisy band data, ``F_i D_{b_i}``.
    camera_matrix
        ``C``, ``(3, n_wavelength)``, already in the units the RGB term uses; or one
        ``C_m`` per image, ``(n_image, 3, n_wavelength)`` (:func:`rgb_forward`).
    rgb
        ``R``, ``(3, n_pixels)``, in the same units.
    neighbours
        The appearance-neighbourhood graph over all pixels.
    weights
        ``alpha, beta, gamma`` of eq. 4.
    extras
        Book-keeping that the operators do not use: ``inputs`` (the
        :class:`~spectralize.nodes.reconstruction.inputs.ReconstructionInputs`, for initial
        guesses), ``camera_scale`` and ``neighbour_seconds``.
    """

    filters: FilterConstraints
    filter_targets: list[np.ndarray]
    camera_matrix: np.ndarray
    rgb: np.ndarray
    neighbours: NeighbourGraph
    weights: TermWeights
    extras: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """``(n_wavelength, n_image, height, width)`` of the unknown cube."""
        return self.filters.shape

    @property
    def dtype(self) -> np.dtype:
        """Floating dtype of the operators."""
        return self.filters.dtype

    def astype(self, dtype: np.dtype | type) -> ReconstructionProblem:
        """The same problem with operators and data in another floating dtype."""
        dtype = np.dtype(dtype)
        if dtype == self.dtype:
            return self
        return ReconstructionProblem(
            filters=self.filters.astype(dtype),
            filter_targets=[t.astype(dtype) for t in self.filter_targets],
            camera_matrix=self.camera_matrix.astype(dtype),
            rgb=self.rgb.astype(dtype),
            neighbours=self.neighbours.astype(dtype),
            weights=self.weights,
            extras=self.extras,
        )

    # -- A and A^T (the paper's two functions) --------------------------------------------
    def apply(self, cube: np.ndarray) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """``A S``: the weighted residual operator, as (filter, rgb, neighbour) blocks."""
        w = self.weights
        filt = [np.sqrt(w.alpha) * r for r in self.filters.forward(cube)]
        rgb = np.sqrt(w.beta) * rgb_forward(cube, self.camera_matrix)
        nbr = np.sqrt(w.gamma) * self.neighbours.differences(cube.reshape(cube.shape[0], -1))
        return filt, rgb, nbr

    def apply_adjoint(self, blocks: tuple[list[np.ndarray], np.ndarray, np.ndarray]) -> np.ndarray:
        """``A^T y`` for blocks shaped like the output of :meth:`apply`."""
        filt, rgb, nbr = blocks
        w = self.weights
        out = self.filters.adjoint([np.sqrt(w.alpha) * r for r in filt])
        out += np.sqrt(w.beta) * rgb_adjoint(rgb, self.camera_matrix, self.shape)
        out += (np.sqrt(w.gamma) * self.neighbours.differences_adjoint(nbr)).reshape(self.shape)
        return out

    def target(self) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """``b``, the data blocks, shaped like :meth:`apply`'s output."""
        w = self.weights
        filt = [np.sqrt(w.alpha) * t for t in self.filter_targets]
        rgb = np.sqrt(w.beta) * self.rgb
        nbr = np.zeros((self.shape[0], self.neighbours.n_pairs), dtype=self.dtype)
        return filt, rgb, nbr

    # -- normal equations --------------------------------------------------------------------
    def normal(self, cube: np.ndarray) -> np.ndarray:
        """``A^T A S = alpha F^T F S + beta C^T C S + gamma L S`` (``L``: graph Laplacian).

        ``cube`` has :attr:`shape`; the work is done by :meth:`normal_pixels`.
        """
        order = self.pixel_order("natural")
        pixels = order.to_pixels(cube.astype(self.dtype, copy=False))
        return order.to_cube(self.normal_pixels(pixels, order=order))

    def pixel_order(self, kind: str = "appearance") -> PixelOrder:
        """The pixel-major storage order of the compiled solvers (:class:`PixelOrder`):
        ``"appearance"`` (:func:`~.neighbourhoods.appearance_order` of the RGB, fast) or
        ``"natural"`` (image, y, x). Built once per problem and kind."""
        cache = self.extras.setdefault("pixel_orders", {})
        key = (kind, self.dtype.name)
        if key not in cache:
            n_pixels = self.neighbours.n_pixels
            if kind == "natural":
                order = np.arange(n_pixels)
            elif kind == "appearance":
                order = appearance_order(np.asarray(self.rgb, dtype=np.float64).T)
            else:
                raise ReconstructionError(
                    f"pixel order: expected 'appearance' or 'natural', found {kind!r}"
                )
            cache[key] = PixelOrder.build(order, self.shape, self.neighbours)
        return cache[key]

    def release_pixel_orders(self) -> None:
        """Drop the pixel orders :meth:`pixel_order` keeps (their index arrays and
        Laplacians): a solver calls it when its solve is done, so that what runs next (a
        set model, the confidence) does not hold them; a later call builds them again, the
        same."""
        self.extras.pop("pixel_orders", None)

    def normal_pixels(
        self,
        cube: np.ndarray,
        *,
        order: PixelOrder,
        epsilon: np.ndarray | float = 0.0,
        out: np.ndarray | None = None,
    ) -> np.ndarray:
        """``(A^T A + epsilon I) S`` on a pixel-major cube ``(n_pixels, n_wavelength)``.

        The RGB term, the neighbour Laplacian and the ridge in one compiled pass over the
        pixels (:func:`~.kernels.normal_pixels`), then the filter term on the band planes.

        Parameters
        ----------
        cube
            C-contiguous, in :attr:`dtype`, pixels stored in ``order``
            (:meth:`PixelOrder.to_pixels`).
        order
            The storage order (:meth:`pixel_order`).
        epsilon
            Ridge: a number or an array that broadcasts to ``(n_wavelength, n_image, 1, 1)``.
        out
            Array to write into (same shape as ``cube``).
        """
        from .kernels import normal_pixels

        if out is None:
            out = np.empty_like(cube)
        normal_pixels(cube, *self._pixel_terms(order, epsilon), out)
        self.filters.normal(cube, out=out, scale=self.weights.alpha, positions=order.positions)
        return out

    def _pixel_terms(self, order: PixelOrder, epsilon: np.ndarray | float) -> _PixelTerms:
        """The compiled pixel passes' leading arguments: the camera blocks and each image's
        index, ``beta``, the neighbour Laplacian (CSR), ``gamma``, the ridge per image and
        wavelength, and each pixel's image."""
        w = self.weights
        n_wavelength, n_image = self.shape[:2]
        dtype = self.dtype
        ridge = np.broadcast_to(np.asarray(epsilon, dtype=dtype), (n_wavelength, n_image, 1, 1))
        laplacian = order.laplacian(dtype)
        blocks, index = self.camera_blocks()
        return (
            blocks,
            index,
            dtype.type(w.beta),
            laplacian.indptr,
            laplacian.indices,
            laplacian.data,
            dtype.type(w.gamma),
            np.ascontiguousarray(ridge[:, :, 0, 0].T),
            order.image,
        )

    def prior_normal_pixels(
        self,
        cube: np.ndarray,
        *,
        order: PixelOrder,
        epsilon: np.ndarray | float,
        out: np.ndarray,
        precision: np.ndarray | None = None,
        weight: np.ndarray | None = None,
        brightness: np.ndarray | None = None,
        shots: np.ndarray | None = None,
        subtract: np.ndarray | None = None,
    ) -> float:
        """``out = (A^T A + epsilon I + w_p Q + f_p M_m) S - subtract`` on a pixel-major
        cube; returns ``S . out`` (the curvature CG needs, meaningless with ``subtract``).

        :meth:`normal_pixels` with the priors' per-pixel terms of
        :func:`~.solvers.prior_pcg.prior_pcg` fused into its compiled pass
        (:func:`~.kernels.prior_normal_pixels`): one pass over the cube for the RGB term,
        the neighbour Laplacian, the ridge, the spectral prior ``w_p Q S_p`` (``precision``
        ``(n_wavelength, n_wavelength)``, ``weight`` ``(n_pixels,)`` in ``order``), the
        brightness-weighted guided prior ``f_p M_m S_p`` (``brightness`` ``(n_pixels,)``,
        ``shots`` ``(n_image, n_wavelength)``) and ``- subtract`` (a gradient's right-hand
        side), then the filter term on the band planes, whose share of ``S . out`` comes
        from its responses. Terms given as None are left out.
        """
        from .kernels import prior_normal_pixels

        dtype = self.dtype
        empty = np.empty(0, dtype=dtype)
        total = prior_normal_pixels(
            cube,
            *self._pixel_terms(order, epsilon),
            np.empty((0, 0), dtype=dtype) if precision is None else precision,
            empty if weight is None else weight,
            empty if brightness is None else brightness,
            np.empty((0, 0), dtype=dtype) if shots is None else shots,
            np.empty((0, 0), dtype=dtype) if subtract is None else subtract,
            out,
        )
        total += self.filters.add_normal(cube, out, self.weights.alpha, positions=order.positions)
        return float(total)

    def camera_blocks(self) -> tuple[np.ndarray, np.ndarray]:
        """The distinct camera matrices ``(n_camera, 3, n_wavelength)`` in :attr:`dtype` and
        per image the index of its own (:func:`~.inputs.camera_blocks`); built once."""
        cache = self.extras.setdefault("camera_blocks", {})
        if self.dtype.name not in cache:
            cache[self.dtype.name] = camera_blocks(self.camera_matrix, self.shape[1])
        return cache[self.dtype.name]

    def normal_rhs(self) -> np.ndarray:
        """``A^T b = alpha F^T (F D) + beta C^T R``."""
        w = self.weights
        out = self.filters.adjoint([self.dtype.type(w.alpha) * t for t in self.filter_targets])
        out += self.dtype.type(w.beta) * rgb_adjoint(self.rgb, self.camera_matrix, self.shape)
        return out

    def energy(self, cube: np.ndarray) -> float:
        """Eq. 1, ``E(S) = ||A S - b||^2``, in float64."""
        applied, wanted = self.apply(cube), self.target()
        total = sum(
            float(np.sum((a.astype(np.float64) - b) ** 2))
            for a, b in zip(applied[0], wanted[0], strict=True)
        )
        total += float(np.sum((applied[1].astype(np.float64) - wanted[1]) ** 2))
        total += float(np.sum(applied[2].astype(np.float64) ** 2))
        return total


def camera_scale(camera_matrix: np.ndarray) -> float:
    """The factor that puts the RGB term of eq. 1 in the units of the bands.

    The mean over channels of ``sum_lambda |C(c, lambda)|``: a flat unit spectrum then maps
    to RGB of about 1, so ``C S - R`` is measured in spectral radiance like the other two
    terms and the result does not depend on the overall gain of ``C`` and ``R``. With one
    ``C_m`` per image ``(n_image, 3, n_wavelength)``, the mean over images and channels
    (one factor for the set: the images' RGB keep their ratios).
    """
    scale = float(np.mean(np.abs(camera_matrix).sum(axis=-1)))
    return scale if scale > 0 else 1.0


def build_problem(
    inputs: ReconstructionInputs,
    *,
    alpha_hat: float = 1.0,
    beta_hat: float = 1.0,
    gamma_hat: float | None = None,
    k: int = 3,
    centre_spacing: float = 2.5,
    normalize_camera_matrix: bool = True,
    neighbours: np.ndarray | None = None,
    appearance: str = "rgb",
    scale_invariant: bool = False,
    dtype: np.dtype | type = np.float64,
) -> ReconstructionProblem:
    """Set up eq. 1 for a set of images: filters, neighbour graph and eq. 4 weights.

    Parameters
    ----------
    inputs
        The checked input arrays.
    alpha_hat, beta_hat, gamma_hat
        Relative weights of eq. 4; ``gamma_hat=None`` takes the paper's choice (1 for one
        image, 20 for a set).
    k
        Appearance neighbours per pixel (paper: 3).
    centre_spacing
        ``d``, the largest distance between filter centres in pixels (paper: 2.5).
    normalize_camera_matrix
        Divide ``C`` and ``R`` by :func:`camera_scale` (recommended; see there).
    neighbours
        Precomputed ``(n_pixels, k)`` neighbour indices (else computed from the RGB).
    appearance
        Appearance space of the neighbour search
        (:func:`~.neighbourhoods.appearance_features`): ``"rgb"`` (paper) or
        ``"chromaticity-spatial"``.
    scale_invariant
        Couple neighbours as ``S(p) - (b_p / b_n) S(n)`` (``b``: RGB brightness), so that a
        texel seen at another brightness keeps its spectral shape (paper: ``False``).
    dtype
        Floating dtype of the operators.

    Returns
    -------
    ReconstructionProblem
        Its ``extras`` hold ``camera_scale``, ``neighbour_seconds`` and ``inputs``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, eqs. 1 and 4.
    """
    dtype = np.dtype(dtype)
    scale = camera_scale(inputs.camera_matrix) if normalize_camera_matrix else 1.0
    rgb = inputs.rgb_pixels() / scale
    started = time.perf_counter()
    if neighbours is None:
        features = appearance_features(rgb, inputs.cube_shape[1:], space=appearance)
        neighbours = appearance_neighbours(features, k=k)
    ratios = brightness_ratios(rgb, neighbours) if scale_invariant else None
    graph = NeighbourGraph(neighbours, dtype, ratios)
    neighbour_seconds = time.perf_counter() - started
    filters = FilterConstraints(
        inputs.cube_shape, inputs.band, inputs.image, inputs.filter_size, centre_spacing, dtype
    )
    targets = [filters.apply_plane(i, inputs.band_data[i].astype(dtype)) for i in range(filters.n_shots)]
    if gamma_hat is None:
        gamma_hat = default_gamma_hat(inputs.n_image)
    weights = term_weights(
        filters.count,
        graph.n_pixels,
        graph.n_pairs,
        alpha_hat=alpha_hat,
        beta_hat=beta_hat,
        gamma_hat=gamma_hat,
    )
    return ReconstructionProblem(
        filters=filters,
        filter_targets=targets,
        camera_matrix=(inputs.camera_matrix / scale).astype(dtype),
        rgb=rgb.astype(dtype),
        neighbours=graph,
        weights=weights,
        extras={"camera_scale": scale, "neighbour_seconds": neighbour_seconds, "inputs": inputs},
    )
