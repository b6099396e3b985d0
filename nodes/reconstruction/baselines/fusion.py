"""The data of the hyperspectral-multispectral fusion baselines ``"hysure"`` and ``"cnmf"``.

Remote sensing fuses a hyperspectral image of low spatial resolution ``Y_h`` with a
multispectral image of high spatial resolution ``Y_m``: ``Y_h = B Z`` (a spatial blur, and a
decimation this project does not have) and ``Y_m = R Z`` (a spectral response). Here
``Y_h`` is the band shots, each filtered by its own Gaussian (``sigma_i = s_i / 5``, eq. 3
of the paper), ``B_i`` that Gaussian, ``Y_m`` the HDR RGB and ``R = C``, all on one pixel
grid. A filtered shot is ``Y_i = B_i D_i = B_i S_{b_i} + B_i n_i``: the band ``b_i`` blurred
by the shot's own Gaussian, plus its filtered noise.

Every ``B_i`` is a Gaussian with reflecting borders (``scipy.ndimage``'s ``"reflect"``, the
filter :mod:`.filtered_bands` applies): a symmetric convolution with half-sample symmetric
borders, which the orthonormal type-II discrete cosine transform (DCT) diagonalises exactly,
as it does the Laplacian ``D_h^T D_h + D_v^T D_v`` of forward differences with Neumann
borders. :func:`blur_spectrum` gives the diagonal, so the fusion baselines apply ``B_i``,
``B_i^T B_i`` and their inverses plus a constant in the DCT domain, one band at a time.

References
----------
.. [1] Simoes, M., Bioucas-Dias, J., Almeida, L. B., Chanussot, J. (2015). A convex
   formulation for hyperspectral image superresolution via subspace-based regularization.
   IEEE Transactions on Geoscience and Remote Sensing 53(6), 3373-3388.
.. [2] Yokoya, N., Yairi, T., Iwasaki, A. (2012). Coupled nonnegative matrix factorization
   unmixing for hyperspectral and multispectral data fusion. IEEE Transactions on
   Geoscience and Remote Sensing 50(2), 528-537.
.. [3] Nascimento, J. M. P., Bioucas-Dias, J. M. (2005). Vertex component analysis: a fast
   algorithm to unmix hyperspectral data. IEEE Transactions on Geoscience and Remote
   Sensing 43(4), 898-910.
.. [4] Fast Capture of Spectral Image Series, section 3, "Filtering" and eq. 3.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from spectralize.nodes.filter_size import FILTER_TRUNCATE, filter_sigma
from spectralize.schemas.errors import ReconstructionError

from ..inputs import ReconstructionInputs
from .filtered_bands import _blur, filtered_bands

__all__ = [
    "FusionData",
    "fusion_data",
    "blur_spectrum",
    "difference_spectrum",
    "dct2",
    "idct2",
    "forward_differences",
    "adjoint_differences",
    "pure_pixels",
    "leading_subspace",
    "check_count",
]


@dataclass(frozen=True)
class FusionData:
    """The fusion baselines' data, divided by one scale so that the mean RGB signal is 1.

    Attributes
    ----------
    shots
        ``Y_i = B_i D_i``, ``(n_shot, height, width)``: every band shot filtered by its own
        Gaussian.
    band, image
        Per shot, its wavelength's index and its image's position.
    blur
        ``(n_shot, height, width)``: the DCT-II eigenvalues of ``B_i`` (:func:`blur_spectrum`).
    rgb
        ``Y_m``: ``(n_image, 3, height, width)``, RGB divided by the gain of ``C``.
    camera
        ``R``: ``(n_image, 3, n_wavelength)``, ``C_m`` divided by its gain (the mean row sum
        of ``|C|``), so the RGB term is in band units.
    start
        ``(n_wavelength, n_image, height, width)``: :func:`~.filtered_bands.filtered_bands`
        (a band an image has no shot of predicted from its RGB), scaled like the rest.
    scale
        What the scaled data were divided by: multiply a scaled cube by it.
    """

    shots: np.ndarray
    band: np.ndarray
    image: np.ndarray
    blur: np.ndarray
    rgb: np.ndarray
    camera: np.ndarray
    start: np.ndarray
    scale: float

    @property
    def n_wavelength(self) -> int:
        """Wavelengths of the spectra."""
        return self.camera.shape[2]

    @property
    def n_image(self) -> int:
        """Images of the set."""
        return self.rgb.shape[0]


def fusion_data(inputs: ReconstructionInputs, method: str) -> FusionData:
    """The checked, scaled data of a fusion baseline (:class:`FusionData`).

    Parameters
    ----------
    inputs
        The checked input arrays.
    method
        The baseline's name, for error messages.

    Raises
    ------
    ReconstructionError
        Naming ``bands``: no band shot at all (there is no hyperspectral image to fuse), or
        a wavelength no image has a shot of (its band cannot be estimated).
    """
    if inputs.band.size == 0:
        raise ReconstructionError(
            f"bands: method {method!r} fuses the filtered band shots (the hyperspectral image) "
            "with the RGB; expected at least one band shot, found none"
        )
    missing = np.setdiff1d(np.arange(inputs.n_wavelength), inputs.band)
    if missing.size:
        raise ReconstructionError(
            f"bands: method {method!r} expected a shot of every wavelength in some image of "
            f"the set, found none of {inputs.wavelength[missing].tolist()} nm"
        )
    cameras = np.stack([inputs.camera_of(m) for m in range(inputs.n_image)])
    gain = float(np.mean(np.abs(cameras).sum(axis=2)))
    rgb = np.moveaxis(inputs.rgb, -1, 1) / gain  # (n_image, 3, height, width)
    scale = float(np.mean(rgb))
    if not np.isfinite(scale) or scale <= 0:
        scale = 1.0
    shots = np.stack(
        [_blur(inputs.band_data[i], inputs.filter_size[i]) for i in range(inputs.band.size)]
    )
    height, width = inputs.height, inputs.width
    blur = np.stack([blur_spectrum(s, height, width) for s in inputs.filter_size])
    return FusionData(
        shots=shots / scale,
        band=np.asarray(inputs.band, dtype=np.intp),
        image=np.asarray(inputs.image, dtype=np.intp),
        blur=blur,
        rgb=rgb / scale,
        camera=cameras / gain,
        start=filtered_bands(inputs) / scale,
        scale=scale,
    )


def check_count(name: str, value: object, least: int) -> None:
    """Refuse a count (a dimension, endmembers, iterations) that is not an integer ``>=
    least``.

    Raises
    ------
    ReconstructionError
        Naming ``name``, what was expected and what was found.
    """
    number = float(value) if isinstance(value, numbers.Real) and not isinstance(value, bool) else None
    if number is None or not (np.isfinite(number) and number.is_integer() and number >= least):
        raise ReconstructionError(f"{name}: expected an integer >= {least}, found {value!r}")


# -- the DCT domain ------------------------------------------------------------------------------
def dct2(planes: np.ndarray) -> np.ndarray:
    """Orthonormal 2-D DCT-II over the last two axes (``y``, ``x``)."""
    from scipy import fft

    return fft.dctn(planes, type=2, norm="ortho", axes=(-2, -1))


def idct2(planes: np.ndarray) -> np.ndarray:
    """The inverse of :func:`dct2`."""
    from scipy import fft

    return fft.idctn(planes, type=2, norm="ortho", axes=(-2, -1))


def _gaussian_taps(filter_size: float) -> np.ndarray:
    """The taps of the paper's Gaussian of filter size ``s_i`` (``sigma = s_i / 5``, cut at
    ``FILTER_TRUNCATE`` sigmas and normalised to sum 1, as ``scipy.ndimage`` builds it)."""
    sigma = filter_sigma(filter_size)
    radius = int(FILTER_TRUNCATE * sigma + 0.5)
    offset = np.arange(-radius, radius + 1, dtype=np.float64)
    taps = np.exp(-0.5 * (offset / sigma) ** 2)
    return taps / taps.sum()


def _symmetric_eigenvalues(taps: np.ndarray, n: int) -> np.ndarray:
    """DCT-II eigenvalues ``sum_q k_q cos(pi j q / n)`` of the symmetric convolution with
    ``taps`` (odd length, centred) and half-sample symmetric borders, ``j = 0 .. n - 1``."""
    radius = taps.size // 2
    offset = np.arange(-radius, radius + 1, dtype=np.float64)
    return np.cos(np.pi * np.arange(n)[:, None] * offset[None, :] / n) @ taps


def blur_spectrum(filter_size: float, height: int, width: int) -> np.ndarray:
    """The DCT-II eigenvalues ``(height, width)`` of ``B_i``, the paper's Gaussian of filter
    size ``s_i`` with reflecting borders: ``dct2(B_i x) = blur_spectrum * dct2(x)``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filtering" (``sigma_i = s_i / 5``).
    """
    taps = _gaussian_taps(filter_size)
    return np.outer(_symmetric_eigenvalues(taps, height), _symmetric_eigenvalues(taps, width))


def difference_spectrum(height: int, width: int) -> np.ndarray:
    """The DCT-II eigenvalues ``(height, width)`` of ``D_h^T D_h + D_v^T D_v``
    (:func:`forward_differences` with Neumann borders): ``4 sin^2(pi k / 2n)`` per axis."""
    along_y = 4 * np.sin(np.pi * np.arange(height) / (2 * height)) ** 2
    along_x = 4 * np.sin(np.pi * np.arange(width) / (2 * width)) ** 2
    return along_y[:, None] + along_x[None, :]


def forward_differences(planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(D_h X, D_v X)``: forward differences along ``x`` and ``y`` of ``planes`` (``..., y,
    x``), zero at the last column and row (Neumann borders)."""
    horizontal = np.zeros_like(planes)
    vertical = np.zeros_like(planes)
    horizontal[..., :-1] = planes[..., 1:] - planes[..., :-1]
    vertical[..., :-1, :] = planes[..., 1:, :] - planes[..., :-1, :]
    return horizontal, vertical


