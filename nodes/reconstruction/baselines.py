"""Baseline spectral reconstructions, for comparison with eq. 1 on the same data.

Every baseline takes a :class:`~spectralize.nodes.reconstruction.inputs.ReconstructionInputs`
and returns a cube ``(n_wavelength, n_image, height, width)``. :data:`BASELINE_METHODS` is
the dispatch table (as colour-science's ``XYZ_TO_SD_METHODS``):

``"pseudo-inverse"``
    ``S = C^+ R`` (Imai and Berns): the minimum-norm spectrum with the measured RGB.
``"wiener"``
    Wiener estimation / linear regression ``S = K C^T (C K C^T + s I)^-1 R`` with the
    second-moment matrix ``K`` of the 190 training reflectances colour-science ships
    (RAW to ACES v1) lit by an illuminant estimated from the bands.
``"mallett2019"``
    colour-science's Mallett and Yuksel (2019) reflectance basis, lit by the same illuminant
    estimate, with coefficients that reproduce the camera RGB exactly.
``"filtered-bands"``
    The band images filtered by their Gaussian (sigma = s_i / 5) alone; a band an image has
    no shot of is predicted from its RGB by a linear fit on the images that have it.
``"filtered-projected"``
    ``filtered-bands`` projected per pixel onto the RGB constraint ``C S = R``:
    ``S = B + C^T (C C^T)^-1 (R - C B)``.
``"guided-projected"``
    Every band image filtered with the RGB image as guide (He et al.'s guided filter with
    Gaussian windows): per window the band is the affine function of RGB that best fits the
    noisy band, ``S_b(p) = a(p)^T R(p) + c(p)``; then projected onto ``C S = R``. The default
    solver's initial guess and prior.

References
----------
.. [1] Imai, F. H., Berns, R. S. (1998). High-resolution multi-spectral image archives: a
   hybrid approach. Color Imaging Conference.
.. [2] Hardeberg, J. Y., Schmitt, F., Brettel, H. (1999). Multispectral image capture using
   a tunable filter. (Wiener-type estimation with prior knowledge of spectra.)
.. [3] Mallett, I., Yuksel, C. (2019). Spectral Primary Decomposition for Rendering with
   sRGB Reflectance. Eurographics Symposium on Rendering.
.. [4] Fast Capture of Spectral Image Series, section 2 ("Hybrid Methods") and section 3.
.. [5] He, K., Sun, J., Tang, X. (2013). Guided Image Filtering. IEEE TPAMI 35(6).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from scipy import ndimage

from .inputs import ReconstructionInputs
from .operators import SIGMA_PER_FILTER_SIZE

__all__ = [
    "BASELINE_METHODS",
    "pseudo_inverse",
    "wiener_estimation",
    "mallett2019_basis",
    "filtered_bands",
    "filtered_bands_projected",
    "guided_filtered_bands",
    "guided_filtered_projected",
    "GUIDED_WINDOW_SCALE",
    "GUIDED_EPSILON",
    "project_onto_rgb",
    "training_reflectances",
    "estimate_illuminant",
]


def _blur(plane: np.ndarray, filter_size: float) -> np.ndarray:
    sigma = SIGMA_PER_FILTER_SIZE * filter_size
    return ndimage.gaussian_filter(plane, sigma=sigma, mode="reflect", truncate=5.0)


def project_onto_rgb(cube: np.ndarray, camera_matrix: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Smallest per-pixel change of ``cube`` that makes ``C S(p) = R(p)`` exact.

    ``S = B + C^T (C C^T)^-1 (R - C B)``.

    Parameters
    ----------
    cube
        ``(n_wavelength, ...)`` spectra ``B``.
    camera_matrix
        ``C``, ``(3, n_wavelength)``.
    rgb
        ``R``, ``(3, ...)`` with the same trailing shape as ``cube``.
    """
    n_wavelength = cube.shape[0]
    flat = cube.reshape(n_wavelength, -1)
    gap = rgb.reshape(3, -1) - camera_matrix @ flat
    correction = camera_matrix.T @ np.linalg.solve(camera_matrix @ camera_matrix.T, gap)
    return (flat + correction).reshape(cube.shape)


def pseudo_inverse(inputs: ReconstructionInputs) -> np.ndarray:
    """RGB pseudo-inverse, ``S(p) = C^+ R(p)`` (Imai and Berns).

    References
    ----------
    .. [1] Imai and Berns (1998); Fast Capture of Spectral Image Series, section 2.
    """
    rgb = inputs.rgb_pixels()
    return (np.linalg.pinv(inputs.camera_matrix) @ rgb).reshape(inputs.cube_shape)


@lru_cache(maxsize=4)
def _rawtoaces_training() -> tuple[np.ndarray, np.ndarray]:
    import colour

    data = colour.characterisation.read_training_data_rawtoaces_v1()
    return np.asarray(data.wavelengths, dtype=np.float64), np.asarray(data.values, np.float64)


