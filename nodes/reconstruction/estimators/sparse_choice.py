"""Estimator ``"sparse-choice"``: each texel's few materials chosen once for the whole set,
with the evidence of all its images, then mixed per image from its RGB.

The endmember mixture (:mod:`.endmember_mixture`) picks a pixel's candidate endmembers by
its chromaticity in one image; a highlight pulls that chromaticity towards the light's, and
a pixel between two materials sits nearer a third. In a set, a texel keeps its materials
while its highlight and shading change from image to image (the dichromatic model), so the
choice is made per texel over all images of the set:

1. **Candidates**: per texel and endmember ``E_j`` the summed chi^2 over the images of the
   best fit ``R_m ~ a_m E_j + h_m L`` (``a_m, h_m >= 0``, ``L`` the highlight atom): the
   lines through the images' RGB meet at the texel's material. The ``candidates`` endmembers
   with the lowest sums, and ``L``, are the texel's candidates.
2. **Supports**: every subset ``T`` of at most ``max_support`` candidates. Per image the
   exact non-negative least squares of ``R_m`` on ``T`` (any sub-support of ``T``: the
   subsets are visited by size and each keeps the best of itself and its children) gives
   ``rgb_cost(T) = sum_m ||C A w_m - R_m||^2 / sigma_R^2`` and, with the band shots ``D_i``
   of the images, ``band_cost(T) = sum_i ((A w_{m_i})_{b_i} - D_i)^2 / (sigma_i^2 +
   (e_b (A w)_{b_i})^2)``; ``sigma_R`` is the RGB noise with a relative model error
   ``rgb_model_error`` (the endmembers are learnt, not exact), ``sigma_i`` the shot's noise
   (:func:`~.endmember_mixture.band_noise_sigma`), ``e_b`` = ``band_model_error``.
   With ``context`` the costs of each texel's supports are pooled with the same supports'
   costs on its RGB-similar neighbours (non-local means over the set's images: a texel's
   neighbours of like RGB in every image usually hold the same materials, and an RGB edge
   cuts the pooling; :func:`rgb_similar_neighbours`).
3. **Choice**: ``argmin_T rgb_cost + band_cost + penalty |T|``. Four atoms fit three RGB
   equations in many ways; the size penalty keeps the sparsest support that the evidence
   allows (the Bayesian information criterion's form). With ``context_candidates`` the
   endmembers the texel's RGB-similar neighbours chose join its candidates (a material its
   own dichromatic fits miss, :func:`neighbour_candidates`), each at a further cost
   ``context_candidate_penalty`` in a support, and steps 2 and 3 run again.
4. Per image the abundances on the chosen support from its RGB (non-negative least squares,
   :func:`~.endmember_mixture.rgb_abundances`), the mixture projected onto ``C S = R`` and
   ``S >= 0``.

The choice needs the images of a set on one texel grid (as the set nodes solve them) and a
library of endmembers good to a few degrees: a run's library
(:mod:`~..endmember_library`), given as ``endmembers``, or the set's own
(:func:`~.endmember_mixture.set_endmembers`).

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 and 3 (eq. 1's RGB term; the image
   sets of a run).
.. [2] Shafer, S. A. (1985). Using color to separate reflection components. Color Research
   and Application 10(4) (the dichromatic model).
.. [3] Iordache, M.-D., Bioucas-Dias, J. M., Plaza, A. (2011). Sparse unmixing of
   hyperspectral data. IEEE Transactions on Geoscience and Remote Sensing 49(6) (choosing
   few endmembers of a library per pixel).
.. [4] Schwarz, G. (1978). Estimating the dimension of a model. The Annals of Statistics
   6(2) (a penalty per parameter).
.. [5] Lawson, C. L., Hanson, R. J. (1974). Solving Least Squares Problems (NNLS: the
   active set of the solution is one of the subsets enumerated here).
.. [6] Buades, A., Coll, B., Morel, J.-M. (2005). A non-local algorithm for image
   denoising. CVPR (weights from the similarity of whole patches; here, of a texel's RGB in
   all images of the set).
"""