def adjoint_differences(horizontal: np.ndarray, vertical: np.ndarray) -> np.ndarray:
    """``D_h^T H + D_v^T V``, the adjoint of :func:`forward_differences`."""
    out = np.zeros_like(horizontal)
    out[..., :-1] -= horizontal[..., :-1]
    out[..., 1:] += horizontal[..., :-1]
    out[..., :-1, :] -= vertical[..., :-1, :]
    out[..., 1:, :] += vertical[..., :-1, :]
    return out


# -- endmembers ----------------------------------------------------------------------------------
def pure_pixels(data: np.ndarray, count: int) -> np.ndarray:
    """``count`` endmember spectra ``(n_wavelength, count)`` picked among the pixels of
    ``data`` ``(n_wavelength, n_pixels)``: the pure-pixel search of vertex component analysis
    (VCA), in its deterministic form, the successive projection algorithm.

    The data are first projected onto their ``count`` leading singular vectors (as VCA does,
    which keeps the noise out of the search). Each endmember is then the pixel farthest from
    the span of those found so far: the pixel of largest norm after projecting the found
    ones out; VCA draws a random direction orthogonal to them instead.

    References
    ----------
    .. [1] Nascimento, J. M. P., Bioucas-Dias, J. M. (2005). Vertex component analysis.
       IEEE TGRS 43(4).
    .. [2] Araujo, M. C. U. et al. (2001). The successive projections algorithm for variable
       selection in spectroscopic multicomponent analysis. Chemometrics and Intelligent
       Laboratory Systems 57(2).
    """
    count = min(count, data.shape[0], data.shape[1])
    basis = leading_subspace(data, count)
    residual = basis.T @ data  # (count, n_pixels)
    picked: list[int] = []
    for _ in range(count):
        norms = np.einsum("kn,kn->n", residual, residual)
        norms[picked] = -1.0
        best = int(np.argmax(norms))
        picked.append(best)
        direction = residual[:, best] / max(float(np.linalg.norm(residual[:, best])), 1e-300)
        residual = residual - np.outer(direction, direction @ residual)
    return data[:, picked]


def leading_subspace(data: np.ndarray, count: int) -> np.ndarray:
    """``E``: an orthonormal basis ``(n_wavelength, count)`` of the ``count``-dimensional
    subspace that holds most of ``data`` ``(n_wavelength, n_pixels)``: its leading left
    singular vectors (the eigenvectors of ``data data^T``); ``count`` at most
    ``n_wavelength``."""
    values, vectors = np.linalg.eigh(data @ data.T)
    return vectors[:, np.argsort(values)[::-1][: min(count, data.shape[0])]]
