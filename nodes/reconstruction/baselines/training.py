"""Training spectra and an illuminant estimate for the statistical baselines.

colour-science ships 190 reflectances (RAW to ACES v1 training data); lit by an illuminant
estimated from the band shots they are the prior of the Wiener and Mallett-Yuksel baselines.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 2 ("Hybrid Methods").
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..inputs import ReconstructionInputs

__all__ = ["training_reflectances", "estimate_illuminant"]


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
    return np.stack([np.interp(wavelength, grid, values[:, j]) for j in range(values.shape[1])], axis=1)


def estimate_illuminant(inputs: ReconstructionInputs, reflectances: np.ndarray) -> np.ndarray:
    """A spectral illuminant estimate from the band data.

    The mean band radiance per wavelength (noise averages out over all pixels), each shot
    first divided by the mean RGB of its image relative to the whole set (so that shots of
    differently lit images of a set compare), divided by the mean training reflectance.

    Parameters
    ----------
    inputs
        The checked input arrays.
    reflectances
        ``(n_wavelength, n_samples)`` training reflectances on ``inputs.wavelength``.

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength,)``, positive (floored at 1e-3 of its maximum).
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