from __future__ import annotations

from collections.abc import Iterator
from itertools import combinations

import numpy as np

from spectralize.schemas import ParameterError, ReconstructionError

from ..inputs import ReconstructionInputs
from .endmember_mixture import (
    DEFAULT_ENDMEMBERS,
    Endmembers,
    _project,
    band_noise_sigma,
    rgb_abundances,
    set_endmembers,
)

__all__ = [
    "sparse_choice",
    "dichromatic_candidates",
    "support_costs",
    "rgb_similar_neighbours",
    "neighbour_candidates",
    "DEFAULT_CHOICE_CANDIDATES",
    "DEFAULT_MAX_SUPPORT",
    "DEFAULT_SUPPORT_PENALTY",
]

DEFAULT_CHOICE_CANDIDATES = 6
"""Endmembers a texel may choose from besides the highlight atom."""

DEFAULT_MAX_SUPPORT = 3
"""Atoms a texel mixes at most (RGB has three equations per image)."""

DEFAULT_SUPPORT_PENALTY = 30.0
"""Cost per atom of a support, in units of chi^2."""

DEFAULT_CONTEXT_RADIUS = 2
"""Half-width of the window a texel's RGB-similar neighbours come from."""

DEFAULT_CONTEXT_BANDWIDTH = 30.0
"""Non-local means' bandwidth of the neighbours' weights, in units of the RGB distance (the
RGB misfit per value in units of its noise and model error: neighbours of one material in
different fractions or shading are tens of units apart)."""


DEFAULT_CANDIDATE_PENALTY = 100.0
"""Further cost of an endmember a texel's neighbours offered, in units of chi^2."""

CONTEXT_TERMS = ("band", "rgb+band", "band-sum", "none")
"""What a texel's support costs pool from its neighbours."""

RGB_NOISE = 0.004
"""Relative noise of an HDR-merged RGB value."""

RGB_FLOOR = 2e-4
"""Noise floor of the RGB, relative to the set's bright (99th percentile) RGB."""


def _cameras(inputs: ReconstructionInputs) -> np.ndarray:
    """``C_m`` per image, ``(n_image, 3, n_wavelength)``."""
    c = np.asarray(inputs.camera_matrix, dtype=np.float64)
    return np.broadcast_to(c, (inputs.n_image, *c.shape)) if c.ndim == 2 else c


def _rgb_variance(rgb: np.ndarray, model_error: float) -> np.ndarray:
    """Per image and texel the variance of an RGB channel, ``(n_image, n_texel)``: the
    relative noise and model error and a floor."""
    relative = RGB_NOISE**2 + model_error**2
    floor = RGB_FLOOR * np.percentile(rgb.reshape(-1, 3), 99.0, axis=0)
    return np.mean(relative * rgb**2 + floor**2, axis=-1)


def dichromatic_candidates(
    atoms_rgb: np.ndarray, rgb: np.ndarray, variance: np.ndarray, count: int
) -> np.ndarray:
    """Step 1: per texel the ``count`` endmembers whose dichromatic fits over the images have
    the lowest summed chi^2, then the highlight atom (the last); ``(n_texel, count + 1)``.

    ``atoms_rgb`` ``(n_image, n_atoms, 3)``: every atom's RGB through each image's camera;
    ``rgb`` ``(n_image, n_texel, 3)``; ``variance`` ``(n_image, n_texel)``. The fits run in
    one compiled pass (:func:`~..kernels.dichromatic_costs`).
    """
    from ..kernels import dichromatic_costs

    n_atoms = atoms_rgb.shape[1]
    cost = np.zeros((n_atoms - 1, rgb.shape[1]))
    dichromatic_costs(
        np.ascontiguousarray(atoms_rgb[:, :-1], dtype=np.float64),
        np.ascontiguousarray(atoms_rgb[:, -1], dtype=np.float64),
        np.ascontiguousarray(rgb, dtype=np.float64),
        np.ascontiguousarray(variance, dtype=np.float64),
        cost,
    )
    count = min(int(count), n_atoms - 1)
    near = np.argsort(cost, axis=0, kind="stable")[:count].T
    return np.hstack([near, np.full((near.shape[0], 1), n_atoms - 1)])


