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
3. **Choice**: ``argmin_T rgb_cost + band_cost + penalty |T|``. Four atoms fit three RGB
   equations in many ways; the size penalty keeps the sparsest support that the evidence
   allows (the Bayesian information criterion's form).
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
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from spectralize.schemas import ReconstructionError

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
    ``rgb`` ``(n_image, n_texel, 3)``; ``variance`` ``(n_image, n_texel)``.
    """
    n_atoms = atoms_rgb.shape[1]
    cost = np.zeros((n_atoms - 1, rgb.shape[1]))
    for m in range(rgb.shape[0]):
        light = atoms_rgb[m, -1]
        r = rgb[m]
        one_light = np.maximum(r @ light / max(float(light @ light), 1e-300), 0.0)
        light_only = ((r - one_light[:, None] * light) ** 2).sum(-1)
        for j in range(n_atoms - 1):
            e = atoms_rgb[m, j]
            pair = np.stack([e, light])
            gram = pair @ pair.T
            gram += (1e-12 * np.trace(gram) + 1e-300) * np.eye(2)
            w = (r @ pair.T) @ np.linalg.inv(gram)
            both = ((r - w @ pair) ** 2).sum(-1)
            alone = np.maximum(r @ e / max(float(e @ e), 1e-300), 0.0)
            material_only = ((r - alone[:, None] * e) ** 2).sum(-1)
            best = np.where((w >= 0).all(-1), both, np.minimum(material_only, light_only))
            cost[j] += best / variance[m]
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
    positions in ``candidates``)."""
    cameras = _cameras(inputs)
    rgb = inputs.rgb.reshape(inputs.n_image, -1, 3).astype(np.float64)
    variance = _rgb_variance(rgb, rgb_model_error)
    sigma = band_noise_sigma(inputs)
    subsets, children = _subsets(candidates.shape[1], int(max_support))
    total = np.zeros((len(subsets), rgb.shape[1]))
    spectra = atoms[candidates]  # (texel, n_candidates, w)
    for m in range(inputs.n_image):
        mine = np.flatnonzero(np.asarray(inputs.image) == m)
        shots = inputs.band_data[mine].reshape(len(mine), rgb.shape[1]).T.astype(np.float64)
        g = (atoms @ cameras[m].T)[candidates]
        rgb_cost, band_cost = _image_costs(
            g,
            spectra,
            rgb[m],
            variance[m],
            shots,
            sigma[mine] ** 2,
            np.asarray(inputs.band)[mine],
            float(band_model_error),
            subsets,
            children,
        )
        total += rgb_cost + band_cost
    return total, subsets


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
    """
    if int(candidates) < 1 or not 1 <= int(max_support) <= int(candidates) + 1 or penalty < 0:
        raise ReconstructionError(
            "sparse-choice: expected candidates >= 1, 1 <= max_support <= candidates + 1 and "
            f"penalty >= 0, found {candidates}, {max_support}, {penalty}"
        )
    atoms = _library(inputs, endmembers, n_endmembers=int(n_endmembers), seed=int(seed))
    cameras = _cameras(inputs)
    rgb = inputs.rgb.reshape(inputs.n_image, -1, 3).astype(np.float64)
    atoms_rgb = np.einsum("aw,mcw->mac", atoms, cameras)
    near = dichromatic_candidates(atoms_rgb, rgb, _rgb_variance(rgb, rgb_model_error), candidates)
    cost, subsets = support_costs(
        inputs,
        atoms,
        near,
        max_support=int(max_support),
        rgb_model_error=rgb_model_error,
        band_model_error=band_model_error,
    )
    size = np.array([len(s) for s in subsets], dtype=np.float64)
    choice = np.argmin(cost + float(penalty) * size[:, None], axis=0)
    support = _chosen_support(near, subsets, choice, int(max_support))
    library = Endmembers(atoms, np.zeros((atoms.shape[0] - 1, 2)), np.ones(3))
    per_image = np.tile(support, (inputs.n_image, 1))
    weights = rgb_abundances(library, per_image, inputs.camera_matrix, rgb.reshape(-1, 3))
    from ..kernels import mix_atoms

    cube = np.empty((inputs.n_wavelength, per_image.shape[0]))
    mix_atoms(weights, per_image, np.ascontiguousarray(atoms), cube)
    return _project(cube.reshape(inputs.cube_shape), inputs)
