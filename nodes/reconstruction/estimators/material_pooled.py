"""Estimator core ``material_pooled_refine``: texels of one material share their band evidence.

Each band is shot once per set, so a texel's spectral shape gets one noisy value per band
(band SNR at or below 1 on the hard scenes) whatever the set's size:
:func:`~.shared_texel.shared_texel_refine` shares a texel's shape over its images but
cannot average the band noise down. Texels of the same material have the same shape
(up to shading and a highlight), so their band shots can be pooled: a material's shape
gets ``N_k`` values per band, and the noise of its estimate falls as ``1 / sqrt(N_k)``.

Model. Every texel ``p`` of material (cluster) ``k(p)`` has the rank-1 dichromatic spectra
of :mod:`.shared_texel` with the cluster's shape,

``S_m(p) = a_m(p) E_{k(p)} + h_m(p) L``,

per-image weights ``a_m(p), h_m(p) >= 0`` (shading, highlight) and the set's highlight
spectrum ``L`` (the illuminant). The clusters come from the texels' own shapes ``E(p)``
fitted with the highlight taken out (one :mod:`.shared_texel` fit, rank 1, every texel):
k-means on the unit-norm shapes in their top :data:`DEFAULT_FEATURES` principal
directions, so a highlight does not pull a matte texel into another cluster.

A cluster's shape is an empirical-Bayes mixture of two pooled least-squares fits over its
texels (eq. 1's RGB and band terms, the weights fixed):

``E_k^0 = argmin sum_{p in k} [ sum_m ||C_m (a_m E + h_m L) - R_m||^2 / sigma_R,m^2
+ sum_i (a_{m_i} E_{b_i} + h_{m_i} L_{b_i} - D_i)^2 / sigma_i^2
+ mu sum_m ||a_m E + h_m L - S^0_m||^2 / sigma_0,m^2 ]``

(held towards the initial estimate ``S^0``, whose errors are shared by a material's texels,
so pooling does not average them out) and ``E_k^D``, the same with ``mu -> 0`` (the pooled
band evidence; noise variance ``v_kb``, the diagonal of its normal matrix's inverse).
With ``d_k = E_k^D - E_k^0`` and ``tau_k^2 = max(mean_b (d_kb^2 - v_kb), 0)`` (how far the
bands say ``S^0`` is off, beyond their noise),

``E_k = E_k^0 + tau_k^2 / (tau_k^2 + v_kb) d_k``,

so a cluster follows its pooled bands where they disagree with ``S^0`` by more than their
noise (woven, halftone: the default's shapes are biased) and keeps ``S^0`` where they do
not (glossy, dark: ``S^0`` is already good and the pooled bands are noisy). Weights and
cluster shapes alternate :data:`DEFAULT_ROUNDS` times.

The RGB is trusted only as far as the set supports it. Three steps use what the data say
about their own noise instead of a fixed trust:

- ``sigma_R,m``, per image and channel (:func:`rgb_noise_sigma`): the RGB of every texel and
  image is fitted by its cluster's colours, ``R_m(p) ~ a C_m E_k + h C_m L`` (two weights,
  three channels: one degree of freedom left per texel and image), and the scale of what is
  left, robustly over the image's texels (median of the squared residual over the median of
  ``chi^2_1``), is the image's RGB noise relative to its mean RGB per channel, never below
  :data:`~.shared_texel.RGB_RELATIVE_SIGMA` (the HDR merge's). An HDR merge through another
  response, or a second camera model mapped onto the paired one (whose 3 x 3 map amplifies
  the noise), shows up here, and its images weigh less in the pooled fit.
- ``v_kb`` counts the model's own error, not only the band noise: the larger of the normal
  matrix's inverse and its sandwich (robust) form ``H^-1 (sum_p g_p g_p^T) H^-1`` over the
  cluster's texels ``p`` (``g_p``: texel ``p``'s gradient of the RGB and band terms at
  ``E_k^D``; times ``n_k / (n_k - W)`` for the ``W`` unknowns the residuals were fitted with,
  MacKinnon and White's HC1), which grows where the texels disagree with the pooled shape
  more than the stated noise allows (weights off, RGB of one camera inconsistent with
  another's). The gain then keeps ``E_k^0`` where the pooled bands are not to be trusted; a
  cluster of no more texels than wavelengths keeps it always.
- The fit ``F = a_m E + h_m L`` is moved towards its image's RGB by the linear-Gaussian
  (Kalman) update ``S_m = F_m + K_m (R_m - C_m F_m)``, ``K_m = C_m^T (C_m C_m^T +
  Sigma_R,m / sigma_0,m^2)^-1``, ``F`` trusted to ``sigma_0,m`` per element
  (:data:`~.shared_texel.PRIOR_RELATIVE_SIGMA`, the prior's) and the RGB to ``sigma_R,m``,
  then ``S >= 0``: where the RGB is exact to its floor this is the projection onto ``C_m S_m =
  R_m``; where it is noisy the fit is not bent onto its noise.

Why it helps: the errors a solver's spectra share over a material are the ones per-texel
fits cannot see through the band noise, and pooling a material's shots averages that noise
down where a texel's own shots cannot. What limits it is the band noise left per cluster:
the number of clusters is fixed, so a larger set pools more texels into each. Measured
gains, limits, cost and the variants tried: ``docs/benchmarks_notes.md`` ("reconstruction").

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 3 and 5 (eq. 1's RGB and band terms;
   BTF sets of rectified images).
.. [2] Shafer, S. A. (1985). Using color to separate reflection components. Color Research
   and Application 10(4) (highlights have the illuminant's spectrum).
.. [3] Efron, B., Morris, C. (1973). Stein's estimation rule and its competitors - an
   empirical Bayes approach. Journal of the American Statistical Association 68(341)
   (shrinkage with the prior variance estimated from the data).
.. [4] Arthur, D., Vassilvitskii, S. (2007). k-means++: the advantages of careful seeding.
   Proceedings of SODA (k-means initialisation).
.. [5] Huber, P. J. (1967). The behavior of maximum likelihood estimates under nonstandard
   conditions. Proceedings of the Fifth Berkeley Symposium 1; White, H. (1980). A
   heteroskedasticity-consistent covariance matrix estimator and a direct test for
   heteroskedasticity. Econometrica 48(4) (the sandwich variance under a wrong noise model).
.. [6] MacKinnon, J. G., White, H. (1985). Some heteroskedasticity-consistent covariance
   matrix estimators with improved finite sample properties. Journal of Econometrics 29(3)
   (HC1).
.. [7] Tarantola, A. (2005). Inverse Problem Theory and Methods for Model Parameter
   Estimation. SIAM, chapter 3 (the posterior mean of a linear Gaussian problem).
"""

