"""Baseline ``"hysure"``: hyperspectral superresolution by subspace-based regularisation.

HySure (Simoes et al. 2015) fuses a hyperspectral image of low spatial resolution with a
multispectral one of high resolution: the spectra live in a subspace ``Z = E X`` learnt from
the hyperspectral data, and ``X`` minimises two quadratic data terms plus a vector total
variation, by ADMM with the splits of SALSA. Here the hyperspectral image is the band shots
filtered by their Gaussians and the multispectral one the RGB (:mod:`.fusion`); every shot
has its own blur, so the blurred term is split in band space and solved band by band in the
DCT domain.

References
----------
.. [1] Simoes, M., Bioucas-Dias, J., Almeida, L. B., Chanussot, J. (2015). A convex
   formulation for hyperspectral image superresolution via subspace-based regularization.
   IEEE Transactions on Geoscience and Remote Sensing 53(6), 3373-3388.
.. [2] Afonso, M. V., Bioucas-Dias, J. M., Figueiredo, M. A. T. (2011). An augmented
   Lagrangian approach to the constrained optimization formulation of imaging inverse
   problems (SALSA). IEEE Transactions on Image Processing 20(3), 681-695.
.. [3] Fast Capture of Spectral Image Series, section 3, "Filtering" and eq. 3.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spectralize.schemas.errors import ReconstructionError

from ..inputs import ReconstructionInputs
from .fusion import (
    FusionData,
    adjoint_differences,
    check_count,
    dct2,
    difference_spectrum,
    forward_differences,
    fusion_data,
    idct2,
    leading_subspace,
)

__all__ = ["hysure", "HySureProblem", "hysure_problem", "hysure_admm", "hysure_objective"]


@dataclass(frozen=True)
class HySureProblem:
    """HySure's data for one image, scaled (:class:`~.fusion.FusionData`).

    Attributes
    ----------
    basis
        ``E``, ``(n_wavelength, p)`` orthonormal: the subspace of the spectra.
    shots, blur, band
        The image's filtered shots ``Y_i`` in the DCT domain, ``(n_shot, height, width)``,
        the DCT eigenvalues of their ``B_i`` and their bands.
    rgb
        ``Y_m``, ``(3, height, width)``.
    camera
        ``R``, ``(3, n_wavelength)``.
    start
        ``(n_wavelength, height, width)``: the filtered bands, where ADMM starts (``X_0 =
        E^T start``).
    """

    basis: np.ndarray
    shots: np.ndarray
    blur: np.ndarray
    band: np.ndarray
    rgb: np.ndarray
    camera: np.ndarray
    start: np.ndarray

    @property
    def observed(self) -> np.ndarray:
        """Per wavelength, whether the image has a shot of it (in the data term)."""
        return np.isin(np.arange(self.basis.shape[0]), self.band)

    def band_sums(self) -> tuple[np.ndarray, np.ndarray]:
        """``sum_i b_i Y_i`` and ``sum_i b_i^2`` per wavelength over the image's shots of it
        (DCT domain, ``(n_wavelength, height, width)``): the normal equations of the
        blurred term ``sum_i ||Y_i - B_i Z_{b_i}||^2``."""
        shape = (self.basis.shape[0], *self.rgb.shape[1:])
        numerator, denominator = np.zeros(shape), np.zeros(shape)
        np.add.at(numerator, self.band, self.blur * self.shots)
        np.add.at(denominator, self.band, self.blur**2)
        return numerator, denominator


def hysure(
    inputs: ReconstructionInputs,
    *,
    subspace: int = 4,
    lambda_m: float = 100.0,
    lambda_phi: float = 0.01,
    iterations: int = 100,
    mu: float = 0.5,
) -> np.ndarray:
    """HySure: the filtered band shots fused with the RGB in a subspace, with vector TV.

    Minimises, for every image, over ``X`` (``p`` coefficients per pixel, ``Z = E X``)

    .. math::

        \\frac{1}{2} \\sum_i \\lVert Y_i - B_i (E X)_{b_i} \\rVert^2
        + \\frac{\\lambda_m}{2} \\lVert Y_m - R E X \\rVert^2
        + \\lambda_\\varphi \\sum_p \\sqrt{\\textstyle\\sum_k (D_h X)_{kp}^2 + (D_v X)_{kp}^2}

    with ``Y_i`` a band shot filtered by its Gaussian ``B_i`` (``sigma_i = s_i / 5``), band
    ``b_i``; ``Y_m`` the RGB; ``R = C``; ``D_h``, ``D_v`` forward differences; ``E``
    ``(n_wavelength, p)`` orthonormal, the leading singular vectors of the filtered bands
    (:func:`~.filtered_bands.filtered_bands`) over every pixel of the set. The paper's
    decimation is left out: both images are on one grid. By ADMM (:func:`hysure_admm`) with
    the paper's splits, except that the blurred term's is ``V_1 = E X`` in band space (the
    paper's ``V_1 = X B`` needs one blur for every band); its step is solved band by band
    in the DCT domain. The data are scaled so that the mean RGB is 1 in band units, so the
    weights do not depend on the radiance scale.

    A set is solved image by image with one ``E``; an image's data term holds the shots of
    that image only. A band an image has no shot of is not in its data term; where its
    shots and the RGB leave directions of ``X`` free (an image with fewer shots than ``p -
    3``, none in a set's images without bands), they stay near the start, ``E^T`` times
    the filtered bands, whose missing bands are predicted from the RGB.

    Parameters
    ----------
    inputs
        The checked input arrays.
    subspace
        ``p``, the subspace's dimension (at most the number of wavelengths).
    lambda_m
        ``lambda_m``: the weight of the RGB term.
    lambda_phi
        ``lambda_phi``: the weight of the vector total variation.
    iterations
        ADMM iterations per image.
    mu
        The augmented Lagrangian's penalty ``mu``.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)``.

    Raises
    ------
    ReconstructionError
        No band shot at all, or a wavelength without a shot in any image (naming
        ``bands``), or a setting out of range (naming it).

    References
    ----------
    .. [1] Simoes, M., Bioucas-Dias, J., Almeida, L. B., Chanussot, J. (2015). A convex
       formulation for hyperspectral image superresolution via subspace-based
       regularization. IEEE TGRS 53(6), eqs. 3-6 and section III.
    .. [2] Fast Capture of Spectral Image Series, section 3, "Filtering" and eq. 3.
    """
    _check_settings(subspace, lambda_m, lambda_phi, iterations, mu)
    data = fusion_data(inputs, "hysure")
    basis = leading_subspace(data.start.reshape(data.n_wavelength, -1), int(subspace))
    cube = np.empty(inputs.cube_shape)
    for m in range(data.n_image):
        problem = hysure_problem(data, m, basis)
        coefficients, _ = hysure_admm(
            problem, lambda_m=lambda_m, lambda_phi=lambda_phi, mu=mu, iterations=int(iterations)
        )
        cube[:, m] = _mix(basis, coefficients) * data.scale
    return cube


def _check_settings(
    subspace: int, lambda_m: float, lambda_phi: float, iterations: int, mu: float
) -> None:
    """Refuse settings out of range, naming the setting."""
    check_count("subspace", subspace, 1)
    check_count("iterations", iterations, 0)
    for name, weight in (("lambda_m", lambda_m), ("lambda_phi", lambda_phi), ("mu", mu)):
        positive = name == "mu"
        if not np.isfinite(weight) or weight < 0 or (positive and weight == 0):
            wanted = "> 0" if positive else ">= 0"
            raise ReconstructionError(f"{name}: expected a finite number {wanted}, found {weight!r}")


def hysure_problem(data: FusionData, image: int, basis: np.ndarray) -> HySureProblem:
    """The :class:`HySureProblem` of image ``image`` of ``data`` in the subspace ``basis``."""
    mine = np.flatnonzero(data.image == image)
    return HySureProblem(
        basis=basis,
        shots=dct2(data.shots[mine]),
        blur=data.blur[mine],
        band=data.band[mine],
        rgb=data.rgb[image],
        camera=data.camera[image],
        start=data.start[:, image],
    )


def _mix(matrix: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """``matrix @ planes`` over the leading axis of ``planes`` (``(k, height, width)``)."""
    return (matrix @ planes.reshape(planes.shape[0], -1)).reshape(-1, *planes.shape[1:])


def hysure_admm(
    problem: HySureProblem,
    *,
    lambda_m: float,
    lambda_phi: float,
    mu: float,
    iterations: int,
    record_objective: bool = False,
) -> tuple[np.ndarray, list[float]]:
    """HySure's ADMM (SALSA) on one image: ``X`` ``(p, height, width)`` and, with
    ``record_objective``, :func:`hysure_objective` at the start and after every iteration.

    The splits ``V_1 = E X`` (band space), ``V_2 = X``, ``V_3 = D_h X``, ``V_4 = D_v X``
    with scaled duals ``D_1 .. D_4``; per iteration

    - ``X``: ``(E^T (V_1 + D_1) + V_2 + D_2 + D_h^T (V_3 + D_3) + D_v^T (V_4 + D_4)) / (2 +
      D_h^T D_h + D_v^T D_v)``, diagonal in the DCT domain (``E^T E = I``);
    - ``V_1``: per band ``b`` with shots, ``(sum_i B_i^T Y_i + mu W_b) / (sum_i B_i^T B_i +
      mu)`` with ``W = E X - D_1``, diagonal in the DCT domain; ``W_b`` for a band without;
    - ``V_2``: ``(lambda_m E^T R^T R E + mu I)^-1 (lambda_m E^T R^T Y_m + mu (X - D_2))``
      per pixel;
    - ``V_3, V_4``: the vector soft threshold of ``(D_h X - D_3, D_v X - D_4)`` at
      ``lambda_phi / mu`` (the norm per pixel over both differences of every coefficient);
    - ``D_j``: ``D_j - (G_j X - V_j)``.

    ``V_1`` and ``D_1`` are kept in the DCT domain.

    References
    ----------
    .. [1] Simoes et al. (2015), section III (SALSA); Afonso et al. (2011).
    """
    basis = problem.basis
    p = basis.shape[1]
    numerator, denominator = problem.band_sums()
    observed = problem.observed[:, None, None]
    x_denominator = 2.0 + difference_spectrum(*problem.rgb.shape[1:])
    spectral = problem.camera @ basis  # R E, (3, p)
    v2_inverse = np.linalg.inv(lambda_m * spectral.T @ spectral + mu * np.eye(p))
    rgb_term = lambda_m * _mix(spectral.T, problem.rgb)
    x = _mix(basis.T, problem.start)
    x_hat = dct2(x)
    v1_hat, d1_hat = _mix(basis, x_hat), np.zeros((basis.shape[0], *x.shape[1:]))
    v2, d2 = x.copy(), np.zeros_like(x)
    (v3, v4), d3, d4 = forward_differences(x), np.zeros_like(x), np.zeros_like(x)
    history = [hysure_objective(problem, x, lambda_m, lambda_phi)] if record_objective else []
    for _ in range(iterations):
        rest = v2 + d2 + adjoint_differences(v3 + d3, v4 + d4)
        x_hat = (dct2(rest) + _mix(basis.T, v1_hat + d1_hat)) / x_denominator
        x = idct2(x_hat)
        w_hat = _mix(basis, x_hat) - d1_hat
        v1_hat = np.where(observed, (numerator + mu * w_hat) / (denominator + mu), w_hat)
        d1_hat = v1_hat - w_hat
        target = x - d2
        v2 = _mix(v2_inverse, rgb_term + mu * target)
        d2 = v2 - target
        horizontal, vertical = forward_differences(x)
        horizontal -= d3
        vertical -= d4
        norm = np.sqrt(np.sum(horizontal**2 + vertical**2, axis=0))
        shrink = np.maximum(0.0, 1.0 - (lambda_phi / mu) / np.maximum(norm, 1e-300))
        v3, v4 = horizontal * shrink, vertical * shrink
        d3, d4 = v3 - horizontal, v4 - vertical
        if record_objective:
            history.append(hysure_objective(problem, x, lambda_m, lambda_phi))
    return x, history


def hysure_objective(problem: HySureProblem, x: np.ndarray, lambda_m: float, lambda_phi: float) -> float:
    """HySure's objective (:func:`hysure`) at ``X`` ``(p, height, width)`` for one image."""
    spectra_hat = _mix(problem.basis, dct2(x))
    blurred = 0.5 * float(np.sum((problem.shots - problem.blur * spectra_hat[problem.band]) ** 2))
    rgb = 0.5 * lambda_m * float(np.sum((problem.rgb - _mix(problem.camera @ problem.basis, x)) ** 2))
    horizontal, vertical = forward_differences(x)
    total_variation = float(np.sum(np.sqrt(np.sum(horizontal**2 + vertical**2, axis=0))))
    return blurred + rgb + lambda_phi * total_variation