def _subsets(n_candidates: int, max_size: int) -> tuple[list[tuple[int, ...]], list[list[int]]]:
    """The non-empty subsets of at most ``max_size`` candidate positions (by size), and for
    each the indices of its subsets one smaller (-1: the empty set)."""
    subsets = [s for r in range(1, max_size + 1) for s in combinations(range(n_candidates), r)]
    index = {s: i for i, s in enumerate(subsets)}
    children = [
        [-1] if len(s) == 1 else [index[c] for c in combinations(s, len(s) - 1)] for s in subsets
    ]
    return subsets, children


def _image_costs(
    g: np.ndarray,
    spectra: np.ndarray,
    r: np.ndarray,
    variance: np.ndarray,
    shots: np.ndarray,
    shot_variance: np.ndarray,
    bands: np.ndarray,
    band_model_error: float,
    subsets: list[tuple[int, ...]],
    children: list[list[int]],
) -> tuple[np.ndarray, np.ndarray]:
    """One image's rgb and band cost of every support, ``(n_subset, n_texel)`` each: the
    exact NNLS over the support's sub-supports (the best feasible one by RGB)."""
    n_subset, n_texel = len(subsets), r.shape[0]
    rgb_cost = np.empty((n_subset, n_texel))
    band_cost = np.empty((n_subset, n_texel))
    empty_rgb = (r * r).sum(-1) / variance
    empty_band = (shots**2 / shot_variance).sum(-1)
    for s, (subset, below) in enumerate(zip(subsets, children, strict=True)):
        a = g[:, list(subset), :]  # (texel, size, 3)
        gram = a @ np.swapaxes(a, 1, 2)
        gram += (1e-12 * np.trace(gram, axis1=1, axis2=2)[:, None, None] + 1e-300) * np.eye(len(subset))
        w = np.linalg.solve(gram, np.einsum("prc,pc->pr", a, r)[..., None])[..., 0]
        residual = r - np.einsum("pr,prc->pc", w, a)
        own_rgb = np.where((w >= 0).all(-1), (residual * residual).sum(-1) / variance, np.inf)
        predicted = np.einsum("pr,prk->pk", w, spectra[:, list(subset)][:, :, bands])
        spread = shot_variance[None] + (band_model_error * predicted) ** 2
        own_band = ((predicted - shots) ** 2 / spread).sum(-1)
        for child in below:
            other_rgb = empty_rgb if child < 0 else rgb_cost[child]
            other_band = empty_band if child < 0 else band_cost[child]
            take = other_rgb < own_rgb
            own_rgb = np.where(take, other_rgb, own_rgb)
            own_band = np.where(take, other_band, own_band)
        rgb_cost[s], band_cost[s] = own_rgb, own_band
    return rgb_cost, band_cost


def support_costs(
    inputs: ReconstructionInputs,
    atoms: np.ndarray,
    candidates: np.ndarray,
    *,
    max_support: int = DEFAULT_MAX_SUPPORT,
    rgb_model_error: float = 0.03,
    band_model_error: float = 0.1,
) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """Step 2: ``rgb_cost + band_cost`` of every support of each texel's ``candidates``,
    summed over the set's images, ``(n_subset, n_texel)``, and the supports (tuples of
    positions in ``candidates``).

    The fits of every texel, image and support run in one compiled pass
    (:func:`~..kernels.support_costs_pixels`), the same fits as :func:`_image_costs` (which
    the pooled costs of :func:`_context_costs` use) without its temporaries."""
    evidence = _Evidence.of(inputs, rgb_model_error)
    return _support_costs(evidence, inputs, atoms, candidates, int(max_support), band_model_error)