from __future__ import annotations

import numpy as np

from spectralize.schemas import ReconstructionError

from ..inputs import ReconstructionInputs
from .shared_texel import (
    PRIOR_RELATIVE_SIGMA,
    RGB_RELATIVE_SIGMA,
    SHAPE_RIDGE,
    FitTerms,
    fit_terms,
    refit_input_problems,
)

__all__ = [
    "material_pooled_refine",
    "material_clusters",
    "rgb_noise_sigma",
    "DEFAULT_CLUSTERS",
    "DEFAULT_FEATURES",
    "DEFAULT_ROUNDS",
    "DEFAULT_TEXEL_ROUNDS",
]

DEFAULT_CLUSTERS = 48
"""``K``: clusters (materials) per set; fixed, so a cluster's texels grow with the set."""

DEFAULT_FEATURES = 8
"""Principal directions of the texels' unit-norm shapes that k-means clusters in."""

DEFAULT_ROUNDS = 3
"""Alternating rounds of the pooled fit (cluster shapes, then per-texel weights)."""

DEFAULT_TEXEL_ROUNDS = 3
"""Alternating rounds of the per-texel fit whose shapes are clustered (0: each texel's top
shape of its initial spectra, :data:`SHAPE_ITERATIONS`)."""

SHAPE_ITERATIONS = 4
"""Power iterations of each texel's starting shape: the top right singular vector of its
``(m, w)`` initial spectra times its singular value (shared-texel's start for ``r = 1``)."""

TEXEL_BLOCK = 4096
"""Texels whose ``W x W`` shape systems are built and solved at a time (:func:`texel_shapes`):
bounds that step's memory by the block, not by the set's texels."""

KMEANS_SAMPLE = 20000
"""At most this many texels (a fixed random subset) place the k-means centres; all are
then assigned to the nearest centre."""

KMEANS_ITERATIONS = 10
"""Lloyd iterations of k-means."""


POOLED_RIDGE = 1e-9
"""Ridge of a cluster's normal matrix, relative to its mean diagonal."""

CHI2_1_MEDIAN = 0.454936423119572
"""The median of the chi-squared distribution with one degree of freedom: the median squared
residual of a Gaussian over its variance (:func:`rgb_noise_sigma`)."""


def _check(
    inputs: ReconstructionInputs, initial: np.ndarray, highlight: np.ndarray, clusters: int
) -> None:
    problems = refit_input_problems(inputs, initial, highlight)
    if clusters < 1:
        problems.append(f"clusters: expected >= 1, found {clusters}")
    if problems:
        raise ReconstructionError("; ".join(problems))


