"""Baseline ``"cnmf"``: coupled nonnegative matrix factorisation unmixing.

CNMF (Yokoya et al. 2012) fuses a hyperspectral image of low spatial resolution with a
multispectral one of high resolution by unmixing both into endmembers and abundances with
Lee and Seung's multiplicative updates, alternately: the hyperspectral image's endmembers
``W_h`` set the multispectral ones (``W_m = R W_h``), the multispectral image's abundances
``H_m`` set the hyperspectral ones (``H_h = B H_m``), and the fused image is ``Z = W_h
H_m``. Here the hyperspectral image is the band shots filtered by their Gaussians and the
multispectral one the RGB (:mod:`.fusion`); every shot has its own blur ``B_i``.

References
----------
.. [1] Yokoya, N., Yairi, T., Iwasaki, A. (2012). Coupled nonnegative matrix factorization
   unmixing for hyperspectral and multispectral data fusion. IEEE Transactions on
   Geoscience and Remote Sensing 50(2), 528-537.
.. [2] Lee, D. D., Seung, H. S. (2001). Algorithms for non-negative matrix factorization.
   Advances in Neural Information Processing Systems 13.
.. [3] Fast Capture of Spectral Image Series, section 3, "Filtering" and eq. 3.
"""

from __future__ import annotations

import numpy as np

from ..inputs import ReconstructionInputs
from .fusion import FusionData, check_count, dct2, fusion_data, pure_pixels

__all__ = ["cnmf", "coupled_endmembers", "multiplicative_abundances", "multiplicative_endmembers"]

_TINY = 1e-12
"""Added to the denominators of the multiplicative updates (and the floor of a factor), so
that a zero never divides and a factor never sticks at zero."""


def cnmf(
    inputs: ReconstructionInputs,
    *,
    n_endmembers: int = 6,
    outer_iterations: int = 3,
    inner_iterations: int = 100,
) -> np.ndarray:
    """CNMF: the filtered band shots and the RGB unmixed alternately, coupled by ``B`` and ``R``.

    Fits ``Z = W_h H_m`` (``W_h`` ``(n_wavelength, M)`` endmember spectra, ``H_m`` ``(M,
    n_pixels)`` abundances, both ``>= 0``) to the two images by alternating the
    nonnegative factorisations

    .. math::

        \\min_{W_h \\ge 0} \\sum_i \\lVert Y_i - w_{b_i}^T (B_i H_m) \\rVert^2
        \\quad\\text{and}\\quad
        \\min_{H_m \\ge 0} \\lVert Y_m - (R W_h) H_m \\rVert^2

    with ``Y_i`` a band shot filtered by its Gaussian ``B_i`` (``sigma_i = s_i / 5``) and
    ``w_b^T`` row ``b`` of ``W_h``; ``Y_m`` the RGB; ``R = C``. Following the paper:

    1. ``W_h`` starts at ``M`` pure pixels of the filtered bands
       (:func:`~.fusion.pure_pixels`, VCA's search in its deterministic form), and the
       filtered bands are unmixed (``H_h`` from ``1/M``, updated with ``W_h`` fixed, then
       both alternately; the paper's hyperspectral unmixing, at full resolution here as
       there is no decimation);
    2. ``W_m = R W_h`` and ``H_m`` starts at ``H_h`` (the paper upsamples ``H_h``; here it
       is on the pixel grid already), updated with ``W_m`` fixed;
    3. ``outer_iterations`` times: the hyperspectral step updates ``W_h`` with the coupled
       abundances ``B_i H_m`` fixed, shot by shot (:func:`coupled_endmembers`), and the
       multispectral step ``H_m`` with ``W_m = R W_h`` fixed.

    Each step takes ``inner_iterations`` multiplicative updates. The paper also refines the
    factor the coupling sets (``H_h`` in the hyperspectral step, ``W_m`` in the
    multispectral one); here each step updates only the other: with a blur per shot, the
    hyperspectral abundances are no single matrix, and a ``W_m`` refined apart from ``R
    W_h`` would let ``H_m`` fit RGB that ``W_h H_m`` does not reproduce. The abundances'
    sum-to-one constraint of the paper is left out: shading scales a pixel's abundances.
    Negative filtered band values (noise) are set to 0 in step 1 and enter step 3 only
    through sums over whole images. A set is unmixed with one ``W_h`` for all its images
    (one scene, the same materials) and ``H_m`` per image; an image without shots gets its
    ``H_m`` from its RGB, started from the filtered bands, whose missing bands are
    predicted from the RGB. The data are scaled so that the mean RGB is 1 in band units.

    Parameters
    ----------
    inputs
        The checked input arrays.
    n_endmembers
        ``M``, the number of endmembers (at most the number of wavelengths).
    outer_iterations
        Alternations of the hyperspectral and multispectral steps (step 3).
    inner_iterations
        Multiplicative updates per step.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``, ``>= 0``.

    Raises
    ------
    ReconstructionError
        No band shot at all, or a wavelength without a shot in any image (naming
        ``bands``), or a setting out of range (naming it).

    References
    ----------
    .. [1] Yokoya, N., Yairi, T., Iwasaki, A. (2012). Coupled nonnegative matrix
       factorization unmixing for hyperspectral and multispectral data fusion. IEEE TGRS
       50(2), section III.
    .. [2] Fast Capture of Spectral Image Series, section 3, "Filtering" and eq. 3.
    """
    check_count("n_endmembers", n_endmembers, 1)
    check_count("outer_iterations", outer_iterations, 0)
    check_count("inner_iterations", inner_iterations, 0)
    data = fusion_data(inputs, "cnmf")
    inner = int(inner_iterations)
    n_wavelength, n_image = data.n_wavelength, data.n_image
    start = np.maximum(data.start, 0.0).reshape(n_wavelength, -1)
    w_h = np.maximum(pure_pixels(start, int(n_endmembers)), _TINY + 1e-3 * float(start.mean()))
    h_h = np.full((w_h.shape[1], start.shape[1]), 1.0 / w_h.shape[1])
    h_h = multiplicative_abundances(start, w_h, h_h, inner)
    for _ in range(inner):
        w_h = multiplicative_endmembers(start, w_h, h_h, 1)
        h_h = multiplicative_abundances(start, w_h, h_h, 1)
    h_m = h_h.reshape(w_h.shape[1], n_image, -1)
    h_m = _multispectral_step(data, w_h, h_m, inner)
    filtered_twice = (data.blur * dct2(data.shots)).reshape(data.shots.shape[0], -1)
    for _ in range(int(outer_iterations)):
        w_h = coupled_endmembers(data, w_h, h_m, inner, filtered_twice)
        h_m = _multispectral_step(data, w_h, h_m, inner)
    cube = np.einsum("wk,kmn->wmn", w_h, h_m) * data.scale
    return cube.reshape(inputs.cube_shape)


