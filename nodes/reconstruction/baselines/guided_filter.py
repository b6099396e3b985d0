"""Baseline ``"guided-projected"``: band images filtered with the RGB image as guide.

He et al.'s guided filter with Gaussian-like windows (three box filters of the Gaussian's
variance from 2 px on, :func:`gaussian_window`): per window the band is the affine function
of RGB that best fits the noisy band, ``S_b(p) = a(p)^T R(p) + c(p)``; then projected onto
``C S = R``. The ``"guided-prior-pcg"`` solver's initial guess and prior centre.

References
----------
.. [1] He, K., Sun, J., Tang, X. (2013). Guided Image Filtering. IEEE TPAMI 35(6).
.. [2] Fast Capture of Spectral Image Series, section 3, "Filtering".
"""

from __future__ import annotations

import numpy as np

from spectralize.nodes.filter_size import filter_sigma

from ..inputs import ReconstructionInputs
from .filtered_bands import filtered_bands
from .projection import project_onto_rgb

__all__ = [
    "guided_filtered_bands",
    "guided_filtered_stacks",
    "guided_filtered_projected",
    "window_sigma",
    "gaussian_window",
    "GUIDED_WINDOW_SCALE",
    "GUIDED_EPSILON",
    "GUIDED_WINDOW_STEP",
    "GUIDED_WINDOW_TRUNCATE",
]

GUIDED_WINDOW_SCALE = 3.0
"""Guided-filter window ``sigma`` in units of the band's filter ``sigma_i = s_i / 5``."""


GUIDED_EPSILON = 1e-4
"""Ridge on the guided filter's RGB slopes, relative to the window's mean ``|R|^2``."""


GUIDED_WINDOW_STEP = 1.05
"""Window sigmas are rounded to a geometric grid of this ratio, so that bands of nearly the
same filter size share one window's RGB statistics (a window's size is a modelling choice,
not a precise quantity)."""


GUIDED_WINDOW_TRUNCATE = 3.0
"""Support of a guided-filter window in its own sigmas. A window is a local-statistics
weight, not the paper's filter (which :mod:`spectralize.nodes.filter_size` truncates at
``5 sigma_i = s_i``)."""


BOX_WINDOW_SIGMA = 2.0
"""Windows at least this wide [px, sigma] are three box filters instead of a Gaussian."""


def window_sigma(filter_size: float, window_scale: float) -> float:
    """The guided filter's window ``sigma`` [px] for a band of filter size ``s_i``:
    ``window_scale`` times the filter's own sigma, rounded to the grid of
    :data:`GUIDED_WINDOW_STEP` (bands of nearly the same size share a window)."""
    sigma = filter_sigma(filter_size) * window_scale
    step = np.log(GUIDED_WINDOW_STEP)
    return float(np.exp(np.round(np.log(sigma) / step) * step))


def _box_widths(sigma: float, passes: int = 3) -> list[int]:
    """Odd widths of ``passes`` box filters whose convolution has variance ``sigma**2``
    (Kovesi's two-width choice: ``m`` passes of ``w`` and the rest of ``w + 2``)."""
    ideal = np.sqrt(12.0 * sigma**2 / passes + 1.0)
    low = int(np.floor(ideal))
    low -= 1 - low % 2  # odd
    m = int(
        round((12.0 * sigma**2 - passes * low**2 - 4 * passes * low - 3 * passes) / (-4.0 * low - 4.0))
    )
    return [low if i < m else low + 2 for i in range(passes)]