def material_clusters(
    shapes: np.ndarray, clusters: int = DEFAULT_CLUSTERS, features: int = DEFAULT_FEATURES, seed: int = 0
) -> np.ndarray:
    """Cluster texels by their spectral shape: k-means++ on unit-norm shapes in their top
    principal directions.

    Parameters
    ----------
    shapes
        ``(n_texel, n_wavelength)`` per-texel shapes (any scale).
    clusters
        ``K``; fewer when there are fewer texels.
    features
        Principal directions (of the unit-norm shapes, uncentred) kept.
    seed
        Seed of the k-means++ start and of the subset that places the centres.

    Returns
    -------
    numpy.ndarray
        ``(n_texel,)`` int cluster index, ``0 .. K - 1``.
    """
    e = np.asarray(shapes, dtype=np.float64)
    unit = e / np.maximum(np.linalg.norm(e, axis=1, keepdims=True), 1e-300)
    sub = unit[:: max(1, unit.shape[0] // KMEANS_SAMPLE)]
    _, vectors = np.linalg.eigh(sub.T @ sub)  # right singular vectors, increasing
    x = unit @ vectors[:, ::-1][:, : min(features, vectors.shape[1])]  # (n, q)
    n = x.shape[0]
    k = int(min(clusters, n))
    rng = np.random.default_rng(seed)
    sample = x if n <= KMEANS_SAMPLE else x[rng.choice(n, KMEANS_SAMPLE, replace=False)]
    centres = [sample[rng.integers(sample.shape[0])]]
    d2 = ((sample - centres[0]) ** 2).sum(axis=1)
    for _ in range(1, k):  # k-means++
        total = d2.sum()
        pick = rng.integers(sample.shape[0]) if total <= 0 else rng.choice(sample.shape[0], p=d2 / total)
        centres.append(sample[pick])
        d2 = np.minimum(d2, ((sample - centres[-1]) ** 2).sum(axis=1))
    c = np.array(centres)
    for _ in range(KMEANS_ITERATIONS):
        label = _nearest(sample, c)
        counts = np.bincount(label, minlength=k)
        sums = np.stack(
            [np.bincount(label, sample[:, j], minlength=k) for j in range(c.shape[1])], axis=1
        )
        filled = counts > 0
        c[filled] = sums[filled] / counts[filled, None]
    return _nearest(x, c)


def _nearest(x: np.ndarray, centres: np.ndarray) -> np.ndarray:
    d = (x**2).sum(axis=1)[:, None] - 2.0 * x @ centres.T + (centres**2).sum(axis=1)[None]
    return d.argmin(axis=1)


def material_pooled_refine(
    inputs: ReconstructionInputs,
    initial: np.ndarray,
    highlight: np.ndarray,
    *,
    clusters: int = DEFAULT_CLUSTERS,
    features: int = DEFAULT_FEATURES,
    rounds: int = DEFAULT_ROUNDS,
    texel_rounds: int = DEFAULT_TEXEL_ROUNDS,
    prior: float = 1.0,
    band_sigma: np.ndarray | None = None,
    rgb_sigma: np.ndarray | None = None,
    labels: np.ndarray | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Refit a set's spectra with one shape per material, pooled over its texels (module
    docstring).

    Parameters
    ----------
    inputs
        The checked inputs of one set (rectified images: pixel ``(y, x)`` is the same texel
        in every image).
    initial
        ``S^0``, ``(n_wavelength, n_image, height, width)``: the estimate to start from and
        to be held towards.
    highlight
        ``L``, ``(n_wavelength,)``: the highlight (illuminant) spectrum, any scale.
    clusters
        ``K``, materials per set (:func:`material_clusters`).
    features
        Principal directions the clustering uses.
    rounds
        Alternating rounds of the pooled fit.
    texel_rounds
        Alternating rounds of the per-texel fit whose shapes are clustered.
    prior
        ``mu``, weight of ``S^0`` (units of ``sigma_0``, as in :mod:`.shared_texel`).
    band_sigma
        Per shot, the band noise's standard deviation (default:
        :func:`~.endmember_mixture.band_noise_sigma`).
    rgb_sigma
        ``(n_image, 3)``: per image and channel, the RGB noise's standard deviation ``sigma_R,m``
        in the RGB's units (default: :func:`rgb_noise_sigma`, estimated from the set).
    labels
        ``(height, width)`` int material per texel to use instead of the clustering (``>= 0``;
        for studies with known materials).
    seed
        Seed of the clustering.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)`` float64, ``>= 0``.

    Raises
    ------
    ReconstructionError
        For an ``initial`` or ``highlight`` of the wrong shape or not finite, ``clusters < 1``,
        ``labels`` of the wrong shape or negative, or an ``rgb_sigma`` of the wrong shape or
        not positive.
    """
    initial = np.asarray(initial)  # a float32 cube is cast once, into the fit's ``x0``
    highlight = np.asarray(highlight, dtype=np.float64)
    _check(inputs, initial, highlight, int(clusters))
    n_w, n_m, h, w = inputs.cube_shape
    t = fit_terms(inputs, initial, highlight, prior, band_sigma)
    del initial  # the fit holds it as ``x0`` (texel-major, float64)
    ell, x0, rgb, cams, rgb_weight, prior_weight, shot_image, shot_band, data, shot_weight, ctc = t
    rgb_terms = (rgb * rgb_weight, cams)  # C_m^T W R_m, applied per texel as needed
    terms = (cams, rgb_weight, rgb, x0, prior_weight, data, shot_image, shot_band, shot_weight)
    shape_terms = (ell, ctc, rgb_terms, x0, prior_weight, data, shot_image, shot_band, shot_weight)

    # 1. each texel's own rank-1 shape with the highlight taken out (shared-texel fit)
    shapes = _top_shape(x0, SHAPE_ITERATIONS)
    weights = texel_weights(shapes, ell, *terms)
    for _ in range(int(texel_rounds)):
        shapes = texel_shapes(shapes, weights, *shape_terms)
        weights = texel_weights(shapes, ell, *terms)

    # 2. materials
    if labels is None:
        label = material_clusters(shapes, clusters, features, seed)
    else:
        label = np.asarray(labels)
        if label.shape != (h, w) or label.min() < 0:
            raise ReconstructionError(
                f"labels: expected ({h}, {w}) ints >= 0, found shape {label.shape}"
                + (f", min {label.min()}" if label.size else "")
            )
        label = label.ravel().astype(np.int64)
    k = int(label.max()) + 1

    # 3. the RGB trusted as far as the material model explains it (module docstring)
    sigma = rgb_noise_sigma(shapes, label, t) if rgb_sigma is None else _checked(rgb_sigma, n_m)
    t = _with_rgb_sigma(t, sigma)
    ell, x0, rgb, cams, rgb_weight, prior_weight, shot_image, shot_band, data, shot_weight, ctc = t
    rgb_terms = (rgb * rgb_weight, cams)
    terms = (cams, rgb_weight, rgb, x0, prior_weight, data, shot_image, shot_band, shot_weight)
    shape_terms = (ell, ctc, rgb_terms, x0, prior_weight, data, shot_image, shot_band, shot_weight)

    # 4. pooled shapes (empirical Bayes between S^0 and the pooled bands), then weights
    prior_sigma = PRIOR_RELATIVE_SIGMA * np.maximum(x0.mean(axis=(0, 2)), 1e-12)
    for _ in range(int(rounds)):
        pooled = _pooled_shapes(weights, label, k, *shape_terms, rgb_weight=rgb_weight)
        shapes = pooled[label]
        weights = texel_weights(shapes, ell, *terms)
    # S^0 (two float32 cubes' worth) is done with: the fitted cube takes its place
    del t, x0, terms, shape_terms, rgb_terms, rgb, data
    fit = _fitted_cube(weights, shapes, ell, inputs.cube_shape)
    return _rgb_update(fit, inputs, sigma, prior_sigma).reshape(n_w, n_m, h, w)


def _fitted_cube(
    weights: np.ndarray, shapes: np.ndarray, ell: np.ndarray, shape: tuple[int, int, int, int]
) -> np.ndarray:
    """``(w, m, n)``: ``a_m E + h_m L`` per texel and image from the weights ``(n, m, 2)``
    and shapes ``(n, w)``, written wavelength by wavelength into the cube (one cube in
    memory, not the ``(n, m, w)`` products, their sum and its transposed copy), from the
    weights and shapes transposed once: each wavelength's plane is then computed in
    place."""
    n_w, n_m, h, w = shape
    shading, shine = weights[:, :, 0].T.copy(), weights[:, :, 1].T.copy()  # (m, n)
    columns = shapes.T.copy()  # (w, n)
    fit = np.empty((n_w, n_m, h * w))
    for band in range(n_w):
        np.multiply(shading, columns[band], out=fit[band])
        fit[band] += shine * ell[band]
    return fit


def _checked(rgb_sigma: np.ndarray, n_image: int) -> np.ndarray:
    sigma = np.asarray(rgb_sigma, dtype=np.float64)
    if sigma.shape != (n_image, 3) or not np.all(sigma > 0):
        raise ReconstructionError(
            f"rgb_sigma: expected ({n_image}, 3) finite values > 0, found shape {sigma.shape}"
            + (f", min {sigma.min()}" if sigma.size else "")
        )
    return sigma


def rgb_noise_sigma(shapes: np.ndarray, label: np.ndarray, terms: FitTerms) -> np.ndarray:
    """``sigma_R,m``: per image and channel, the RGB noise the material model leaves
    (module docstring), ``(n_image, 3)`` in the RGB's units.

    Every texel's RGB in image ``m``, divided by the image's mean RGB per channel, is fitted by
    least squares with its cluster's two colours ``C_m E_k`` and ``C_m L`` (``E_k``: the mean
    of the cluster's unit-norm texel shapes). One degree of freedom is left per texel and
    image, so under Gaussian noise of relative standard deviation ``s_m`` per channel the
    squared residual is ``s_m^2 chi^2_1``: ``s_m^2`` is its median over the texels divided by
    :data:`CHI2_1_MEDIAN` (a median: highlights and texels mixing materials are outliers, not
    noise). The result is ``max(s_m, RGB_RELATIVE_SIGMA)`` times the image's mean RGB.

    Parameters
    ----------
    shapes
        ``(n_texel, n_wavelength)`` per-texel shapes (any scale).
    label
        ``(n_texel,)`` cluster per texel.
    terms
        The fit's fixed terms (:func:`~.shared_texel.fit_terms`): ``ell``, ``rgb``, ``cams``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1's RGB term).
    .. [2] Huber, P. J., Ronchetti, E. M. (2009). Robust Statistics, 2nd ed. Wiley, chapter 5
       (scale from the median of the residuals).
    """
    ell, rgb, cams = terms.ell, terms.rgb, terms.cams
    mean = np.maximum(np.abs(rgb.mean(axis=0)), 1e-12)  # (m, 3)
    unit = shapes / np.maximum(np.linalg.norm(shapes, axis=1, keepdims=True), 1e-300)
    centre = np.zeros((int(label.max()) + 1, unit.shape[1]))
    np.add.at(centre, label, unit)
    u = (centre @ cams.reshape(-1, cams.shape[2]).T).reshape(-1, *mean.shape)[label] / mean  # (n, m, 3)
    v = (cams @ ell) / mean  # (m, 3)
    y = rgb / mean
    uu, uv, vv = (u * u).sum(axis=2), (u * v).sum(axis=2), (v * v).sum(axis=1)
    uy, vy = (u * y).sum(axis=2), (v * y).sum(axis=2)
    det = uu * vv - uv**2
    det = np.where(det > 1e-12 * uu * vv, det, np.inf)  # a colour along L: no fit, no residual
    a = (vv * uy - uv * vy) / det
    b = (uu * vy - uv * uy) / det
    residual = ((y - a[..., None] * u - b[..., None] * v) ** 2).sum(axis=2)  # (n, m)
    residual = np.where(np.isfinite(det), residual, np.nan)
    scale = np.sqrt(np.nanmedian(residual, axis=0) / CHI2_1_MEDIAN)
    scale = np.where(np.isfinite(scale), scale, 0.0)
    return np.maximum(scale, RGB_RELATIVE_SIGMA)[:, None] * mean


def _with_rgb_sigma(t: FitTerms, sigma: np.ndarray) -> FitTerms:
    """The fit's terms with the RGB weighted by ``1 / sigma_R,m^2``."""
    weight = 1.0 / sigma**2
    ctc = np.matmul(np.swapaxes(t.cams, 1, 2) * weight[:, None, :], t.cams)
    return t._replace(rgb_weight=weight, ctc=ctc)


