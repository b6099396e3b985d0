"""Estimator ``"endmember-mixture"``: every pixel a non-negative mixture of a few of the
scene's own spectra, learnt from the noisy bands of all pixels at once.

The physics: a camera pixel integrates the materials under it, lit by one illuminant
``L``, plus a highlight that has the illuminant's spectrum (the dichromatic reflection
model). So a pixel's spectrum is a non-negative combination of a few *endmember* spectra
``E_j = L rho_j`` and of ``L`` itself:

``S(p) = sum_j w_j(p) E_j``,  ``w(p) >= 0``, few ``j`` per pixel.

Three endmembers are pinned down by the (good, HDR) RGB alone, ``C E w = R``; what RGB
cannot tell, the endmembers' spectra, is learnt from the band shots of *all* pixels
together, where the noise of single pixels (band SNR at or below 1) averages out:

1. **Endmembers**: k-means on the pixels' chromaticity (channel-balanced RGB, brightness
   divided out, so shading does not split a material) over the pixels between 0.2 x the
   median and the 90th percentile of brightness (the darkest have noisy chromaticity, the
   brightest are highlights); every pixel joins its nearest cluster, and per cluster the
   spectrum per unit brightness is the pooled least squares ``D_b(p) ~ b_p g_b``; one
   more atom for the highlights, pooled over the brightest 1 % of pixels.
2. **Abundances**: per pixel, non-negative least squares ``min ||C E_K w - R(p)||`` over the
   ``K`` endmembers nearest in chromaticity and the highlight atom, solved exactly for all
   pixels at once by enumerating the subsets of these ``K + 1`` atoms.
2b. **Materials around**: after the last round below, each pixel also gets the endmembers
   most abundant in its neighbourhood as candidates, and step 2 is solved once more
   (:func:`neighbourhood_candidates`).
3. **Dictionary update**: per band, the endmembers that best explain every pixel's band
   value with those abundances (a ``J x J`` ridge regression over all pixels shot in that
   band, held towards the previous atoms); then 2 again. A few rounds.
4. The mixture, projected per pixel onto ``C S = R`` and onto ``S >= 0`` (alternately).
5. A local correction from the band shots where they disagree with the mixture by more
   than their noise (:func:`local_correction`: highlights, materials the dictionary
   lacks) at two scales, projected again.

In a set, images share the endmembers (the same materials under other light and view), so
an image without band shots gets spectra from the bands of the others through its RGB.
The estimate is the centre and the covariance source of the preset ``"mixture-prior-pcg"``
(:mod:`~..solvers.prior_pcg`), which then adds eq. 1's filter and neighbour terms.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 ("Hybrid Methods") and 3.
.. [2] Shafer, S. A. (1985). Using color to separate reflection components. Color Research
   and Application 10(4) (the dichromatic model: highlights have the illuminant's colour).
.. [3] Keshava, N., Mustard, J. F. (2002). Spectral unmixing. IEEE Signal Processing
   Magazine 19(1) (the linear mixing model, endmembers and non-negative abundances).
.. [4] Lawson, C. L., Hanson, R. J. (1974). Solving Least Squares Problems (NNLS: the
   active set of the solution is one of the subsets enumerated here).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from spectralize.schemas import ReconstructionError

from ..baselines.projection import project_onto_rgb
from ..inputs import ReconstructionInputs

__all__ = [
    "endmember_mixture",
    "Endmembers",
    "set_endmembers",
    "sample_stride",
    "learn_endmembers",
    "rgb_abundances",
    "chromaticity",
    "local_correction",
    "neighbourhood_candidates",
    "band_noise_sigma",
    "DEFAULT_ENDMEMBERS",
    "DEFAULT_CANDIDATES",
    "DEFAULT_ROUNDS",
    "DEFAULT_SPATIAL_CANDIDATES",
]

DEFAULT_ENDMEMBERS = 32
"""``J``: endmembers learnt per scene (clusters of chromaticity), besides the highlight atom."""

DEFAULT_CANDIDATES = 3
"""``K``: endmembers nearest in chromaticity each pixel may mix (plus the highlight atom);
RGB determines at most three weights."""

DEFAULT_SPATIAL_CANDIDATES = 2
"""Endmembers most abundant around a pixel added to its candidates (step 2b)."""

NEIGHBOURHOOD_SIGMA = 1.5
"""Gaussian ``sigma`` [px] of the abundance-share maps of step 2b."""

DEFAULT_ROUNDS = 4
"""Abundance / dictionary rounds."""

DICTIONARY_RIDGE = 0.1
"""Ridge of the dictionary update towards the previous atoms, relative to the mean
diagonal of the abundances' Gram matrix (endmembers of similar colour have nearly
collinear abundances; without it their spectra fit the band noise)."""

CLUSTER_BRIGHTNESS = (0.2, 90.0)
"""Pixels clustered: brightness above this fraction of the median and below this
percentile."""

HIGHLIGHT_PERCENTILE = 99.0
"""The highlight atom is pooled over the pixels brighter than this percentile."""

LOCAL_WINDOW_SCALE = 3.0
"""Window of the local correction's guided filter, in units of the shot's filter ``sigma``
(as the ``"guided-projected"`` baseline)."""

LOCAL_DETAIL_SCALE = 1.0
"""Window of the local correction's detail layer (the same guided filter, finer), in units
of the shot's filter ``sigma``; see :func:`local_correction`."""