def training_reflectances(wavelength: np.ndarray) -> np.ndarray:
    """The 190 RAW-to-ACES v1 training reflectances colour-science ships, on ``wavelength``.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, 190)``, linearly interpolated.
    """
    grid, values = _rawtoaces_training()
    return np.stack([np.interp(wavelength, grid, values[:, j]) for j in range(values.shape[1])],
                    axis=1)


def estimate_illuminant(inputs: ReconstructionInputs, reflectances: np.ndarray) -> np.ndarray:
    """A spectral illuminant estimate from the band data.

    The mean band radiance per wavelength (noise averages out over all pixels), each shot
    first divided by the mean RGB of its image relative to the whole set (so that shots of
    differently lit images of a set compare), divided by the mean training reflectance.
    """
    rgb_mean = inputs.rgb.mean(axis=(1, 2, 3))
    brightness = rgb_mean / max(float(rgb_mean.mean()), 1e-30)
    shot_mean = inputs.band_data.reshape(len(inputs.band), -1).mean(axis=1)
    shot_mean = shot_mean / np.maximum(brightness[inputs.image], 1e-12)
    sums = np.bincount(inputs.band, weights=shot_mean, minlength=inputs.n_wavelength)
    counts = np.bincount(inputs.band, minlength=inputs.n_wavelength)
    mean_radiance = sums / np.maximum(counts, 1)
    illuminant = mean_radiance / np.maximum(reflectances.mean(axis=1), 1e-6)
    floor = 1e-3 * max(float(np.abs(illuminant).max()), 1e-30)
    return np.maximum(illuminant, floor)


def wiener_estimation(inputs: ReconstructionInputs, *, relative_noise: float = 1e-4
                      ) -> np.ndarray:
    """Wiener estimation (linear regression) from RGB with a training-set prior.

    ``S = K C^T (C K C^T + s I)^-1 R`` with ``K = E[t t^T]`` over the training radiances
    ``t = diag(L) rho`` (colour-science's RAW-to-ACES reflectances ``rho``, illuminant ``L``
    from :func:`estimate_illuminant`) and ``s = relative_noise * trace(C K C^T) / 3``.

    References
    ----------
    .. [1] Hardeberg et al. (1999); Fast Capture of Spectral Image Series, section 2.
    """
    reflectances = training_reflectances(inputs.wavelength)
    radiances = estimate_illuminant(inputs, reflectances)[:, None] * reflectances
    second_moment = radiances @ radiances.T / radiances.shape[1]
    c = inputs.camera_matrix
    projected = c @ second_moment @ c.T
    noise = relative_noise * np.trace(projected) / 3
    operator = second_moment @ c.T @ np.linalg.inv(projected + noise * np.eye(3))
    return (operator @ inputs.rgb_pixels()).reshape(inputs.cube_shape)


def mallett2019_basis(inputs: ReconstructionInputs) -> np.ndarray:
    """colour-science's Mallett and Yuksel (2019) basis, fitted to the camera RGB.

    The three sRGB basis reflectances of ``colour.recovery`` lit by the estimated illuminant
    span the spectra; per pixel the three coefficients reproduce ``R(p)`` exactly. (The
    library's ``RGB_to_sd_Mallett2019`` takes sRGB reflectance; here the camera matrix
    replaces the sRGB observer so that any camera's HDR radiance can be used.)

    References
    ----------
    .. [1] Mallett and Yuksel (2019).
    """
    import colour

    basis_sds = colour.recovery.MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019
    grid = np.asarray(basis_sds.wavelengths, dtype=np.float64)
    basis = np.stack([np.interp(inputs.wavelength, grid, basis_sds.values[:, j])
                      for j in range(3)], axis=1)  # (n_wavelength, 3)
    reflectances = training_reflectances(inputs.wavelength)
    lit = estimate_illuminant(inputs, reflectances)[:, None] * basis
    coefficients = np.linalg.solve(inputs.camera_matrix @ lit, inputs.rgb_pixels())
    return (lit @ coefficients).reshape(inputs.cube_shape)


def filtered_bands(inputs: ReconstructionInputs) -> np.ndarray:
    """Every band image filtered by its own Gaussian (``sigma = s_i / 5``) alone.

    Shots of the same band and image are averaged. An image without a shot of band ``b``
    gets ``w_b^T R(p)``, where ``w_b`` is the least-squares fit of the filtered band to the
    equally filtered RGB over the images that have the band.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filtering".
    """
    cube = np.zeros(inputs.cube_shape)
    counts = np.zeros(inputs.cube_shape[:2])
    for i in range(len(inputs.band)):
        cube[inputs.band[i], inputs.image[i]] += _blur(inputs.band_data[i],
                                                       inputs.filter_size[i])
        counts[inputs.band[i], inputs.image[i]] += 1
    have = counts > 0
    cube[have] /= counts[have][:, None, None]
    for b in np.flatnonzero(~have.all(axis=1)):
        images = np.flatnonzero(have[b])
        size = float(np.mean(inputs.filter_size[inputs.band == b]))
        design = np.concatenate([
            np.stack([_blur(inputs.rgb[m, ..., c], size) for c in range(3)], axis=-1)
            .reshape(-1, 3) for m in images])
        response = cube[b, images].reshape(-1)
        weights, *_ = np.linalg.lstsq(design, response, rcond=None)
        for m in np.flatnonzero(~have[b]):
            cube[b, m] = inputs.rgb[m] @ weights
    return cube