def _rgb_update(
    fit: np.ndarray, inputs: ReconstructionInputs, rgb_sigma: np.ndarray, prior_sigma: np.ndarray
) -> np.ndarray:
    """``(w, m, n)``: per image ``max(F_m + K_m (R_m - C_m F_m), 0)`` with ``K_m = C_m^T (C_m
    C_m^T + Sigma_R,m / sigma_0,m^2)^-1`` (module docstring), in place on ``fit`` ``(w, m,
    n)``."""
    for m in range(fit.shape[1]):
        c = np.asarray(inputs.camera_of(m), dtype=np.float64)
        rgb = inputs.rgb[m].reshape(-1, 3).T.astype(np.float64)  # (3, n)
        gain = c.T @ np.linalg.inv(c @ c.T + np.diag((rgb_sigma[m] / prior_sigma[m]) ** 2))
        fit[:, m] += gain @ (rgb - c @ fit[:, m])
    return np.maximum(fit, 0.0, out=fit)


def _pooled_shapes(
    weights,
    label,
    k,
    ell,
    ctc,
    rgb_terms,
    x0,
    prior_weight,
    data,
    shot_image,
    shot_band,
    shot_weight,
    *,
    rgb_weight,
):
    """``(k, w)``: per cluster ``E_k^0 + tau_k^2 / (tau_k^2 + v_k) (E_k^D - E_k^0)``, ``v_k``
    the larger of the model's and the sandwich variance (:func:`_sandwich_variance`)."""
    from scipy import sparse

    n_w = ell.size
    n = label.size
    a, hl = weights[:, :, 0], weights[:, :, 1]  # (n, m)
    member = sparse.csr_matrix((np.ones(n), (label, np.arange(n))), shape=(k, n))  # sums
    aa = member @ a**2  # (k, m)
    # RGB and band terms, summed over each cluster's texels
    rgb_mat = np.einsum("km,mwv->kwv", aa, ctc)
    rgb_rhs = member @ (_rgb_rhs(a, *rgb_terms) - (a * hl) @ (ctc @ ell))
    a_shot = a[:, shot_image]  # (n, shots)
    band_diag = member @ _group_sum(a_shot**2 * shot_weight, shot_band, n_w)
    band_rhs = member @ _group_sum(
        a_shot * shot_weight * (data - hl[:, shot_image] * ell[shot_band]), shot_band, n_w
    )
    prior_diag = aa @ prior_weight  # (k,)
    ap = a * prior_weight
    prior_rhs = member @ (np.matmul(ap[:, None, :], x0)[:, 0] - (ap * hl).sum(axis=1)[:, None] * ell)
    idx = np.arange(n_w)
    band_mat = rgb_mat.copy()
    band_mat[:, idx, idx] += band_diag
    held_mat = band_mat.copy()
    held_mat[:, idx, idx] += prior_diag[:, None]
    eye = np.eye(n_w)

    def ridge(mat):
        return (
            mat
            + (POOLED_RIDGE * np.maximum(np.einsum("kii->k", mat) / n_w, 1e-300))[:, None, None] * eye
        )

    held = np.linalg.solve(ridge(held_mat), (rgb_rhs + band_rhs + prior_rhs)[..., None])[..., 0]
    inverse = np.linalg.inv(ridge(band_mat))
    bands = np.matmul(inverse, (rgb_rhs + band_rhs)[..., None])[..., 0]
    variance = np.maximum(np.einsum("kii->ki", inverse), 0.0)
    gradient = _texel_gradients(
        bands[label], weights, ell, rgb_terms, rgb_weight, data, shot_image, shot_band, shot_weight
    )
    variance = np.maximum(variance, _sandwich_variance(inverse, gradient, label))
    d = bands - held
    tau2 = np.maximum((d**2 - variance).mean(axis=1, keepdims=True), 0.0)
    gain = tau2 / np.maximum(tau2 + variance, 1e-300)
    return held + gain * d


