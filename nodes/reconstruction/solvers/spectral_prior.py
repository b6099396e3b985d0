"""The spectral prior: a soft per-pixel Gaussian prior on the spectrum's shape.

The term

``sum_p w_p (S_p - m_p)^T Q (S_p - m_p)``

* ``Q = (Sigma / mean(diag Sigma) + delta I)^-1`` with ``Sigma`` the covariance of sample
  spectra, each normalised by its level: cheap along the samples' typical spectral
  variations, expensive along shapes none of them has;
* ``m_p``: the Wiener estimate from the pixel's RGB with the samples' second moment ``K``,
  ``K C^T (C K C^T + s I)^-1 R_p`` (as baseline ``"wiener"``), linear in ``R`` so it scales
  with the pixel; or, with the ``"mixture"`` source, the endmember-mixture estimate;
* ``w_p = weight * mean(diag A^T A) / max(b_p, b_min)^2`` with ``b_p`` the pixel's RGB
  brightness relative to its image's mean: the prior is one on the spectrum's *shape*, its
  covariance scales with the square of the spectrum's scale.

The samples (``source``, :data:`PRIOR_SOURCES`): ``"scene"``, the pixels of the RGB-guided
filtered bands ``S_0`` of every image that has a shot of every band (the scene's own
materials under its own illuminant; none for a sparse set, which then gets no spectral
prior); ``"mixture"``, the :func:`~..estimators.endmember_mixture` estimate of every pixel
(any set has one); ``"training"``, colour-science's RAW-to-ACES reflectances lit by the
illuminant estimated from the bands (biased where the collection and the estimate are);
``"natural"``, the ``"mixture"`` source with the natural-spectra prior beside it, per
pixel as the band shots favour either (:mod:`.natural_prior`, :mod:`.band_evidence`).

A soft term, not a hard subspace: the band shots and the neighbour term move a spectrum off
the samples' span where they say so. :func:`~.prior_pcg.prior_pcg` adds it to eq. 1.

Also here: :func:`prior_brightness`, the per-pixel weighting of the guided prior.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 ("Hybrid Methods") and 3.
.. [2] Hardeberg, J. Y., Schmitt, F., Brettel, H. (1999). Multispectral image capture
   using a tunable filter (Wiener estimation).
.. [3] Keshava, N., Mustard, J. F. (2002). Spectral unmixing. IEEE Signal Processing
   Magazine 19(1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from spectralize.schemas.errors import ParameterError, ReconstructionError

from ..baselines.training import estimate_illuminant, training_reflectances
from ..baselines.wiener import WIENER_RELATIVE_NOISE, wiener_from_rgb
from ..estimators import endmember_mixture
from ..estimators.endmember_mixture import Endmembers
from ..inputs import ReconstructionInputs
from ..operators import ReconstructionProblem
from .band_evidence import band_evidence
from .common import vdot
from .guided_estimate import guided_initial, shot_mask
from .natural_prior import natural_prior

__all__ = [
    "SpectralPrior",
    "spectral_prior_term",
    "prior_brightness",
    "MIN_BRIGHTNESS",
    "MAX_BRIGHTNESS",
    "PRIOR_WEIGHTINGS",
    "PRIOR_SOURCES",
]

MIN_BRIGHTNESS = 0.1
"""``b_min``: pixels darker than this fraction of their image's mean are weighted as this."""

MAX_BRIGHTNESS = 10.0
"""``b_max``: with ``prior_weighting="brightness"``, pixels brighter than this multiple of
their image's mean weigh the guided prior as this (a highlight does not pin its pixel
harder than a bright material)."""

PRIOR_WEIGHTINGS = ("uniform", "brightness")
"""How the guided prior's weight ``epsilon_p`` is spread over the pixels (see
:func:`~.prior_pcg.prior_pcg`)."""

PRIOR_SOURCES = ("scene", "mixture", "training", "natural")
"""Where the spectral prior is learnt (:func:`spectral_prior_term`)."""