def filtered_bands_projected(inputs: ReconstructionInputs) -> np.ndarray:
    """:func:`filtered_bands` projected per pixel onto ``C S(p) = R(p)``."""
    rgb = np.moveaxis(inputs.rgb, -1, 0)  # (3, n_image, height, width)
    return project_onto_rgb(filtered_bands(inputs), inputs.camera_matrix, rgb)


GUIDED_WINDOW_SCALE = 3.0
"""Guided-filter window ``sigma`` in units of the band's filter ``sigma_i = s_i / 5``."""

GUIDED_EPSILON = 1e-4
"""Ridge on the guided filter's RGB slopes, relative to the window's mean ``|R|^2``."""


GUIDED_WINDOW_STEP = 1.05
"""Window sigmas are rounded to a geometric grid of this ratio, so that bands of nearly the
same filter size share one window's RGB statistics (a window is a modelling choice; 2.5 %
in its size changes nothing measurable)."""


def _window_sigma(filter_size: float, window_scale: float) -> float:
    sigma = SIGMA_PER_FILTER_SIZE * filter_size * window_scale
    step = np.log(GUIDED_WINDOW_STEP)
    return float(np.exp(np.round(np.log(sigma) / step) * step))


def _gaussian_window(planes: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian-weighted local mean over the last two axes (reflecting borders)."""
    sigmas = (0.0,) * (planes.ndim - 2) + (sigma, sigma)
    return ndimage.gaussian_filter(planes, sigma=sigmas, mode="reflect", truncate=3.0)


def guided_filtered_bands(inputs: ReconstructionInputs, *,
                          window_scale: float = GUIDED_WINDOW_SCALE,
                          epsilon: float = GUIDED_EPSILON) -> np.ndarray:
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
    rgb = np.moveaxis(inputs.rgb, -1, 1).astype(np.float32)  # (n_image, 3, height, width)
    cube = np.zeros(inputs.cube_shape)
    counts = np.zeros(inputs.cube_shape[:2])
    upper = np.triu_indices(3)
    sigmas = [_window_sigma(float(size), window_scale) for size in inputs.filter_size]
    statistics: tuple[tuple[int, float], np.ndarray, np.ndarray] | None = None
    # shots in order of image and window, so that one window's statistics serve them all
    for i in sorted(range(len(inputs.band)), key=lambda i: (inputs.image[i], sigmas[i])):
        b, m, sigma = inputs.band[i], inputs.image[i], sigmas[i]
        if statistics is None or statistics[0] != (m, sigma):
            guide = rgb[m]
            mean = _gaussian_window(guide, sigma)
            # the 6 distinct second moments of the symmetric 3 x 3 covariance
            second = _gaussian_window(guide[upper[0]] * guide[upper[1]], sigma)
            covariance = np.empty((3, 3) + guide.shape[1:], dtype=np.float64)
            for n, (c, d) in enumerate(zip(*upper, strict=True)):
                covariance[c, d] = covariance[d, c] = second[n] - mean[c] * mean[d]
            ridge = epsilon * np.sum(mean.astype(np.float64)**2, axis=0) / 3 + 1e-300
            covariance[[0, 1, 2], [0, 1, 2]] += ridge
            inverse = np.linalg.inv(np.moveaxis(covariance, (0, 1), (2, 3))).astype(np.float32)
            statistics = ((m, sigma), mean, inverse)
        _, mean, inverse = statistics
        guide = rgb[m]
        band = inputs.band_data[i].astype(np.float32)
        band_mean = _gaussian_window(band, sigma)
        cross = _gaussian_window(guide * band[None], sigma) - mean * band_mean[None]
        slope = np.einsum("yxcd,dyx->cyx", inverse, cross)
        offset = band_mean - np.sum(slope * mean, axis=0)
        coefficients = _gaussian_window(np.concatenate([slope, offset[None]]), sigma)
        cube[b, m] += np.sum(coefficients[:3] * guide, axis=0) + coefficients[3]
        counts[b, m] += 1
    have = counts > 0
    cube[have] /= counts[have][:, None, None]
    if not have.all():
        fallback = filtered_bands(inputs)
        cube[~have] = fallback[~have]
    return cube


def guided_filtered_projected(inputs: ReconstructionInputs, **options) -> np.ndarray:
    """:func:`guided_filtered_bands` projected per pixel onto ``C S(p) = R(p)``."""
    rgb = np.moveaxis(inputs.rgb, -1, 0)
    return project_onto_rgb(guided_filtered_bands(inputs, **options), inputs.camera_matrix,
                            rgb)


BASELINE_METHODS: dict[str, Callable[[ReconstructionInputs], np.ndarray]] = {
    "pseudo-inverse": pseudo_inverse,
    "wiener": wiener_estimation,
    "mallett2019": mallett2019_basis,
    "filtered-bands": filtered_bands,
    "filtered-projected": filtered_bands_projected,
    "guided-projected": guided_filtered_projected,
}
"""Baselines by name; see the module docstring."""