def _support_costs(
    evidence: _Evidence,
    inputs: ReconstructionInputs,
    atoms: np.ndarray,
    candidates: np.ndarray,
    max_support: int,
    band_model_error: float,
) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """:func:`support_costs` on the set's ``evidence`` (:meth:`_Evidence.of`)."""
    from ..kernels import support_costs_pixels

    subsets, children = _subsets(candidates.shape[1], int(max_support))
    size = max(len(s) for s in subsets)
    positions = np.array([list(s) + [0] * (size - len(s)) for s in subsets], dtype=np.int64)
    below = np.array([c + [-1] * (size - len(c)) for c in children], dtype=np.int64)
    cameras = _cameras(inputs)
    atoms = np.ascontiguousarray(atoms, dtype=np.float64)
    images, bands = np.asarray(inputs.image), np.asarray(inputs.band, dtype=np.int64)
    order = np.argsort(images, kind="stable").astype(np.int64)
    start = np.searchsorted(images[order], np.arange(inputs.n_image + 1)).astype(np.int64)
    total = np.zeros((len(subsets), candidates.shape[0]))
    support_costs_pixels(
        np.stack([atoms @ cameras[m].T for m in range(inputs.n_image)]),
        atoms,
        np.ascontiguousarray(candidates, dtype=np.int64),
        positions,
        np.array([len(s) for s in subsets], dtype=np.int64),
        below,
        np.ascontiguousarray(evidence.rgb),
        np.ascontiguousarray(evidence.variance),
        np.ascontiguousarray(evidence.shots),
        np.ascontiguousarray(evidence.shot_variance, dtype=np.float64),
        bands,
        start,
        order,
        float(band_model_error),
        total,
    )
    return total, subsets


class _Evidence:
    """A set's RGB ``(n_image, n_texel, 3)`` with its variance ``(n_image, n_texel)``, and its
    band shots ``(n_shot, n_texel)`` with their noise variance ``(n_shot,)``: what a texel's
    supports are scored on (its own, or a neighbour's: :meth:`at`)."""

    def __init__(
        self, rgb: np.ndarray, variance: np.ndarray, shots: np.ndarray, shot_variance: np.ndarray
    ):
        self.rgb, self.variance, self.shots, self.shot_variance = rgb, variance, shots, shot_variance

    @classmethod
    def of(cls, inputs: ReconstructionInputs, rgb_model_error: float) -> _Evidence:
        rgb = inputs.rgb.reshape(inputs.n_image, -1, 3).astype(np.float64)
        shots = inputs.band_data.reshape(inputs.band_data.shape[0], -1).astype(np.float64)
        sigma = band_noise_sigma(inputs)
        return cls(rgb, _rgb_variance(rgb, rgb_model_error), shots, sigma**2)

    def at(self, texels: np.ndarray) -> _Evidence:
        """The evidence of ``texels`` (one per texel): each texel's supports scored on them."""
        return _Evidence(
            self.rgb[:, texels], self.variance[:, texels], self.shots[:, texels], self.shot_variance
        )

    def image_costs(
        self,
        inputs: ReconstructionInputs,
        atoms: np.ndarray,
        candidates: np.ndarray,
        subsets: list[tuple[int, ...]],
        children: list[list[int]],
        band_model_error: float,
    ) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Per image its rgb and band cost of every support, ``(n_subset, n_texel)`` each."""
        cameras = _cameras(inputs)
        spectra = atoms[candidates]  # (texel, n_candidates, w)
        images, bands = np.asarray(inputs.image), np.asarray(inputs.band)
        for m in range(inputs.n_image):
            mine = np.flatnonzero(images == m)
            yield _image_costs(
                (atoms @ cameras[m].T)[candidates],
                spectra,
                self.rgb[m],
                self.variance[m],
                self.shots[mine].T,
                self.shot_variance[mine],
                bands[mine],
                band_model_error,
                subsets,
                children,
            )


def rgb_similar_neighbours(
    rgb: np.ndarray, variance: np.ndarray, height: int, width: int, count: int, radius: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per texel the ``count`` texels of its ``(2 radius + 1)^2`` window whose RGB over all
    the set's images is nearest, ``(n_texel, count)`` indices, and their distances
    ``d_pq = mean_(m, c) (R_pmc - R_qmc)^2 / (var_pm + var_qm)`` (the RGB misfit per value in
    units of its noise and model error; ``inf`` where the window has fewer texels).

    ``rgb`` ``(n_image, n_texel, 3)`` and ``variance`` ``(n_image, n_texel)``, texels in
    row-major ``(height, width)`` order. The distance over the stacked images is the
    non-local means' patch distance with the set's images as the patch: two texels of the same
    materials in the same fractions agree in every image, whatever each image's light, while
    an RGB edge between them shows in the images that light it.
    """
    r = rgb.reshape(rgb.shape[0], height, width, 3)
    v = variance.reshape(variance.shape[0], height, width)
    offsets = [
        (dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1) if dy or dx
    ]
    grid = np.full((len(offsets), height, width), np.inf)
    for o, (dy, dx) in enumerate(offsets):
        here = (slice(max(-dy, 0), height - max(dy, 0)), slice(max(-dx, 0), width - max(dx, 0)))
        there = (slice(max(dy, 0), height + min(dy, 0)), slice(max(dx, 0), width + min(dx, 0)))
        misfit = ((r[:, here[0], here[1]] - r[:, there[0], there[1]]) ** 2).mean(-1)
        grid[o][here] = (misfit / (v[:, here[0], here[1]] + v[:, there[0], there[1]])).mean(0)
    distance = grid.reshape(len(offsets), -1)
    count = min(int(count), len(offsets))
    nearest = np.argsort(distance, axis=0, kind="stable")[:count].T  # (texel, count)
    step = np.array([dy * width + dx for dy, dx in offsets])
    texel = np.arange(height * width)[:, None]
    found = np.take_along_axis(distance.T, nearest, axis=1)
    index = np.where(np.isfinite(found), texel + step[nearest], texel)
    return index, found