def _texel_gradients(
    shapes, weights, ell, rgb_terms, rgb_weight, data, shot_image, shot_band, shot_weight
):
    """``(n, w)``: per texel ``g_p``, the half gradient of its RGB and band terms with respect
    to its shape ``E`` ``(n, w)``: ``sum_m a_m C_m^T W_m (R_m - C_m (a_m E + h_m L)) + sum_i
    a_{m_i} (D_i - a_{m_i} E_{b_i} - h_{m_i} L_{b_i}) / sigma_i^2 e_{b_i}``."""
    weighted_rgb, cams = rgb_terms  # W_m R_m, C_m
    a, hl = weights[:, :, 0], weights[:, :, 1]
    n, n_m = a.shape
    n_w = ell.size
    seen = (shapes @ cams.reshape(-1, n_w).T).reshape(n, n_m, 3)  # C_m E
    residual = weighted_rgb - rgb_weight * (a[:, :, None] * seen + hl[:, :, None] * (cams @ ell))
    gradient = (a[:, :, None] * residual).reshape(n, n_m * 3) @ cams.reshape(n_m * 3, n_w)
    a_shot = a[:, shot_image]
    band_residual = data - a_shot * shapes[:, shot_band] - hl[:, shot_image] * ell[shot_band]
    return gradient + _group_sum(a_shot * shot_weight * band_residual, shot_band, n_w)