def multiplicative_abundances(
    y: np.ndarray, w: np.ndarray, h: np.ndarray, iterations: int
) -> np.ndarray:
    """``iterations`` of Lee and Seung's update of ``H >= 0`` in ``min ||Y - W H||^2`` with
    ``W`` fixed: ``H <- H * (W^T Y)_+ / (W^T W H)``; ``Y`` ``(channels, n)``, ``W``
    ``(channels, M)``, ``H`` ``(M, n)``."""
    numerator = np.maximum(w.T @ y, 0.0)
    gram = w.T @ w
    for _ in range(iterations):
        h = h * numerator / (gram @ h + _TINY)
    return h


def multiplicative_endmembers(
    y: np.ndarray, w: np.ndarray, h: np.ndarray, iterations: int
) -> np.ndarray:
    """``iterations`` of Lee and Seung's update of ``W >= 0`` in ``min ||Y - W H||^2`` with
    ``H`` fixed: ``W <- W * (Y H^T)_+ / (W H H^T)``."""
    numerator = np.maximum(y @ h.T, 0.0)
    gram = h @ h.T
    for _ in range(iterations):
        w = w * numerator / (w @ gram + _TINY)
    return w


def _multispectral_step(
    data: FusionData, w_h: np.ndarray, h_m: np.ndarray, iterations: int
) -> np.ndarray:
    """CNMF's multispectral step: every image's ``H_m`` ``(M, n_image, n_pixels)`` updated
    with ``W_m = R_m W_h`` fixed (its own camera's ``R_m``)."""
    out = np.empty_like(h_m)
    for m in range(data.n_image):
        rgb = np.maximum(data.rgb[m].reshape(3, -1), 0.0)
        out[:, m] = multiplicative_abundances(rgb, data.camera[m] @ w_h, h_m[:, m], iterations)
    return out


def coupled_endmembers(
    data: FusionData,
    w_h: np.ndarray,
    h_m: np.ndarray,
    iterations: int,
    filtered_twice: np.ndarray | None = None,
) -> np.ndarray:
    """CNMF's hyperspectral step: ``W_h`` ``(n_wavelength, M)`` updated with the coupled
    abundances fixed, ``iterations`` times; ``filtered_twice`` ``(n_shot, n_pixels)``, the
    shots' ``b_i Y_i^`` (computed when not given).

    Shot ``i`` sees ``Y_i = w_{b_i}^T (B_i H_m)``, ``H_m`` of its image blurred by its own
    Gaussian, so row ``b`` of ``W_h`` is updated as ``w_b <- w_b * (sum_i <Y_i, B_i H_m>)_+ /
    (w_b^T sum_i (B_i H_m)(B_i H_m)^T)`` over the shots of band ``b``. ``B_i`` is symmetric
    and diagonal in the DCT domain (:func:`~.fusion.blur_spectrum`), so both sums are taken
    there: ``<Y_i, B_i h_k> = <b_i Y_i^, h_k^>`` and ``<B_i h_k, B_i h_l> = <b_i^2 h_k^,
    h_l^>``.
    """
    n_endmember = w_h.shape[1]
    shape = data.shots.shape[1:]
    spectra = dct2(h_m.reshape(n_endmember, data.n_image, *shape)).reshape(n_endmember, data.n_image, -1)
    if filtered_twice is None:
        filtered_twice = (data.blur * dct2(data.shots)).reshape(data.shots.shape[0], -1)
    blur = data.blur.reshape(data.blur.shape[0], -1)
    numerator = np.zeros_like(w_h)
    gram = np.zeros((w_h.shape[0], n_endmember, n_endmember))
    for i, (band, image) in enumerate(zip(data.band, data.image, strict=True)):
        abundances = spectra[:, image]
        numerator[band] += abundances @ filtered_twice[i]
        gram[band] += (abundances * blur[i] ** 2) @ abundances.T
    numerator = np.maximum(numerator, 0.0)
    gram = np.maximum(gram, 0.0)
    for _ in range(iterations):
        w_h = w_h * numerator / (np.einsum("bk,bkl->bl", w_h, gram) + _TINY)
    return w_h
