"""Capture of a hard scene through the project's camera model (eq. 2, 3, 5).

Band shots: the spectral camera (quantum efficiency
:func:`~spectralize.nodes.simulation.camera_model.spectral_quantum_efficiency`, weak in the
blue) records eq. 5 with a linear response, 10 bit, shot noise, 3 DN Gaussian read noise and
a per-pixel ADC offset (fixed-pattern, about 24 DN); exposure times follow eq. 2
(``omega = 0.8``) with ``t0`` set so that the median band signal of the scene's reference
image is :data:`MEDIAN_BAND_SIGNAL_DN`; filter sizes follow eq. 3 with ``s0`` set so that
the best-exposed band gets :data:`SMALLEST_FILTER_PX`. Calibration subtracts the mean of 200
dark frames (drawn as its exact distribution: the per-pixel offset minus the floor's 1/2
plus Gaussian error of ``sqrt(3^2 + 1/12) / sqrt(200)`` DN) and divides by ``Q_i t_i`` of
full scale, negative values kept.

RGB: HDR radiance ``C S`` with the noise of a 4-exposure merge: 0.4 % relative plus an
absolute floor of 2e-4 of a white target's RGB.

References
----------
.. [1] Fast Capture of Spectral Image Series, eqs. 2, 3 and 5; section 4 (200 dark frames,
   3 DN dark noise).
"""

from __future__ import annotations

import numpy as np

from ..camera_model import LinearResponse, capture_with_generator
from ..exposure_plan import exposure_plan

__all__ = [
    "MEDIAN_BAND_SIGNAL_DN",
    "SMALLEST_FILTER_PX",
    "READ_NOISE_DN",
    "DARK_FRAMES",
    "band_plan",
    "capture_bands",
    "capture_rgb",
]

MEDIAN_BAND_SIGNAL_DN = 2.5
"""Median over all bands and pixels of the reference image's band signal [DN]."""

SMALLEST_FILTER_PX = 6.0
"""Filter size of the best-exposed band (eq. 3's ``s0``)."""

READ_NOISE_DN = 3.0
"""Gaussian read/dark noise of the spectral camera (the paper's measured 3 DN)."""

DARK_FRAMES = 200
"""Dark frames averaged per exposure time (paper section 4)."""

FULL_SCALE = 1023.0
OMEGA = 0.8


def band_plan(
    reference: np.ndarray,
    quantum_efficiency: np.ndarray,
    illuminant: np.ndarray,
    wavelength: np.ndarray,
    *,
    max_filter_size: float,
):
    """Eq. 2/3 exposure plan for a scene: ``t0`` for the median signal, ``s0`` for the
    smallest filter, filters capped at ``max_filter_size`` (so a centre fits the image).

    ``reference``: ``(n_wavelength, y, x)`` radiance of the reference image.
    """
    plan = exposure_plan(
        quantum_efficiency, illuminant, t0=1.0, s0=1.0, omega=OMEGA, wavelength=wavelength
    )
    dn = reference * (quantum_efficiency * plan["exposure_time"].values * FULL_SCALE)[:, None, None]
    t0 = float(MEDIAN_BAND_SIGNAL_DN / np.median(dn)) ** (1 / OMEGA)
    plan = exposure_plan(
        quantum_efficiency, illuminant, t0=t0, s0=1.0, omega=OMEGA, wavelength=wavelength
    )
    s0 = SMALLEST_FILTER_PX / float(plan["filter_size"].min())
    plan = exposure_plan(
        quantum_efficiency, illuminant, t0=t0, s0=s0, omega=OMEGA, wavelength=wavelength
    )
    plan["filter_size"] = plan["filter_size"].clip(max=max_filter_size)
    plan.attrs["max_filter_size"] = float(max_filter_size)
    return plan


def capture_bands(
    truth: np.ndarray,
    shot_band: np.ndarray,
    shot_image: np.ndarray,
    quantum_efficiency: np.ndarray,
    exposure_time: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Calibrated noisy band radiance ``(n_shot, y, x)`` and the raw signal in DN.

    ``truth`` ``(n_image, n_wavelength, y, x)``; shot ``i`` images band ``shot_band[i]`` of
    image ``shot_image[i]``.
    """
    _, _, h, w = truth.shape
    offset = 24.0 + rng.normal(0.0, 1.5, size=(h, w))
    dark_error = np.sqrt(READ_NOISE_DN**2 + 1 / 12) / np.sqrt(DARK_FRAMES)
    shots = np.empty((len(shot_band), h, w), dtype=np.float64)
    signal = np.empty_like(shots)
    for i, (b, m) in enumerate(zip(shot_band, shot_image, strict=True)):
        q, t = float(quantum_efficiency[b]), float(exposure_time[b])
        counts = capture_with_generator(
            truth[m, b],
            t,
            rng,
            response=LinearResponse(),
            quantum_efficiency=q,
            adc_offset=offset,
            noise_sigma=READ_NOISE_DN,
            bit_depth=10,
            noise="shot",
        ).astype(np.float64)
        dark = offset - 0.5 + rng.normal(0.0, dark_error, size=(h, w))
        shots[i] = (counts - dark) / (q * t * FULL_SCALE)
        signal[i] = truth[m, b] * q * t * FULL_SCALE
    return shots, signal


def capture_rgb(
    truth: np.ndarray, camera_matrix: np.ndarray, illuminant: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """HDR RGB ``(n_image, y, x, 3)`` of ``truth`` with a 4-exposure merge's noise."""
    rgb = np.einsum("cw,mwyx->myxc", camera_matrix, truth)
    white = camera_matrix @ illuminant
    sigma = np.sqrt((0.004 * rgb) ** 2 + (2e-4 * white) ** 2)
    return rgb + rng.normal(size=rgb.shape) * sigma