def _sandwich_variance(inverse: np.ndarray, gradient: np.ndarray, label: np.ndarray) -> np.ndarray:
    """``(k, w)``: the diagonal of ``n_k / (n_k - W) H_k^-1 (sum_{p in k} g_p g_p^T) H_k^-1``
    as ``sum_{p in k} (H_k^-1 g_p)^2`` times the small-sample factor (MacKinnon and White's
    HC1), cluster by cluster (no ``n x w x w`` array); ``inf`` for a cluster of ``n_k <= W``
    texels."""
    out = np.zeros(inverse.shape[:2])
    order = np.argsort(label, kind="stable")
    ordered = label[order]
    starts = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]])
    for start, stop in zip(starts, [*starts[1:], len(order)], strict=True):
        cluster = ordered[start]
        u = gradient[order[start:stop]] @ inverse[cluster].T
        texels, unknowns = stop - start, inverse.shape[1]
        # n / (n - W): the sandwich's residuals lost W degrees of freedom to E_k^D; with no
        # more texels than unknowns it says nothing, and the pooled bands are not trusted
        out[cluster] = (u**2).sum(axis=0) * texels / (texels - unknowns) if texels > unknowns else np.inf
    return out


def _top_shape(x0: np.ndarray, iterations: int) -> np.ndarray:
    """``(n, w)``: per texel the top right singular vector of its ``(m, w)`` spectra ``x0``
    ``(n, m, w)`` times its singular value, by power iteration on ``x0^T x0`` applied as two
    products (no ``w x w`` matrices), from the mean spectrum as
    :func:`~.shared_texel._top_shapes` starts; sign: a positive sum."""
    start = x0.mean(axis=1)
    v = start + 1e-3 * np.abs(start).mean(axis=1, keepdims=True) * np.cos(np.arange(x0.shape[2]))
    for _ in range(int(iterations)):
        v = np.matmul(np.matmul(x0, v[:, :, None])[:, :, 0][:, None, :], x0)[:, 0]
        v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
    scale = np.linalg.norm(np.matmul(x0, v[:, :, None])[:, :, 0], axis=1)
    v *= np.where(v.sum(axis=1) < 0, -1.0, 1.0)[:, None]
    return v * scale[:, None]