@dataclass(frozen=True)
class SpectralPrior:
    """The quadratic term ``sum_p w_p (S_p - m_p)^T Q (S_p - m_p)`` on a cube ``(w, m, y, x)``.

    Attributes
    ----------
    precision
        ``Q``, ``(n_wavelength, n_wavelength)``, symmetric positive definite.
    weight
        ``w_p``, ``(n_image, height, width)`` (absolute).
    centre
        ``m``, the cube ``(n_wavelength, n_image, height, width)``.
    """

    precision: np.ndarray
    weight: np.ndarray
    centre: np.ndarray

    def apply(self, cube: np.ndarray) -> np.ndarray:
        """``w ⊙ Q cube`` (the term's Hessian / 2 applied), same shape as ``cube``."""
        n = cube.shape[0]
        out = self.precision @ cube.reshape(n, -1)
        out *= self.weight.reshape(1, -1)
        return out.reshape(cube.shape)

    def rhs(self) -> np.ndarray:
        """``w ⊙ Q m``."""
        return self.apply(self.centre)

    def energy(self, cube: np.ndarray) -> float:
        d = cube - self.centre
        return vdot(d, self.apply(d))

    def diagonal(self) -> np.ndarray:
        """Diagonal of the term's Hessian / 2, cube-shaped."""
        return np.diag(self.precision)[:, None, None, None] * self.weight[None]

    def astype(self, dtype: np.dtype | type) -> SpectralPrior:
        return SpectralPrior(
            self.precision.astype(dtype), self.weight.astype(dtype), self.centre.astype(dtype)
        )