def _context_costs(
    evidence: _Evidence,
    inputs: ReconstructionInputs,
    atoms: np.ndarray,
    candidates: np.ndarray,
    max_support: int,
    band_model_error: float,
    index: np.ndarray,
    weight: np.ndarray,
    terms: str,
) -> tuple[np.ndarray, list[tuple[int, ...]]]:
    """Step 2 with context: each texel's support costs pooled with the same supports' costs
    on its RGB-similar neighbours ``index`` ``(n_texel, n_neighbour)``
    (:func:`rgb_similar_neighbours`), each weighted ``w_pq`` (``weight``, non-local means'
    ``exp(-d_pq / bandwidth)``), ``(n_subset, n_texel)``.

    A neighbour's cost of ``T`` is its own images' fit on ``T`` (its own abundances per
    image): the hypothesis that it holds the same materials, in any fractions. The pooled
    cost is the weighted mean ``(c_p + sum_q w_pq c_q) / (1 + sum_q w_pq)`` of the band chi^2
    (``terms="band"``; the texel's own RGB cost is added unpooled) or of both chi^2
    (``"rgb+band"``), so the penalty per atom keeps its scale; ``"band-sum"`` adds the
    neighbours' band chi^2 to the texel's own cost unnormalised (the neighbours' shots as
    more evidence of the texel's materials, weighing the bands more against the RGB);
    ``"none"`` keeps the texel's own costs (the neighbours only offer candidates:
    :func:`neighbour_candidates`).
    """
    subsets, children = _subsets(candidates.shape[1], int(max_support))

    def summed(where: _Evidence) -> tuple[np.ndarray, np.ndarray]:
        rgb_total = np.zeros((len(subsets), candidates.shape[0]))
        band_total = np.zeros_like(rgb_total)
        for rgb_cost, band_cost in where.image_costs(
            inputs, atoms, candidates, subsets, children, band_model_error
        ):
            rgb_total += rgb_cost
            band_total += band_cost
        return rgb_total, band_total

    own_rgb, own_band = summed(evidence)
    if terms == "none":
        return own_rgb + own_band, subsets
    pooled_rgb, pooled_band, total_weight = own_rgb.copy(), own_band.copy(), np.ones(candidates.shape[0])
    for k in range(index.shape[1]):
        rgb_cost, band_cost = summed(evidence.at(index[:, k]))
        pooled_rgb += weight[:, k] * rgb_cost
        pooled_band += weight[:, k] * band_cost
        total_weight += weight[:, k]
    if terms == "band":
        return own_rgb + pooled_band / total_weight, subsets
    if terms == "band-sum":
        return own_rgb + pooled_band, subsets
    return (pooled_rgb + pooled_band) / total_weight, subsets