LOCAL_DETAIL_THRESHOLD = 5.0
"""``lambda`` of the detail layer's shrinkage ``max(0, 1 - lambda <v> / <d^2>)``: keeps a
detail only where its local power is several times its noise's (with ``lambda = 1`` the
windows' own scatter lets noise through); chosen on the hard scenes of
``benchmarks/reconstruction.py``."""

PROJECTION_ROUNDS = 5
"""Alternating projections onto ``C S = R`` and ``S >= 0``."""

_PIXELS_PER_ENDMEMBER = 256
"""At least this many clustered pixels per endmember (fewer endmembers on small images: an
endmember pooled over fewer pixels carries their band noise)."""

_SAMPLE = 20000
"""Pixels the k-means sees at most (a strided, seeded sample)."""


def chromaticity(
    rgb_pixels: np.ndarray, scale: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Brightness and chromaticity of RGB pixels ``(n, 3)``.

    Each channel is divided by ``scale`` (default: its mean over the pixels) so the three
    weigh alike; brightness ``b`` is the sum of the balanced channels, chromaticity its
    first two shares, clipped to ``[0, 1]``. Shading scales ``b`` and leaves the
    chromaticity alone.

    Returns
    -------
    brightness, chroma
        ``(n,)`` and ``(n, 2)``, float64.
    """
    rgb = np.asarray(rgb_pixels, dtype=np.float64)
    if scale is None:
        scale = np.abs(rgb.mean(axis=0))
    balanced = rgb / np.maximum(scale, 1e-300)
    brightness = balanced.sum(axis=1)
    floor = 1e-6 * max(float(np.abs(brightness).mean()), 1e-300)
    chroma = np.clip(balanced[:, :2] / np.maximum(brightness, floor)[:, None], 0.0, 1.0)
    return brightness, chroma


@dataclass
class Endmembers:
    """The learnt dictionary: atoms ``(J + 1, n_wavelength)`` (the last one the highlight
    atom), the chromaticity centres ``(J, 2)`` of the first ``J``, and the channel scale
    ``(3,)`` of :func:`chromaticity` the centres are in (so a tile of a set finds its
    candidates in the set's chromaticity, not its own)."""

    atoms: np.ndarray
    centres: np.ndarray
    scale: np.ndarray

    @property
    def highlight(self) -> int:
        """Index of the highlight atom."""
        return self.atoms.shape[0] - 1

    def candidates(self, chroma: np.ndarray, k: int) -> np.ndarray:
        """``(n, min(k, J) + 1)``: the ``k`` atoms nearest in chromaticity (nearest first),
        and the highlight atom (one compiled pass, :func:`~..kernels.nearest_centres`)."""
        from ..kernels import nearest_centres

        k = min(k, self.centres.shape[0])
        near = np.empty((chroma.shape[0], k + 1), dtype=np.int64)
        nearest_centres(
            np.ascontiguousarray(chroma, dtype=np.float64),
            np.ascontiguousarray(self.centres, dtype=np.float64),
            k,
            near,
        )
        near[:, k] = self.highlight
        return near


def _band_shots(inputs: ReconstructionInputs) -> dict[int, list[int]]:
    shots: dict[int, list[int]] = {}
    for i, b in enumerate(inputs.band):
        shots.setdefault(int(b), []).append(i)
    return shots


def _pooled_shape(
    inputs: ReconstructionInputs, brightness: np.ndarray, label: np.ndarray, n_label: int
) -> np.ndarray:
    """Per label and band the least-squares ``g`` of ``D_b(p) ~ b_p g`` over the label's
    pixels; ``(n_label, n_wavelength)``; labels < 0 are left out, empty labels get the
    pooled shape of all pixels."""
    per_image = inputs.height * inputs.width
    num = np.zeros((n_label + 1, inputs.n_wavelength))
    den = np.zeros((n_label + 1, inputs.n_wavelength))
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
        here = slice(m * per_image, (m + 1) * per_image)
        lab = np.where(label[here] < 0, n_label, label[here])
        weight = brightness[here]
        data = inputs.band_data[i].ravel().astype(np.float64)
        num[:, b] += np.bincount(lab, weights=weight * data, minlength=n_label + 1)
        den[:, b] += np.bincount(lab, weights=weight * weight, minlength=n_label + 1)
    total = num.sum(axis=0) / np.maximum(den.sum(axis=0), 1e-300)
    shape = num[:n_label] / np.maximum(den[:n_label], 1e-300)
    empty = den[:n_label] <= 0
    shape[empty] = np.broadcast_to(total, shape.shape)[empty]
    return shape


def learn_endmembers(
    inputs: ReconstructionInputs,
    brightness: np.ndarray,
    chroma: np.ndarray,
    scale: np.ndarray,
    *,
    n_endmembers: int = DEFAULT_ENDMEMBERS,
    seed: int = 0,
) -> Endmembers:
    """Step 1 of the module docstring: chromaticity clusters and their pooled spectra.

    Parameters
    ----------
    inputs
        The checked input arrays (band shots).
    brightness, chroma
        :func:`chromaticity` of every pixel of every image, in (image, y, x) order.
    scale
        The channel scale ``brightness`` and ``chroma`` were computed with.
    n_endmembers
        ``J`` (fewer when there are few pixels: at least 256 clustered pixels each).
    seed
        Seed of the k-means initialisation and sample (deterministic result).
    """
    from scipy.cluster.vq import kmeans2

    low, high = CLUSTER_BRIGHTNESS
    keep = (brightness > low * np.median(brightness)) & (brightness < np.percentile(brightness, high))
    if keep.sum() < 16:
        keep = np.ones_like(keep)
    sample = chroma[keep]
    step = max(1, sample.shape[0] // _SAMPLE)
    sample = sample[::step]
    n = int(max(1, min(n_endmembers, sample.shape[0] // _PIXELS_PER_ENDMEMBER)))
    with warnings.catch_warnings():  # an empty cluster is handled below
        warnings.simplefilter("ignore")
        centres, _ = kmeans2(sample, n, minit="++", seed=np.random.default_rng(seed))
    label = Endmembers(np.zeros((n + 1, 1)), centres, scale).candidates(chroma, 1)[:, 0]
    atoms = _pooled_shape(inputs, brightness, label, n)
    brightest = np.where(brightness > np.percentile(brightness, HIGHLIGHT_PERCENTILE), 0, -1)
    highlight = _pooled_shape(inputs, brightness, brightest, 1)
    return Endmembers(np.vstack([atoms, highlight]), centres, scale)


ABUNDANCE_RIDGE = 1e-6
"""Ridge of the abundance solve relative to the trace of its Gram matrix: more candidates
than RGB channels leave it singular; the ridge picks the smallest weights."""


def rgb_abundances(
    endmembers: Endmembers, near: np.ndarray, camera_matrix: np.ndarray, rgb_pixels: np.ndarray
) -> np.ndarray:
    """Step 2: per pixel ``w >= 0`` minimising ``||C E_near w - R||^2`` (plus a tiny ridge,
    :data:`ABUNDANCE_RIDGE`, that keeps it unique); ``(n, K + 1)`` beside ``near``.

    ``camera_matrix`` is ``C`` ``(3, n_wavelength)``, or one ``C_m`` per image ``(n_image,
    3, n_wavelength)``: then the pixels are ``n_image`` equal runs, image by image.

    Exact NNLS by enumerating the active sets (compiled,
    :func:`~spectralize.nodes.reconstruction.kernels.mixture_abundances`): the solution is
    the unconstrained least-squares solution on its support, which is feasible, and no
    feasible one on another support has a lower objective.
    """
    from ..kernels import mixture_abundances

    c = np.asarray(camera_matrix, dtype=np.float64)
    weights = np.empty(near.shape)
    near = np.ascontiguousarray(near, dtype=np.int64)
    rgb_pixels = np.ascontiguousarray(rgb_pixels, dtype=np.float64)
    runs = [(slice(None), c)] if c.ndim == 2 else []
    if c.ndim == 3:
        per_image = rgb_pixels.shape[0] // c.shape[0]
        runs = [(slice(m * per_image, (m + 1) * per_image), c[m]) for m in range(c.shape[0])]
    for here, c_m in runs:
        projected = np.ascontiguousarray(endmembers.atoms @ c_m.T)  # (J + 1, 3): atoms' RGB
        mixture_abundances(projected, near[here], rgb_pixels[here], ABUNDANCE_RIDGE, weights[here])
    return weights


def _update_atoms(
    inputs: ReconstructionInputs, endmembers: Endmembers, near: np.ndarray, weights: np.ndarray
) -> None:
    """Step 3: per band, the atoms that best explain the band values with the abundances
    (the Gram matrix of an image's abundances serves every band shot in it)."""
    from ..kernels import mixture_gram, mixture_rhs

    atoms = endmembers.atoms
    n_atoms = atoms.shape[0]
    per_image = inputs.height * inputs.width
    near = np.ascontiguousarray(near, dtype=np.int64)
    grams: dict[int, np.ndarray] = {}
    for b, shots in _band_shots(inputs).items():
        gram = np.zeros((n_atoms, n_atoms))
        rhs = np.zeros(n_atoms)
        for i in shots:
            m = int(inputs.image[i])
            here = slice(m * per_image, (m + 1) * per_image)
            if m not in grams:
                grams[m] = np.zeros((n_atoms, n_atoms))
                mixture_gram(near[here], weights[here], grams[m])
            gram += grams[m]
            mixture_rhs(near[here], weights[here], inputs.band_data[i].ravel().astype(np.float64), rhs)
        ridge = DICTIONARY_RIDGE * max(float(np.trace(gram)) / n_atoms, 1e-300)
        atoms[:, b] = np.linalg.solve(gram + ridge * np.eye(n_atoms), rhs + ridge * atoms[:, b])


def band_noise_sigma(inputs: ReconstructionInputs) -> np.ndarray:
    """Per shot, the standard deviation of the band noise.

    From the high-pass part of the shot (the shot minus its 3 x 3 mean: white noise keeps
    8/9 of its variance there) less what the high-pass part of its RGB image explains (one
    least-squares fit per shot: fine texture, print dots and edges are in the RGB too, the
    band noise is not), by the median absolute deviation (robust to the edges that one
    linear fit leaves). The high-pass part alone takes texture for noise: it overestimates
    the noise where materials mix below a pixel.

    Computed once per inputs object (:meth:`~..inputs.ReconstructionInputs.cached`): the
    spectral prior's mixture, its band evidence and the set model each ask for it.
    """
    return inputs.cached("band_noise_sigma", _band_noise_sigma)


def _band_noise_sigma(inputs: ReconstructionInputs) -> np.ndarray:
    """:func:`band_noise_sigma`, computed."""
    from scipy import ndimage

    sigma = np.empty(len(inputs.band))
    rgb_high: dict[int, np.ndarray] = {}
    for i in range(len(inputs.band)):
        m = int(inputs.image[i])
        if m not in rgb_high:
            guide = np.moveaxis(inputs.rgb[m], -1, 0).astype(np.float64)
            high = guide - ndimage.uniform_filter(guide, (0, 3, 3), mode="reflect")
            rgb_high[m] = high.reshape(3, -1).T
        plane = inputs.band_data[i].astype(np.float64)
        high = (plane - ndimage.uniform_filter(plane, 3, mode="reflect")).ravel()
        slope, *_ = np.linalg.lstsq(rgb_high[m], high, rcond=None)
        rest = high - rgb_high[m] @ slope
        mad = np.median(np.abs(rest - np.median(rest)))
        sigma[i] = _MAD_TO_SIGMA * mad * np.sqrt(9.0 / 8.0)
    return sigma


_MAD_TO_SIGMA = 1.4826
"""Standard deviation of a normal distribution per median absolute deviation."""


def local_correction(
    inputs: ReconstructionInputs,
    cube: np.ndarray,
    *,
    window_scale: float = LOCAL_WINDOW_SCALE,
    detail_scale: float | None = LOCAL_DETAIL_SCALE,
    detail_threshold: float = LOCAL_DETAIL_THRESHOLD,
    draws: int = 2,
    seed: int = 0,
) -> np.ndarray:
    """Add to ``cube`` what the band shots say locally and the mixture missed, where it
    stands out of the noise.

    The residual ``D - S`` of every shot is filtered with the RGB image as guide
    (:func:`~..baselines.guided_filter.guided_filtered_bands`: locally affine in RGB, so
    a highlight or a material the dictionary lacks keeps its per-pixel detail); the same
    filter applied to pure noise of the shot's level (``draws`` draws) gives the
    correction's noise variance ``v``; the correction ``c`` is kept in the proportion
    ``max(0, 1 - <v> / <c^2>)`` (``<>``: the window's local mean), a James-Stein shrinkage
    per pixel. A detail layer ``d``, the residual filtered with the finer window
    ``detail_scale`` less ``c`` (its noise from the same draws), is added where it stands
    out, ``max(0, 1 - lambda <v_d> / <d^2>)`` in windows of its own size: a
    highlight or a bright material narrower than the coarse window, where the shots' SNR
    is high. Only bands an image has a shot of are corrected. In place; returns ``cube``.

    Parameters
    ----------
    inputs
        The checked input arrays.
    cube
        The mixture ``(n_wavelength, n_image, height, width)``, corrected in place.
    window_scale, detail_scale
        Windows of the correction and its detail layer, in units of the shot's filter
        ``sigma`` (eq. 3); ``detail_scale=None``: no detail layer.
    detail_threshold
        ``lambda`` (:data:`LOCAL_DETAIL_THRESHOLD`).
    draws, seed
        Noise draws for the variances, and their seed.
    """
    from ..baselines.guided_filter import guided_filtered_stacks, window_sigma

    residual = inputs.band_data.astype(np.float64) - cube[inputs.band, inputs.image]
    sigma = band_noise_sigma(inputs)
    rng = np.random.default_rng(seed)
    noises = [rng.normal(size=inputs.band_data.shape) * sigma[:, None, None] for _ in range(int(draws))]
    correction, *pure = guided_filtered_stacks(inputs, [residual, *noises], window_scale=window_scale)
    fine: np.ndarray | None = None
    pure_fine: list[np.ndarray] = []
    detail_window_scale = 0.0
    if detail_scale:
        detail_window_scale = float(detail_scale)
        fine, *pure_fine = guided_filtered_stacks(inputs, [residual, *noises], window_scale=detail_scale)
    del residual, noises
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
        coarse = correction[i].astype(np.float64)
        variance = sum(p[i].astype(np.float64) ** 2 for p in pure) / len(pure)
        window = window_sigma(float(inputs.filter_size[i]), window_scale)
        step = coarse * _shrinkage(variance, coarse, window)
        if fine is not None:
            detail = fine[i] - coarse
            pairs = zip(pure_fine, pure, strict=True)
            variance = sum((f[i] - p[i].astype(np.float64)) ** 2 for f, p in pairs) / len(pure)
            window = window_sigma(float(inputs.filter_size[i]), detail_window_scale)
            step += detail * _shrinkage(float(detail_threshold) * variance, detail, window)
        cube[b, m] += step / np.count_nonzero((inputs.band == b) & (inputs.image == m))
    return cube


def _shrinkage(noise_variance: np.ndarray, signal: np.ndarray, window: float) -> np.ndarray:
    """``max(0, 1 - <v> / <s^2>)`` clipped to ``[0, 1]``, ``<>`` the local mean over the
    Gaussian window ``window`` [px, sigma]."""
    from ..baselines.guided_filter import gaussian_window

    power = gaussian_window(signal**2, window)
    return np.clip(1.0 - gaussian_window(noise_variance, window) / np.maximum(power, 1e-300), 0.0, 1.0)


def neighbourhood_candidates(
    inputs: ReconstructionInputs,
    near: np.ndarray,
    weights: np.ndarray,
    count: int,
    *,
    sigma: float = NEIGHBOURHOOD_SIGMA,
) -> np.ndarray:
    """Step 2b: per pixel the ``count`` endmembers with the largest abundance share around
    it (each atom's share map Gaussian-smoothed within its image), ``(n, count)``.

    A pixel that straddles two yarns or print dots has a chromaticity between theirs, and
    the endmembers nearest to it in chromaticity may be other mixtures; the materials of the
    pixels around it are the ones it most likely holds. The highlight atom is left out (it
    is always a candidate). Per image, all share maps in one compiled pass
    (:func:`~..kernels.share_planes`), one Gaussian filter over them, and the running
    top-``count`` in another (:func:`~..kernels.top_planes`; ties to the lower atom).
    """
    from scipy import ndimage

    from ..kernels import share_planes, top_planes

    n_atoms = int(near.max()) + 1
    highlight = n_atoms - 1
    per_image = inputs.height * inputs.width
    near = np.ascontiguousarray(near, dtype=np.int64)
    weights = np.ascontiguousarray(weights, dtype=np.float64)
    index = np.zeros((near.shape[0], count), dtype=np.int64)
    planes = np.empty((n_atoms, per_image))
    for m in range(inputs.n_image):  # one image's share maps at a time (bounded memory)
        here = slice(m * per_image, (m + 1) * per_image)
        planes[:] = 0.0
        share_planes(near[here], weights[here], highlight, planes)
        smooth = ndimage.gaussian_filter(
            planes.reshape(n_atoms, inputs.height, inputs.width), (0, sigma, sigma), mode="reflect"
        )
        top_planes(smooth.reshape(n_atoms, per_image), highlight, index[here])
    return index


def _project(cube: np.ndarray, inputs: ReconstructionInputs) -> np.ndarray:
    """Step 4: alternate ``C S = R`` and ``S >= 0``; ends non-negative.

    Each pixel alternates on its own: one compiled pass does every round per pixel
    (:func:`~..kernels.project_rgb_nonnegative`) instead of ``2 * PROJECTION_ROUNDS``
    passes over the cube.
    """
    if cube.dtype == np.float64 and cube.flags.c_contiguous:
        from ..kernels import project_rgb_nonnegative

        c = np.asarray(inputs.camera_matrix, dtype=np.float64)
        cameras = np.ascontiguousarray(c[None] if c.ndim == 2 else c)  # (n_camera, 3, w)
        transposed = np.transpose(cameras, (0, 2, 1))
        pseudo = np.ascontiguousarray(transposed @ np.linalg.inv(cameras @ transposed))
        n_image = inputs.n_image
        index = np.zeros(n_image, np.intp) if c.ndim == 2 else np.arange(n_image)
        project_rgb_nonnegative(
            cube.reshape(cube.shape[0], n_image, -1),
            cameras,
            pseudo,
            index,
            np.ascontiguousarray(inputs.rgb).reshape(n_image, -1, 3),
            PROJECTION_ROUNDS,
        )
        return cube
    rgb = np.moveaxis(inputs.rgb, -1, 0)
    for _ in range(PROJECTION_ROUNDS):
        project_onto_rgb(cube, inputs.camera_matrix, rgb, overwrite=True)
        np.maximum(cube, 0, out=cube)
    return cube


def set_endmembers(
    inputs: ReconstructionInputs,
    *,
    n_endmembers: int = DEFAULT_ENDMEMBERS,
    candidates: int = DEFAULT_CANDIDATES,
    rounds: int = DEFAULT_ROUNDS,
    seed: int = 0,
) -> Endmembers:
    """Steps 1-3 of the module docstring: the endmembers of the pixels of ``inputs``.

    Every step is per pixel or pooled over pixels, never spatial, so ``inputs`` may be a
    strided sample of a set (:func:`~..tiling.sample_grid`): a tiled solve learns the dictionary
    once per set from such a sample and every tile mixes the same endmembers.

    Parameters
    ----------
    inputs
        The checked input arrays (all pixels, or a sample of them).
    n_endmembers, candidates, rounds, seed
        As for :func:`endmember_mixture`.

    Returns
    -------
    Endmembers
        After ``rounds - 1`` dictionary updates (the abundances of the last round are
        solved by :func:`endmember_mixture` on the pixels it reconstructs).
    """
    rgb = inputs.rgb_pixels().T  # (n_pixels, 3)
    scale = np.abs(rgb.mean(axis=0))
    brightness, chroma = chromaticity(rgb, scale)
    endmembers = learn_endmembers(
        inputs, brightness, chroma, scale, n_endmembers=int(n_endmembers), seed=int(seed)
    )
    near = endmembers.candidates(chroma, int(candidates))
    del chroma, brightness
    for _ in range(int(rounds) - 1):
        weights = rgb_abundances(endmembers, near, inputs.camera_matrix, rgb)
        _update_atoms(inputs, endmembers, near, weights)
    return endmembers


SAMPLE_PIXELS = 1 << 21
"""Pixels (over all images) a set's dictionary is learnt from at most: a set larger than
this is sampled on a strided grid (:func:`~..tiling.sample_grid`)."""


def sample_stride(n_image: int, height: int, width: int, pixels: int = SAMPLE_PIXELS) -> int:
    """The smallest grid stride that leaves at most ``pixels`` of ``n_image`` images of
    ``height x width`` (1: every pixel)."""
    stride = 1
    while n_image * -(-height // stride) * -(-width // stride) > pixels:
        stride += 1
    return stride


def endmember_mixture(
    inputs: ReconstructionInputs,
    *,
    endmembers: Endmembers | None = None,
    n_endmembers: int = DEFAULT_ENDMEMBERS,
    candidates: int = DEFAULT_CANDIDATES,
    rounds: int = DEFAULT_ROUNDS,
    spatial_candidates: int = DEFAULT_SPATIAL_CANDIDATES,
    local: bool = True,
    seed: int = 0,
) -> np.ndarray:
    """Spectra as non-negative mixtures of learnt endmembers (see the module docstring).

    Parameters
    ----------
    inputs
        The checked input arrays.
    endmembers
        A dictionary learnt before (:func:`set_endmembers`, e.g. once for a whole set that
        is solved tile by tile); None: learnt from ``inputs`` (then ``n_endmembers``,
        ``rounds`` and ``seed`` apply).
    n_endmembers
        ``J``, endmembers besides the highlight atom.
    candidates
        ``K``, endmembers nearest in chromaticity a pixel may mix.
    rounds
        Abundance / dictionary-update rounds (1: the pooled cluster spectra as they are).
    spatial_candidates
        Endmembers most abundant around each pixel added to its candidates (step 2b; 0:
        none).
    local
        Add the :func:`local_correction` (step 5 of the module docstring).
    seed
        Seed of the clustering and of the local correction's noise draws (the result is
        deterministic for a given seed).

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``, float64, ``>= 0``.

    Raises
    ------
    ReconstructionError
        For ``endmembers`` on other wavelengths than the bands'.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1's RGB term).
    .. [2] Keshava and Mustard (2002), Spectral unmixing.
    """
    if endmembers is None:
        endmembers = set_endmembers(
            inputs, n_endmembers=n_endmembers, candidates=candidates, rounds=rounds, seed=seed
        )
    elif endmembers.atoms.shape[1] != inputs.n_wavelength:
        raise ReconstructionError(
            f"endmembers: expected atoms on the bands' {inputs.n_wavelength} wavelengths, "
            f"found {endmembers.atoms.shape[1]}"
        )
    rgb = inputs.rgb_pixels().T  # (n_pixels, 3)
    _, chroma = chromaticity(rgb, endmembers.scale)
    near = endmembers.candidates(chroma, int(candidates))
    del chroma
    weights = rgb_abundances(endmembers, near, inputs.camera_matrix, rgb)
    if spatial_candidates > 0:
        nearby = neighbourhood_candidates(inputs, near, weights, int(spatial_candidates))
        near = np.hstack([near, nearby])
        del nearby
        weights = rgb_abundances(endmembers, near, inputs.camera_matrix, rgb)
    from ..kernels import mix_atoms

    cube = np.empty((inputs.n_wavelength, rgb.shape[0]))
    mix_atoms(
        weights,
        np.ascontiguousarray(near, dtype=np.int64),
        np.ascontiguousarray(endmembers.atoms, dtype=np.float64),
        cube,
    )
    cube = cube.reshape(inputs.cube_shape)
    if local:
        _project(cube, inputs)
        local_correction(inputs, cube, seed=int(seed))
    return _project(cube, inputs)