def _rgb_rhs(a: np.ndarray, weighted_rgb: np.ndarray, cams: np.ndarray) -> np.ndarray:
    """``(n, w)``: ``sum_m a_m C_m^T W_m R_m`` from ``a`` ``(n, m)``, ``W_m R_m`` ``(n, m, 3)``
    and ``C_m`` ``(m, 3, w)``."""
    n, n_m = a.shape
    return (a[:, :, None] * weighted_rgb).reshape(n, n_m * 3) @ cams.reshape(n_m * 3, -1)


def _group_sum(x: np.ndarray, group: np.ndarray, size: int) -> np.ndarray:
    """``(n, size)``: the columns of ``x`` ``(n, shots)`` summed by ``group`` (per shot
    ``0 .. size - 1``), in the shots' order within a group; ufunc sums, not a matrix product
    (no BLAS threads). Groups of at most :data:`~..kernels.GROUP_SUM_MEMBERS` shots (a
    band's shots, an image's) are summed by :func:`~..kernels.group_sums` in one pass over
    ``x``, the same sums bit for bit as ``numpy.add.reduceat`` over the reordered columns,
    which sums larger groups."""
    from ..kernels import GROUP_SUM_MEMBERS, group_sums

    order = np.argsort(group, kind="stable")
    g = np.asarray(group)[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    out = np.zeros((x.shape[0], size))
    indptr = np.r_[starts, g.size]
    if x.dtype == np.float64 and np.diff(indptr).max(initial=0) <= GROUP_SUM_MEMBERS:
        group_sums(x, order.astype(np.int64), indptr.astype(np.int64), g[starts].astype(np.int64), out)
        return out
    out[:, g[starts]] = np.add.reduceat(x[:, order], starts, axis=1)
    return out


def texel_weights(
    shapes, ell, cams, rgb_weight, rgb, x0, prior_weight, data, shot_image, shot_band, shot_weight
):
    """``(n, m, 2)``: per texel and image ``(a_m, h_m) >= 0`` for fixed rank-1 shapes
    ``(n, w)``: the normal equations of :func:`~.shared_texel.shared_texel_refine`'s
    weights step (RGB through each image's camera, the prior, the image's band shots), in
    closed form (Cramer's rule), then clipped at 0."""
    n_m = cams.shape[0]
    seen = (shapes @ cams.reshape(-1, cams.shape[2]).T).reshape(-1, n_m, 3)  # C_m E: (n, m, 3)
    seen_l = cams @ ell  # C_m L: (m, 3)
    e_b = shapes[:, shot_band] * shot_weight  # (n, shots)
    l_b = ell[shot_band] * shot_weight
    x0_e = np.matmul(x0, shapes[:, :, None])[..., 0]
    g00 = (seen**2 * rgb_weight).sum(axis=2)
    g00 += prior_weight * (shapes**2).sum(axis=1)[:, None] + _group_sum(
        e_b * shapes[:, shot_band], shot_image, n_m
    )
    g01 = (seen * (rgb_weight * seen_l)).sum(axis=2)
    g01 += prior_weight * (shapes @ ell)[:, None] + _group_sum(e_b * ell[shot_band], shot_image, n_m)
    g11 = (rgb_weight * seen_l**2).sum(axis=1) + prior_weight * (ell @ ell)
    g11 = np.broadcast_to(g11 + _group_sum((l_b * ell[shot_band])[None], shot_image, n_m), g00.shape)
    r0 = (seen * rgb_weight * rgb).sum(axis=2) + prior_weight * x0_e
    r0 += _group_sum(e_b * data, shot_image, n_m)
    r1 = (rgb * (rgb_weight * seen_l)).sum(axis=2) + prior_weight * (x0 @ ell)
    r1 += _group_sum(data * l_b, shot_image, n_m)
    ridge = 1e-9 * (g00 + g11) / 2
    g00, g11 = g00 + ridge, g11 + ridge
    det = g00 * g11 - g01 * g01
    det = np.where(det > 0, det, 1e-300)
    solved = np.stack([(g11 * r0 - g01 * r1) / det, (g00 * r1 - g01 * r0) / det], axis=-1)
    return np.maximum(solved, 0.0)


def texel_shapes(
    previous, weights, ell, ctc, rgb_terms, x0, prior_weight, data, shot_image, shot_band, shot_weight
):
    """``(n, w)``: per texel the rank-1 shape for fixed weights, one ``W x W`` system each:
    :func:`~.shared_texel.shared_texel_refine`'s shapes step for ``r = 1``, with the band
    terms gathered by matrix products.

    The systems are built and solved :data:`TEXEL_BLOCK` texels at a time: all of them at
    once are ``n x W x W`` floats (more than the spectra of all the set's images, twice over
    while LAPACK solves a copy). The ridge needs every system's trace first, which comes
    from the diagonals alone.
    """
    n_w = ell.size
    a, hl = weights[:, :, 0], weights[:, :, 1]
    a_shot = a[:, shot_image]  # (n, shots)
    gram = ctc.reshape(ctc.shape[0], -1)  # C_m^T W C_m, (m, w * w)
    diagonal = ((a**2) @ prior_weight)[:, None] + _group_sum(a_shot**2 * shot_weight, shot_band, n_w)
    idx = np.arange(n_w)
    # sum_m a_m (C_m^T W R_m + pw_m S^0_m - h_m (C_m^T W C_m + pw_m) L)
    rhs = _rgb_rhs(a, *rgb_terms) + np.matmul((a * prior_weight)[:, None, :], x0)[:, 0]
    rhs -= (a * hl) @ (ctc @ ell + prior_weight[:, None] * ell)
    rhs += _group_sum(a_shot * shot_weight * (data - hl[:, shot_image] * ell[shot_band]), shot_band, n_w)
    trace = _system_traces((a**2) @ np.ascontiguousarray(gram[:, idx * (n_w + 1)]) + diagonal)
    ridge = SHAPE_RIDGE * max(float(np.median(trace)) / n_w, 1e-300)
    rhs += ridge * previous
    shapes = np.empty_like(rhs)
    for start in range(0, len(rhs), TEXEL_BLOCK):
        block = slice(start, start + TEXEL_BLOCK)
        mat = ((a[block] ** 2) @ gram).reshape(-1, n_w, n_w)
        mat[:, idx, idx] += diagonal[block]
        mat[:, idx, idx] += ridge
        shapes[block] = np.linalg.solve(mat, rhs[block, :, None])[..., 0]
    return shapes


def _system_traces(diagonals: np.ndarray) -> np.ndarray:
    """``(n,)``: the traces of ``n`` ``W x W`` systems from their diagonals ``(n, W)``, summed
    as ``einsum("nii->n")`` sums a whole system's (the same order, so the same ridge),
    :data:`TEXEL_BLOCK` systems at a time."""
    n, n_w = diagonals.shape
    idx = np.arange(n_w)
    traces = np.empty(n)
    for start in range(0, n, TEXEL_BLOCK):
        block = diagonals[start : start + TEXEL_BLOCK]
        square = np.zeros((len(block), n_w * n_w))
        square[:, idx * (n_w + 1)] = block
        traces[start : start + TEXEL_BLOCK] = np.einsum("nii->n", square.reshape(-1, n_w, n_w))
    return traces