def neighbour_candidates(
    ranked: np.ndarray,
    count: int,
    support: np.ndarray,
    index: np.ndarray,
    weight: np.ndarray,
    extra: int,
    *,
    min_weight: float = 0.0,
    fill: bool = True,
) -> np.ndarray:
    """Each texel's ``count`` own candidates, then ``extra`` endmembers its RGB-similar
    neighbours chose, then the highlight atom, ``(n_texel, count + extra + 1)``.

    ``ranked`` ``(n_texel, count + extra + 1)``: the dichromatic ranking
    (:func:`dichromatic_candidates` of ``count + extra``); ``support`` the choice of a first
    pass; ``index``, ``weight`` the neighbours and their weights. The endmembers the
    neighbours chose, weighted, rank the extra candidates (an atom a texel misses by its own
    RGB, such as a thin material whose colour its neighbours show better); where the
    neighbours offer fewer, the texel's own next-ranked endmembers fill the places.
    ``min_weight``: neighbours of less weight offer nothing; ``fill=False``: places left
    over repeat the texel's first candidate (a repeated atom adds no support) instead.
    """
    n_texel, light = ranked.shape[0], int(ranked[0, -1])
    rows = np.arange(n_texel)[:, None]
    score = np.zeros((n_texel, light + 1))
    for k in range(index.shape[1]):
        theirs = support[index[:, k]]
        for s in range(theirs.shape[1]):
            new = (theirs[:, s : s + 1] != theirs[:, :s]).all(axis=1)
            similar = new & (weight[:, k] >= min_weight)
            score[rows[:, 0], theirs[:, s]] += np.where(similar, weight[:, k], 0.0)
    spare = ranked[:, count:-1]
    if fill:
        tiny = 1e-200 * (spare.shape[1] - np.arange(spare.shape[1]))
        score[rows, spare] = np.maximum(score[rows, spare], tiny)
    score[rows, ranked[:, :count]] = -np.inf
    score[:, light] = -np.inf
    order = np.argsort(-score, axis=1, kind="stable")[:, :extra]
    offered = np.take_along_axis(score, order, axis=1) > 0
    picked = np.where(offered, order, ranked[:, :1])
    return np.hstack([ranked[:, :count], picked, ranked[:, -1:]])


def _choose(
    candidates: np.ndarray,
    costs: tuple[np.ndarray, list[tuple[int, ...]]],
    penalty: float,
    max_support: int,
    borrowed: tuple[range, float] = (range(0), 0.0),
) -> np.ndarray:
    """Step 3: each texel's support of least cost plus penalty (:func:`_chosen_support`);
    ``borrowed``: the candidate positions a texel's neighbours offered and the further cost
    of each in a support."""
    cost, subsets = costs
    size = np.array([len(s) for s in subsets], dtype=np.float64)
    total = cost + float(penalty) * size[:, None]
    if borrowed[1]:
        lent = np.array([sum(p in borrowed[0] for p in s) for s in subsets], dtype=np.float64)
        total = total + borrowed[1] * lent[:, None]
    choice = np.argmin(total, axis=0)
    return _chosen_support(candidates, subsets, choice, max_support)


