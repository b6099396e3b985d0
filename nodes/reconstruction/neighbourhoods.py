"""Appearance neighbourhoods ``N_p``: k nearest neighbours in the camera's RGB space.

The neighbourhood of pixel ``p`` is the set of the ``k`` (paper: 3) pixels with the closest
RGB values over *all* pixels of *all* images of a set (paper section 3). The third term of
eq. 1, ``gamma sum_p sum_{n in N_p} ||S(p) - S(n)||^2``, couples them; over a set of images
it is what carries spectral information from images with band shots to images without.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, eq. 1 (third term) and
   "Application for Reflectance Acquisition".
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from pykdtree.kdtree import KDTree

from spectralize.schemas.errors import ReconstructionError

__all__ = [
    "appearance_neighbours",
    "appearance_features",
    "brightness_ratios",
    "appearance_order",
    "appearance_bins",
    "NeighbourGraph",
    "APPEARANCE_SPACES",
]

APPEARANCE_SPACES = ("rgb", "chromaticity-spatial")
"""Appearance spaces of :func:`appearance_features`: the paper's RGB, and chromaticity with
spatial proximity (the paper's own fix for metamers, section 6)."""


def appearance_bins(
    rgb: np.ndarray, mean_level: np.ndarray | float, bins: tuple[int, int]
) -> np.ndarray:
    """Per colour of ``rgb`` ``(..., 3)`` (non-negative) its bin of an appearance histogram:
    the chromaticity ``(r, g) / (r + g + b)`` in ``n_c x n_c`` bins and the brightness
    ``(r + g + b) / mean_level`` in ``n_l`` bins of log2 steps from 1/16, ``bins = (n_c,
    n_l)``; integers in ``[0, n_c^2 n_l)``.

    Pixels of one bin look alike, so they mostly hold the same material: the band evidence
    pools over them (:mod:`~.solvers.band_evidence`, :mod:`~.estimators.evidence_blend`).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (appearance neighbours).
    """
    n_c, n_l = bins
    total = rgb.sum(axis=-1)
    chroma = rgb[..., :2] / np.maximum(total, 1e-300)[..., None]
    level = total / np.maximum(mean_level, 1e-300)
    c = np.clip((chroma * n_c).astype(np.intp), 0, n_c - 1)
    b = np.clip(np.floor(np.log2(np.maximum(level, 1e-300)) + 4).astype(np.intp), 0, n_l - 1)
    return (c[..., 0] * n_c + c[..., 1]) * n_l + b


def appearance_neighbours(
    appearance: np.ndarray, *, k: int = 3, queries: np.ndarray | None = None
) -> np.ndarray:
    """The ``k`` nearest neighbours of every pixel in appearance (RGB) space.

    Parameters
    ----------
    appearance
        ``(n_pixels, n_features)``: one row per pixel of all images of the set (RGB: 3).
    k
        Neighbours per pixel (paper: 3). Clipped to ``n_pixels - 1``.
    queries
        Indices of the pixels whose neighbours are wanted (searched among all pixels; the
        answer for a pixel does not depend on which others are asked); None: all.

    Returns
    -------
    numpy.ndarray
        ``(n_pixels, k)`` (``(len(queries), k)``) int indices; row ``p`` never contains
        ``p`` itself. Pixels with identical appearance are neighbours of each other (ties
        are broken by the tree).

    Notes
    -----
    An exact k-d tree search over all pixels (``pykdtree``, float32 features, its queries
    on OpenMP threads: ``OMP_NUM_THREADS``, all cores by default), chosen over
    :class:`scipy.spatial.cKDTree` because this search is the largest step of a tile's
    set-up and pykdtree's is the faster on a tile's features. The queries are asked in
    Morton order (:func:`appearance_order`: the same answers, read from a tree that stays
    in cache). The query asks for ``k + 1``
    points and drops the pixel itself (or, when ``k + 1`` duplicates tie, the last of them).
    """
    appearance = np.ascontiguousarray(appearance, dtype=np.float32)
    n_pixels = appearance.shape[0]
    asked = np.arange(n_pixels) if queries is None else np.asarray(queries, dtype=np.intp)
    k = int(min(k, n_pixels - 1))
    if k <= 0:
        return np.zeros((asked.size, 0), dtype=np.intp)
    tree = KDTree(appearance, leafsize=32)
    points = appearance if queries is None else appearance[asked]
    # queried along a Morton curve through every feature (:func:`appearance_order`):
    # consecutive queries walk the same branches of the tree, so its nodes stay in cache
    # (each query's answer does not depend on the order they are asked in)
    order = appearance_order(points, features=points.shape[1])
    # squared distances: pykdtree's own, no square roots of answers that are dropped
    _, answers = tree.query(np.ascontiguousarray(points[order]), k=k + 1, sqr_dists=True)
    del points
    # back to the asked order by a gather through the inverse permutation, in the tree's
    # compact index type (one pass, no scatter of rows, no full-width copy before it)
    inverse = np.empty(asked.size, dtype=np.intp)
    inverse[order] = np.arange(asked.size, dtype=np.intp)
    found = answers.reshape(asked.size, k + 1).take(inverse, axis=0)
    del answers, inverse
    # the pixel itself is nearly always its own first answer: the next k are its neighbours
    mixed = np.flatnonzero(found[:, 0] != asked)
    neighbours = found[:, 1 : k + 1].astype(np.intp)
    if mixed.size:  # ties among duplicates: the others first, in distance order, keep k
        rows = found[mixed].astype(np.intp)
        order = np.argsort(rows == asked[mixed][:, None], axis=1, kind="stable")
        neighbours[mixed] = np.take_along_axis(rows, order, axis=1)[:, :k]
    return neighbours


def appearance_features(
    rgb: np.ndarray,
    shape: tuple[int, int, int],
    *,
    space: str = "rgb",
    spatial_scale: float = 0.002,
    brightness_scale: float = 0.05,
) -> np.ndarray:
    """Per-pixel features ``(n_pixels, n_features)`` in which neighbours are searched.

    ``"rgb"``: the RGB itself (paper section 3). ``"chromaticity-spatial"``: the chromaticity
    ``(r, g) = (R, G) / (R + G + B)``, ``brightness_scale * log(R + G + B)`` and the pixel
    position ``spatial_scale * (y, x)`` [per px]. Chromaticity does not change with shading,
    so the same texel in the other images of a rectified set (same position, same
    chromaticity, other brightness) is a near neighbour; position separates metamers that
    are not adjacent (paper section 6).

    Parameters
    ----------
    rgb
        ``(3, n_pixels)``, pixels of all images in (image, y, x) order.
    shape
        ``(n_image, height, width)``.
    space
        One of :data:`APPEARANCE_SPACES`.
    spatial_scale, brightness_scale
        Weights of position [per px] and log brightness against chromaticity.
    """
    if space == "rgb":
        return np.asarray(rgb, dtype=np.float64).T
    if space != "chromaticity-spatial":
        raise ReconstructionError(f"appearance: expected one of {APPEARANCE_SPACES}, found {space!r}")
    rgb = np.asarray(rgb, dtype=np.float64)
    total = rgb.sum(axis=0)
    floor = 1e-3 * max(float(np.median(np.abs(total))), 1e-30)
    safe = np.maximum(total, floor)
    n_image, height, width = shape
    y, x = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    position = np.tile(np.stack([y.ravel(), x.ravel()], axis=1), (n_image, 1)) * spatial_scale
    chroma = (rgb[:2] / safe).T
    return np.hstack([chroma, brightness_scale * np.log(safe)[:, None], position])


def brightness_ratios(
    rgb: np.ndarray, neighbours: np.ndarray, *, limit: float = 20.0, pixels: np.ndarray | None = None
) -> np.ndarray:
    """``b_p / b_n`` for every pair (``b = R + G + B``), clipped to ``[1 / limit, limit]``:
    the scale-invariant coupling ``S(p) - (b_p / b_n) S(n)``. With ``pixels``, ``neighbours``
    holds the rows of those pixels only (the brightness floor is still the whole set's)."""
    total = np.asarray(rgb, dtype=np.float64).sum(axis=0)
    floor = 1e-3 * max(float(np.median(np.abs(total))), 1e-30)
    total = np.maximum(total, floor)
    here = total if pixels is None else total[pixels]
    return np.clip(here[:, None] / total[neighbours], 1 / limit, limit)


def appearance_order(appearance: np.ndarray, *, bits: int = 10, features: int = 3) -> np.ndarray:
    """Pixels sorted along a Morton (Z-order) curve through appearance space.

    Appearance neighbours are far apart in image order, so a pass over the neighbour term
    jumps through memory; stored in this order, most neighbours of a pixel lie close to it,
    so the solvers' passes over the neighbour term read memory mostly in order.

    Parameters
    ----------
    appearance
        ``(n_pixels, n_features)``.
    bits
        Quantisation per feature (the curve's resolution); at most ``64 // features``
        are used (the code is 64 bits wide).
    features
        How many of the leading features the curve runs through (the storage order of the
        solvers: the first three, e.g. RGB; the neighbour search's queries: all of them, so
        that consecutive queries are near in every feature the tree splits on).

    Returns
    -------
    numpy.ndarray
        ``order``: position ``i`` holds pixel ``order[i]``.

    References
    ----------
    .. [1] Morton, G. M. (1966). A computer oriented geodetic data base and a new technique
       in file sequencing. IBM Technical Report.
    """
    appearance = np.asarray(appearance)
    n_axes = min(int(features), appearance.shape[1])
    bits = min(int(bits), 64 // max(n_axes, 1))
    features_used = np.asarray(appearance[:, :n_axes], dtype=np.float64)
    low = np.nanmin(features_used, axis=0) if features_used.size else 0.0
    span = (np.nanmax(features_used, axis=0) - low) if features_used.size else 1.0
    levels = (1 << bits) - 1
    # ((f - low) / span) * levels, clipped to [0, levels]: in one buffer, step by step
    scaled = np.subtract(features_used, low)
    scaled /= np.where(span > 0, span, 1.0)
    scaled *= levels
    np.nan_to_num(scaled, copy=False)
    np.clip(scaled, 0, levels, out=scaled)
    quantised = scaled.astype(np.uint64)
    del scaled
    # bit ``b`` of a quantised value goes to bit ``b * n_axes`` of the code: spread once for
    # every value a feature can take, then one table look-up per feature and pixel
    values = np.arange(levels + 1, dtype=np.uint64)
    spread = np.zeros(values.size, dtype=np.uint64)
    for bit in range(bits):
        spread |= ((values >> np.uint64(bit)) & np.uint64(1)) << np.uint64(bit * n_axes)
    code = np.zeros(features_used.shape[0], dtype=np.uint64)
    for axis in range(n_axes):
        code |= spread[quantised[:, axis]] << np.uint64(axis)
    return np.argsort(code, kind="stable")


@dataclass
class NeighbourGraph:
    """The neighbour-difference operator ``D`` and its Laplacian ``L = D^T D``.

    Row ``p * k + j`` of ``D`` is ``e_p - e_{N_p[j]}``, so ``||D S||^2`` is the third sum of
    eq. 1 and ``sum_p |N_p| = n_pairs``.

    Parameters
    ----------
    neighbours
        ``(n_pixels, k)`` indices from :func:`appearance_neighbours`.
    dtype
        Floating dtype of the operator.
    ratios
        Optional ``(n_pixels, k)`` factors ``r``: row ``p * k + j`` is then
        ``e_p - r e_{N_p[j]}`` (scale-invariant coupling, :func:`brightness_ratios`);
        ``None``: all 1 (eq. 1).
    """

    neighbours: np.ndarray
    dtype: np.dtype = field(default_factory=lambda: np.dtype(np.float64))
    ratios: np.ndarray | None = None
    _difference: sp.csr_array | None = field(init=False, repr=False, default=None)
    _laplacian: sp.csr_array | None = field(init=False, repr=False, default=None)
    _degree: np.ndarray | None = field(init=False, repr=False, default=None)
    _scaled: dict = field(init=False, repr=False, default_factory=dict)

    def __post_init__(self) -> None:
        self.dtype = np.dtype(self.dtype)
        self.neighbours = np.asarray(self.neighbours, dtype=np.intp)
        if self.ratios is not None:  # in the operator's dtype (float32: half the memory)
            self.ratios = np.asarray(self.ratios, dtype=self.dtype)

    def _ratios(self) -> np.ndarray:
        """``r`` per pair, float64, ``(n_pairs,)`` (all 1 without ratios)."""
        if self.ratios is None:
            return np.ones(self.neighbours.size)
        return np.asarray(self.ratios, np.float64).ravel()

    def _assemble_laplacian(self) -> sp.csr_array:
        """``L = D^T D = sum over pairs (e_p - r e_n)(e_p - r e_n)^T``.

        With the pairs' weights ``W`` (``W[p, N_p[j]] = r``), ``L = diag - (W + W^T)``, the
        diagonal :attr:`degree`: each row built straight from the pixel's neighbour list
        and the pairs that end at it, in one compiled pass that counts the rows' entries
        and one that writes them (:func:`~.kernels.laplacian_rows`; scipy's sums of ``W``,
        ``W^T`` and the diagonal bit for bit), without the COO triplets or the sparse sums'
        intermediate matrices that would cost a tile's set-up time and its peak memory.
        """
        from .kernels import laplacian_rows

        n_pixels, k = self.neighbours.shape
        neighbours = np.ascontiguousarray(self.neighbours, dtype=np.int64)
        ratios = np.ascontiguousarray(self._ratios().reshape(n_pixels, k), dtype=np.float64)
        ending = neighbours.ravel()  # pair p * k + j ends at N_p[j]
        reverse_pair = np.argsort(ending, kind="stable")
        reverse_ptr = np.zeros(n_pixels + 1, dtype=np.int64)
        np.cumsum(np.bincount(ending, minlength=n_pixels), out=reverse_ptr[1:])
        degree = np.ascontiguousarray(self.degree, dtype=np.float64)
        indptr = np.zeros(n_pixels + 1, dtype=np.int64)
        none = np.empty(0, dtype=np.int64)
        laplacian_rows(
            neighbours, ratios, degree, reverse_ptr, reverse_pair, indptr, none, none.astype(self.dtype)
        )
        np.cumsum(indptr, out=indptr)
        # 32-bit column indices where they fit (scipy's choice too): the solvers read the
        # Laplacian in every pass and hold it for the whole solve
        entries = int(indptr[-1])
        index = np.int32 if max(entries, n_pixels) <= np.iinfo(np.int32).max else np.int64
        indices = np.empty(entries, dtype=index)
        data = np.empty(entries, dtype=self.dtype)
        laplacian_rows(neighbours, ratios, degree, reverse_ptr, reverse_pair, indptr, indices, data)
        return sp.csr_array((data, indices, indptr.astype(index)), shape=(n_pixels, n_pixels))

    @property
    def difference_operator(self) -> sp.csr_array:
        """``D`` (``n_pairs x n_pixels``), built on first use."""
        if self._difference is None:
            n_pixels, k = self.neighbours.shape
            pairs = n_pixels * k
            rows = np.arange(pairs)
            here = np.repeat(np.arange(n_pixels), k)
            other = -np.ones(pairs) if self.ratios is None else -np.asarray(self.ratios).ravel()
            data = np.concatenate([np.ones(pairs), other]).astype(self.dtype)
            self._difference = sp.csr_array(
                (data, (np.concatenate([rows, rows]), np.concatenate([here, self.neighbours.ravel()]))),
                shape=(pairs, n_pixels),
            )
        return self._difference

    @property
    def n_pixels(self) -> int:
        """Pixels over all images of the set (``P``)."""
        return self.neighbours.shape[0]

    @property
    def n_pairs(self) -> int:
        """``sum_p |N_p|`` (eq. 4)."""
        return self.neighbours.size

    @property
    def degree(self) -> np.ndarray:
        """Diagonal of ``L``: per pixel ``k`` (its own pairs) plus ``r^2`` of every pair that
        ends at it (with ``r = 1``: out-degree plus in-degree), without building ``L``;
        computed once (the Laplacian, the preconditioner and the unit of the priors all read
        it; a graph in another dtype shares it: its pairs and ratios are the same)."""
        if self._degree is None:
            n_pixels, k = self.neighbours.shape
            r = self._ratios()
            self._degree = k + np.bincount(self.neighbours.ravel(), weights=r * r, minlength=n_pixels)
            self._degree.flags.writeable = False
        return self._degree

    @property
    def laplacian(self) -> sp.csr_array:
        """``L = D^T D`` (``n_pixels x n_pixels``), built on first use: the compiled solvers
        use only the graph in their own pixel order, so the natural-order one is never
        assembled for them (a tile's peak memory would hold both)."""
        if self._laplacian is None:
            self._laplacian = self._assemble_laplacian()
        return self._laplacian

    def differences(self, flat: np.ndarray) -> np.ndarray:
        """``D S``: ``S(p) - S(n)`` for every pair, ``(n_channels, n_pairs)`` from
        ``(n_channels, n_pixels)``."""
        k = self.neighbours.shape[1]
        there = flat[:, self.neighbours.ravel()]
        if self.ratios is not None:
            there = there * self.ratios.ravel().astype(flat.dtype)
        return np.repeat(flat, k, axis=1) - there

    def differences_adjoint(self, pairs: np.ndarray) -> np.ndarray:
        """``D^T y``: ``(n_channels, n_pixels)`` from ``(n_channels, n_pairs)``."""
        return np.asarray(pairs @ self.difference_operator)

    def laplacian_apply(
        self, flat: np.ndarray, *, scale: float = 1.0, out: np.ndarray | None = None
    ) -> np.ndarray:
        """``scale * L S`` for ``S`` of shape ``(n_channels, n_pixels)``; added to ``out``
        when given.

        ``L`` is applied to the pixel-major copy of ``S`` (contiguous rows of
        ``n_channels`` values per pixel), which is about twice as fast as per channel.
        """
        key = float(scale)
        if key not in self._scaled:
            self._scaled = {key: (self.laplacian * self.dtype.type(scale)).astype(self.dtype)}
        matrix = self._scaled[key]
        pixel_major = np.ascontiguousarray(flat.T)
        result = np.ascontiguousarray((matrix @ pixel_major).T)
        if out is None:
            return result
        out += result
        return out

    def permuted(self, order: np.ndarray) -> NeighbourGraph:
        """The same graph with the pixels stored in ``order`` (position ``i`` holds pixel
        ``order[i]``, e.g. :func:`appearance_order`)."""
        position = np.empty_like(order)
        position[order] = np.arange(order.size)
        ratios = None if self.ratios is None else self.ratios[order]
        return NeighbourGraph(position[self.neighbours[order]], self.dtype, ratios)

    def astype(self, dtype: np.dtype | type) -> NeighbourGraph:
        """The same graph in another floating dtype."""
        dtype = np.dtype(dtype)
        if dtype == self.dtype:
            return self
        other = copy.copy(self)
        other.dtype = dtype
        other._laplacian = self.laplacian.astype(dtype)  # built (and kept) here once
        other._difference = None
        other._scaled = {}
        return other