def gaussian_window(planes: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian-weighted local mean over the last two axes (reflecting borders).

    From :data:`BOX_WINDOW_SIGMA` on, three box filters of the same variance (a quadratic
    B-spline window; its peak differs from the Gaussian's by about 12 %), each a running sum
    whose cost does not grow with ``sigma`` (compiled, :func:`~..kernels.box_mean_columns`
    and :func:`~..kernels.box_mean_rows`: scipy's ``uniform_filter1d`` in float64 running
    sums, one row at a time along the columns); below it, the Gaussian.
    """
    from scipy import ndimage

    if sigma < BOX_WINDOW_SIGMA:
        sigmas = (0.0,) * (planes.ndim - 2) + (sigma, sigma)
        return ndimage.gaussian_filter(
            planes, sigma=sigmas, mode="reflect", truncate=GUIDED_WINDOW_TRUNCATE
        )
    from ..kernels import box_mean_columns, box_mean_rows

    planes = np.asarray(planes)
    if planes.dtype not in (np.float32, np.float64):
        planes = planes.astype(np.float64)
    source = np.ascontiguousarray(planes).reshape((-1,) + planes.shape[-2:])
    between, out = np.empty_like(source), np.empty_like(source)
    current = source  # never written into
    for width in _box_widths(sigma):
        box_mean_columns(current, width, between)
        box_mean_rows(between, width, out)
        current = out
    return out.reshape(planes.shape)


def guided_filtered_bands(
    inputs: ReconstructionInputs,
    *,
    window_scale: float = GUIDED_WINDOW_SCALE,
    epsilon: float = GUIDED_EPSILON,
) -> np.ndarray:
    """Every band image filtered with its RGB image as guide (guided filter).

    In the Gaussian window of every pixel ``q`` (``sigma = window_scale * s_i / 5``) the
    band is modelled as an affine function of the RGB, ``D_b(p) ~ a_q^T R(p) + c_q``, fitted
    by weighted least squares with the ridge ``epsilon * mean_window |R|^2 * ||a_q||^2``; the
    estimate is ``S_b(p) = abar(p)^T R(p) + cbar(p)`` with the coefficients averaged over the
    windows covering ``p`` [1]_. Within one material a spectrum that is a diffuse and a
    specular (illuminant-coloured) part of varying strength, ``S = u L rho + v L``, is a
    *linear* function of its RGB, so the model keeps the per-pixel detail that a plain
    Gaussian filter (:func:`filtered_bands`) blurs away and that the RGB pins down.

    Shots of the same band and image are averaged; a band an image has no shot of comes
    from :func:`filtered_bands` (a linear fit to RGB on the images that have it).

    Parameters
    ----------
    inputs
        The checked input arrays.
    window_scale
        Window ``sigma`` in units of the shot's filter ``sigma_i = s_i / 5`` (eq. 3).
    epsilon
        Relative ridge on the slopes ``a`` (keeps flat windows well posed).

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``.

    References
    ----------
    .. [1] He, Sun and Tang (2013), Guided Image Filtering, algorithm 1 (with Gaussian
       instead of box windows).
    .. [2] Fast Capture of Spectral Image Series, section 3, "Filtering".
    """
    (planes,) = guided_filtered_stacks(
        inputs, [inputs.band_data], window_scale=window_scale, epsilon=epsilon
    )
    cube = np.zeros(inputs.cube_shape)
    counts = np.zeros(inputs.cube_shape[:2])
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
        cube[b, m] += planes[i]
        counts[b, m] += 1
    have = counts > 0
    cube[have] /= counts[have][:, None, None]
    if not have.all():
        fallback = filtered_bands(inputs)
        cube[~have] = fallback[~have]
    return cube


GUIDED_CHUNK_PIXELS = 2**17
"""Shot pixels :func:`guided_filtered_stacks` filters in one pass: a set of small frames in a
few passes per window instead of one per shot, a large tile shot by shot (larger passes'
float32 temporaries per shot would leave the cache)."""


def guided_filtered_stacks(
    inputs: ReconstructionInputs,
    stacks: list[np.ndarray],
    *,
    window_scale: float = GUIDED_WINDOW_SCALE,
    epsilon: float = GUIDED_EPSILON,
) -> list[np.ndarray]:
    """The guided filter of :func:`guided_filtered_bands`, shot by shot, for several stacks
    of shots at once.

    Each of ``stacks`` is ``(n_shot, height, width)``, shot ``i`` guided by the RGB of image
    ``inputs.image[i]`` with the window of ``inputs.filter_size[i]`` (the band data itself,
    or residuals or noise of the same shots); the windows' RGB statistics and their
    inverses are computed once for all stacks.

    The shots that share a window are filtered together, :data:`GUIDED_CHUNK_PIXELS` shot
    pixels at a time, each window filter one pass over a stack of planes (per plane the
    same arithmetic as one shot alone: the same result to the bit); a set of small frames
    makes a few dozen filter calls instead of some 400.

    Returns
    -------
    list of numpy.ndarray
        One ``(n_shot, height, width)`` float32 stack of filtered shots per input stack.
    """
    rgb = np.moveaxis(inputs.rgb, -1, 1).astype(np.float32)  # (n_image, 3, height, width)
    outputs = [np.empty(stack.shape, dtype=np.float32) for stack in stacks]
    sigmas = np.array([window_sigma(float(size), window_scale) for size in inputs.filter_size])
    images = np.asarray(inputs.image, dtype=np.intp)
    per_chunk = max(1, GUIDED_CHUNK_PIXELS // int(np.prod(rgb.shape[-2:])))
    for sigma in np.unique(sigmas):
        shots = np.flatnonzero(sigmas == sigma)
        shots = shots[np.argsort(images[shots], kind="stable")]
        owners = np.unique(images[shots])
        for first in range(0, len(owners), per_chunk):  # a group of images' window statistics
            group = owners[first : first + per_chunk]
            mean, inverse = _window_statistics(rgb[group], float(sigma), epsilon)
            own = shots[np.isin(images[shots], group)]
            for start in range(0, len(own), per_chunk):  # their shots, a chunk at a time
                chunk = own[start : start + per_chunk]
                which = np.searchsorted(group, images[chunk])
                guide, window_mean, window_inverse = rgb[images[chunk]], mean[which], inverse[:, which]
                for out, stack in zip(outputs, stacks, strict=True):
                    bands = np.asarray(stack[chunk], dtype=np.float32)
                    out[chunk] = _guided_shots(bands, guide, window_mean, window_inverse, float(sigma))
    return outputs


def _window_statistics(
    guides: np.ndarray, sigma: float, epsilon: float
) -> tuple[np.ndarray, np.ndarray]:
    """Window means ``(n, 3, h, w)`` float32 of RGB guides ``(n, 3, h, w)`` and the inverses
    of their ridged 3 x 3 covariances, ``(6, n, h, w)`` in the order of :data:`_UPPER`."""
    upper = np.triu_indices(3)
    mean = gaussian_window(guides, sigma)
    # the 6 distinct second moments of the symmetric 3 x 3 covariance
    second = gaussian_window(guides[:, upper[0]] * guides[:, upper[1]], sigma)
    covariance: dict[tuple[int, int], np.ndarray] = {}
    for n, (c, d) in enumerate(zip(upper[0].tolist(), upper[1].tolist(), strict=True)):
        covariance[c, d] = second[:, n] - mean[:, c].astype(np.float64) * mean[:, d]
    ridge = epsilon * np.sum(mean.astype(np.float64) ** 2, axis=1) / 3 + 1e-300
    for c in range(3):
        covariance[c, c] += ridge
    return mean, _symmetric_inverse(covariance)


def _guided_shots(
    bands: np.ndarray, guide: np.ndarray, mean: np.ndarray, inverse: np.ndarray, sigma: float
) -> np.ndarray:
    """Guided filter of shots ``bands`` ``(n, h, w)`` by their guides ``(n, 3, h, w)``, whose
    window means and covariance inverses are given (:func:`_window_statistics`)."""
    band_mean = gaussian_window(bands, sigma)
    cross = gaussian_window(guide * bands[:, None], sigma) - mean * band_mean[:, None]
    slope = np.empty_like(cross)
    for c in range(3):  # inverse @ cross per pixel (inverse is symmetric)
        slope[:, c] = inverse[_UPPER[c, 0]] * cross[:, 0]
        slope[:, c] += inverse[_UPPER[c, 1]] * cross[:, 1]
        slope[:, c] += inverse[_UPPER[c, 2]] * cross[:, 2]
    offset = band_mean - np.sum(slope * mean, axis=1)
    coefficients = gaussian_window(np.concatenate([slope, offset[:, None]], axis=1), sigma)
    return np.sum(coefficients[:, :3] * guide, axis=1) + coefficients[:, 3]


_UPPER = np.array([[0, 1, 2], [1, 3, 4], [2, 4, 5]])
"""Position of entry ``(c, d)`` of a symmetric 3 x 3 matrix among its 6 distinct entries
``(0,0), (0,1), (0,2), (1,1), (1,2), (2,2)``."""


def _symmetric_inverse(matrix: dict[tuple[int, int], np.ndarray]) -> np.ndarray:
    """Per pixel the inverse of a symmetric 3 x 3 matrix by its adjugate.

    ``matrix[c, d]`` (``c <= d``) are float64 planes; returns the inverse's 6 distinct
    entries ``(6, ...)`` (order of :data:`_UPPER`) as float32. The matrices are covariances
    plus a ridge (positive definite), so the determinant does not vanish; it is computed
    in float64, a vectorised closed form instead of a batched LU per pixel.
    """
    a, b, c = matrix[0, 0], matrix[0, 1], matrix[0, 2]
    d, e, f = matrix[1, 1], matrix[1, 2], matrix[2, 2]
    cofactors = [
        d * f - e * e,
        c * e - b * f,
        b * e - c * d,
        a * f - c * c,
        b * c - a * e,
        a * d - b * b,
    ]
    determinant = a * cofactors[0] + b * cofactors[1] + c * cofactors[2]
    inverse = np.empty((6,) + a.shape, dtype=np.float32)
    for n, cofactor in enumerate(cofactors):
        np.divide(cofactor, determinant, out=inverse[n], casting="same_kind")
    return inverse


def guided_filtered_projected(
    inputs: ReconstructionInputs,
    *,
    window_scale: float = GUIDED_WINDOW_SCALE,
    epsilon: float = GUIDED_EPSILON,
) -> np.ndarray:
    """:func:`guided_filtered_bands` projected per pixel onto ``C S(p) = R(p)``.

    Parameters
    ----------
    inputs, window_scale, epsilon
        As for :func:`guided_filtered_bands`.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``.
    """
    rgb = np.moveaxis(inputs.rgb, -1, 0)
    cube = guided_filtered_bands(inputs, window_scale=window_scale, epsilon=epsilon)
    return project_onto_rgb(cube, inputs.camera_matrix, rgb, overwrite=True)