def _chosen_support(
    candidates: np.ndarray, subsets: list[tuple[int, ...]], choice: np.ndarray, max_support: int
) -> np.ndarray:
    """``(n_texel, max_support)`` atom indices of each texel's chosen support, short supports
    padded with their first atom (a repeated atom splits its weight; the mixture is the same)."""
    support = np.empty((candidates.shape[0], max_support), dtype=np.int64)
    for s, subset in enumerate(subsets):
        here = np.flatnonzero(choice == s)
        if here.size:
            positions = list(subset) + [subset[0]] * (max_support - len(subset))
            support[here] = candidates[here][:, positions]
    return support


def _library(inputs: ReconstructionInputs, endmembers: Endmembers | None, **learn) -> np.ndarray:
    """The atoms to choose from, the highlight atom last (its shape the illuminant's where
    the inputs carry one)."""
    if endmembers is None:
        endmembers = set_endmembers(inputs, **learn)
    elif endmembers.atoms.shape[1] != inputs.n_wavelength:
        raise ReconstructionError(
            f"endmembers: expected atoms on the bands' {inputs.n_wavelength} wavelengths, "
            f"found {endmembers.atoms.shape[1]}"
        )
    atoms = np.array(endmembers.atoms, dtype=np.float64)
    if inputs.illuminant is not None:
        light = np.asarray(inputs.illuminant, dtype=np.float64)
        atoms[-1] = light * float(atoms[-1] @ light) / max(float(light @ light), 1e-300)
    return atoms