def _level_normalised(spectra: np.ndarray) -> np.ndarray:
    """Sample spectra ``(n_wavelength, n)``, clipped at 0, each divided by its mean; those
    darker than a quarter of the median left out; at most about 20000, strided."""
    step = max(1, spectra.shape[1] // 20000)
    spectra = np.maximum(spectra[:, ::step], 0)  # the sample first: no cube-sized copies
    level = spectra.mean(axis=0)
    keep = level > 0.25 * max(float(np.median(level)), 1e-300)
    return spectra[:, keep] / level[keep]


def _scene_spectra(problem: ReconstructionProblem) -> np.ndarray | None:
    """Pixel spectra of the guided estimate ``S_0`` on the images that have a shot of every
    band, each divided by its mean: ``(n_wavelength, n_samples)``; None if no image has."""
    full = shot_mask(problem)[:, :, 0, 0].all(axis=0)
    if not full.any():
        return None
    centre = np.asarray(guided_initial(problem), dtype=np.float64).reshape(problem.shape)
    return _level_normalised(centre[:, full].reshape(problem.shape[0], -1))


def spectral_prior_term(
    problem: ReconstructionProblem,
    weight: float,
    mean_diagonal: float,
    *,
    covariance_floor: float,
    source: str,
    endmembers: Endmembers | None = None,
    natural_prior: float = 0.0,
) -> SpectralPrior | None:
    """The spectral prior of a problem built with its inputs (see the module docstring).

    ``weight`` is relative to ``mean_diagonal`` (the mean diagonal of ``A^T A``);
    ``covariance_floor`` is ``delta`` of ``Q``. ``source``: ``"training"`` learns the mean
    and covariance from colour-science's training reflectances lit by the estimated
    illuminant; ``"scene"`` from the scene's own guided estimate ``S_0`` (pixels of the
    images with every band, normalised by their level; no illuminant estimate needed); None
    (no prior) without such an image (a sparse set, where its covariance cannot be learnt).
    ``"mixture"``: the covariance of the :func:`~..estimators.endmember_mixture` estimate of
    every pixel (level-normalised), and that estimate itself as the centre ``m`` instead of
    the Wiener estimate (any set has one); ``endmembers``: its dictionary, learnt before
    (e.g. once per set for all its tiles), with ``"mixture"`` and ``"natural"`` only.
    ``"natural"``: the ``"mixture"`` term and the natural-spectra prior
    (:mod:`.natural_prior`), the Gaussian centred on the Wiener estimate ``m^W``, as one
    prior per pixel: the mixture of the two, ``pi_p N(m^W_p) + (1 - pi_p) N(m^X_p)``, with
    ``pi_p`` the band evidence for the Wiener estimate over the mixture ``m^X``
    (:mod:`.band_evidence`), approximated by one Gaussian with its mean
    ``c_p = m^X_p + pi_p (m^W_p - m^X_p)`` and the shared ``Q``, weighed
    ``w_p + v_p`` with ``v_p = natural_prior * mean_diagonal * pi_p / max(b_p, b_min)^2``
    (the natural prior holds a pixel harder where the bands favour it).

    Raises
    ------
    ReconstructionError
        For a problem not built from its inputs, or ``endmembers`` with a source other
        than ``"mixture"`` and ``"natural"``.
    ParameterError
        For a ``source`` not in :data:`PRIOR_SOURCES`.
    """
    inputs = problem.extras.get("inputs")
    if inputs is None:
        raise ReconstructionError.single(
            "problem.extras['inputs']",
            "the inputs the problem was built from (the spectral prior learns from them)",
            "none",
        )
    mixture = None
    if endmembers is not None and source not in ("mixture", "natural"):
        raise ReconstructionError(
            f"endmembers: only the 'mixture' prior source takes a dictionary, found source {source!r}"
        )
    if source == "scene":
        samples = _scene_spectra(problem)
        if samples is None:
            return None
    elif source in ("mixture", "natural"):
        mixture = endmember_mixture(inputs, endmembers=endmembers).reshape(problem.shape)
        samples = _level_normalised(mixture.reshape(problem.shape[0], -1))
    elif source == "training":
        reflectances = training_reflectances(inputs.wavelength)
        samples = estimate_illuminant(inputs, reflectances)[:, None] * reflectances
    else:
        raise ParameterError.single("prior_source", f"one of {PRIOR_SOURCES}", repr(source))
    n = samples.shape[0]
    covariance = np.cov(samples)
    covariance = covariance / max(float(np.mean(np.diag(covariance))), 1e-300)
    precision = np.linalg.inv(covariance + covariance_floor * np.eye(n))
    precision = 0.5 * (precision + precision.T)
    rgb = np.asarray(inputs.rgb, dtype=np.float64)  # (image, y, x, channel)
    brightness = np.abs(rgb.sum(axis=-1))
    brightness = brightness / np.maximum(brightness.mean(axis=(1, 2), keepdims=True), 1e-300)
    inverse_level = 1.0 / np.maximum(brightness, MIN_BRIGHTNESS) ** 2
    w = weight * mean_diagonal * inverse_level
    if mixture is not None and source == "natural" and natural_prior > 0:
        return _with_natural(inputs, precision, w, inverse_level, mixture, natural_prior * mean_diagonal)
    if mixture is not None:
        return SpectralPrior(precision, w, mixture)
    # Wiener estimate from RGB with the samples' second moment
    second_moment = samples @ samples.T / samples.shape[1]
    centre = wiener_from_rgb(inputs, second_moment, WIENER_RELATIVE_NOISE).reshape(problem.shape)
    return SpectralPrior(precision, w, centre)


def _with_natural(
    inputs: ReconstructionInputs,
    precision: np.ndarray,
    w: np.ndarray,
    inverse_level: np.ndarray,
    mixture: np.ndarray,
    scale: float,
) -> SpectralPrior:
    """The mixture term and the natural prior as one Gaussian term per pixel (see
    :func:`spectral_prior_term`); ``inverse_level`` is ``1 / max(b_p, b_min)^2`` and
    ``scale`` is ``natural_prior * mean_diagonal``."""
    natural, _ = natural_prior(inputs)
    evidence = band_evidence(inputs, natural, mixture)  # pi_p
    total = w + scale * evidence * inverse_level  # w_p + v_p
    natural -= mixture
    natural *= evidence[None]
    natural += mixture  # c_p = m^X_p + pi_p (m^W_p - m^X_p)
    return SpectralPrior(precision, total, natural)


def prior_brightness(rgb: np.ndarray) -> np.ndarray:
    """Per pixel ``f_p = clip(b_p, b_min, b_max) / mean(...)``, ``(n_image, height, width)``:
    the RGB brightness relative to its image's mean, clipped to
    [:data:`MIN_BRIGHTNESS`, :data:`MAX_BRIGHTNESS`] and normalised to mean 1 over all
    pixels (so ``prior`` keeps its meaning as the mean weight)."""
    brightness = np.abs(np.asarray(rgb, dtype=np.float64).sum(axis=-1))
    brightness /= np.maximum(brightness.mean(axis=(1, 2), keepdims=True), 1e-300)
    np.clip(brightness, MIN_BRIGHTNESS, MAX_BRIGHTNESS, out=brightness)
    return brightness / max(float(brightness.mean()), 1e-300)