def sparse_choice(
    inputs: ReconstructionInputs,
    *,
    endmembers: Endmembers | None = None,
    n_endmembers: int = DEFAULT_ENDMEMBERS,
    candidates: int = DEFAULT_CHOICE_CANDIDATES,
    max_support: int = DEFAULT_MAX_SUPPORT,
    penalty: float = DEFAULT_SUPPORT_PENALTY,
    rgb_model_error: float = 0.03,
    band_model_error: float = 0.1,
    context: int = 0,
    context_radius: int = DEFAULT_CONTEXT_RADIUS,
    context_bandwidth: float = DEFAULT_CONTEXT_BANDWIDTH,
    context_terms: str = "band-sum",
    context_candidates: int = 0,
    context_candidate_penalty: float = DEFAULT_CANDIDATE_PENALTY,
    seed: int = 0,
) -> np.ndarray:
    """Spectra of a set whose texels choose their materials over all images (module docstring).

    Parameters
    ----------
    inputs
        The checked input arrays of a set (or one image), its images on one texel grid.
    endmembers
        The library to choose from (e.g. the run's, :mod:`~..endmember_library`); None: the
        set's own (:func:`~.endmember_mixture.set_endmembers` with ``n_endmembers`` and
        ``seed``).
    n_endmembers
        ``J`` of a library learnt here.
    candidates
        Endmembers per texel chosen by the dichromatic fits (step 1), besides the highlight.
    max_support
        Atoms a texel mixes at most (step 2).
    penalty
        Cost per atom of a support (step 3), in chi^2 units.
    rgb_model_error, band_model_error
        Relative errors of the library's spectra added to the RGB and band noise.
    context
        RGB-similar neighbours whose evidence each texel's support costs pool (0: none, the
        texel's own evidence only): the ``context`` texels of its window nearest in RGB over
        all images (:func:`rgb_similar_neighbours`, :func:`_context_costs`).
    context_radius
        Half-width of the window the neighbours come from.
    context_bandwidth
        Non-local means' bandwidth: a neighbour at RGB distance ``d`` weighs ``exp(-d /
        context_bandwidth)``.
    context_terms
        What the neighbours' costs add: ``"band"`` (their band chi^2, averaged with the
        texel's), ``"rgb+band"`` (both chi^2, averaged), ``"band-sum"`` (their band chi^2,
        summed onto the texel's cost) or ``"none"`` (nothing: with ``context_candidates``
        the neighbours only offer candidates).
    context_candidates
        Endmembers added to each texel's candidates from the supports its RGB-similar
        neighbours chose in a first pass (:func:`neighbour_candidates`), then chosen again;
        needs ``context``.
    context_candidate_penalty
        Further cost, in chi^2 units, of each such borrowed endmember in a support: the
        texel's own evidence must favour it clearly over its own candidates.
    seed
        Seed of a library learnt here.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``, float64, ``>= 0``.

    Raises
    ------
    ReconstructionError
        For ``endmembers`` on other wavelengths than the bands', or settings out of range.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1's RGB term).
    .. [2] Iordache, Bioucas-Dias and Plaza (2011), Sparse unmixing of hyperspectral data.
    .. [3] Buades, Coll and Morel (2005), A non-local algorithm for image denoising
       (``context``).
    """
    if int(candidates) < 1 or not 1 <= int(max_support) <= int(candidates) + 1 or penalty < 0:
        raise ReconstructionError(
            "sparse-choice: expected candidates >= 1, 1 <= max_support <= candidates + 1 and "
            f"penalty >= 0, found {candidates}, {max_support}, {penalty}"
        )
    if (
        int(context) < 0
        or int(context_radius) < 1
        or context_bandwidth <= 0
        or context_candidate_penalty < 0
        or int(context_candidates) < 0
        or (int(context_candidates) > 0 and int(context) == 0)
    ):
        raise ReconstructionError(
            "sparse-choice: expected context >= 0, context_radius >= 1, context_bandwidth > 0, "
            "context_candidates >= 0 (> 0 only with context) and context_candidate_penalty >= 0, "
            f"found {context}, {context_radius}, {context_bandwidth}, {context_candidates}, "
            f"{context_candidate_penalty}"
        )
    if context_terms not in CONTEXT_TERMS:
        raise ParameterError.single("context_terms", f"one of {CONTEXT_TERMS}", repr(context_terms))
    atoms = _library(inputs, endmembers, n_endmembers=int(n_endmembers), seed=int(seed))
    cameras = _cameras(inputs)
    evidence = _Evidence.of(inputs, rgb_model_error)
    rgb, variance = evidence.rgb, evidence.variance
    atoms_rgb = np.einsum("aw,mcw->mac", atoms, cameras)
    if int(context) > 0:
        index, distance = rgb_similar_neighbours(
            evidence.rgb, evidence.variance, inputs.height, inputs.width, context, context_radius
        )
        weight = np.exp(-distance / float(context_bandwidth))
        own = min(int(candidates), atoms.shape[0] - 1)
        extra = min(int(context_candidates), atoms.shape[0] - 1 - own)
        ranked = dichromatic_candidates(atoms_rgb, rgb, variance, own + extra)
        near = np.hstack([ranked[:, :own], ranked[:, -1:]])
        setting = (int(max_support), float(band_model_error))
        pooled = _context_costs(evidence, inputs, atoms, near, *setting, index, weight, context_terms)
        support = _choose(near, pooled, penalty, int(max_support))
        if extra:
            near = neighbour_candidates(ranked, own, support, index, weight, extra)
            pooled = _context_costs(
                evidence, inputs, atoms, near, *setting, index, weight, context_terms
            )
            lent = (range(own, own + extra), float(context_candidate_penalty))
            support = _choose(near, pooled, penalty, int(max_support), lent)
    else:
        near = dichromatic_candidates(atoms_rgb, rgb, variance, candidates)
        costs = _support_costs(evidence, inputs, atoms, near, int(max_support), float(band_model_error))
        support = _choose(near, costs, penalty, int(max_support))
    library = Endmembers(atoms, np.zeros((atoms.shape[0] - 1, 2)), np.ones(3))
    per_image = np.tile(support, (inputs.n_image, 1))
    weights = rgb_abundances(library, per_image, inputs.camera_matrix, rgb.reshape(-1, 3))
    from ..kernels import mix_atoms

    cube = np.empty((inputs.n_wavelength, per_image.shape[0]))
    mix_atoms(weights, per_image, np.ascontiguousarray(atoms), cube)
    return _project(cube.reshape(inputs.cube_shape), inputs)
