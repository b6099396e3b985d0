"""Certainty weights of pixel values for Robertson's estimator: a table plus a dispatcher.

``WEIGHTING_FUNCTIONS`` maps a name to a function of the normalised position
``u = (code - black_level) / (saturation - black_level)`` in the valid interval; the
dispatcher :func:`weighting_function` evaluates one at pixel values and sets the weight of
under-exposed and saturated codes to 0. New weightings are new table entries.

References
----------
.. [1] M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic
   range enhancement using multiple exposures", Journal of Electronic Imaging 12(2),
   219-228, 2003, section 3.
.. [2] P. E. Debevec, J. Malik, "Recovering high dynamic range radiance maps from
   photographs", SIGGRAPH 1997 (the hat function).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Literal

import numpy as np

from spectralize.schemas import CalibrationError

__all__ = ["Weighting", "WEIGHTING_FUNCTIONS", "weighting_function"]

Weighting = Literal["gaussian", "hat", "uniform"]


def _gaussian(u: np.ndarray) -> np.ndarray:
    # Robertson et al. (1999/2003): exp(-4 (z - mid)^2 / mid^2), shifted and rescaled so that
    # it is exactly 0 at both ends of the valid interval and 1 at its middle.
    floor = math.exp(-4.0)
    return (np.exp(-4.0 * (2.0 * u - 1.0) ** 2) - floor) / (1.0 - floor)


def _hat(u: np.ndarray) -> np.ndarray:
    # Debevec & Malik (1997) triangle.
    return 1.0 - np.abs(2.0 * u - 1.0)


def _uniform(u: np.ndarray) -> np.ndarray:
    return np.ones_like(u)


#: Weighting functions of the normalised position ``u`` in the valid interval, ``u in (0, 1)``.
WEIGHTING_FUNCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "gaussian": _gaussian,
    "hat": _hat,
    "uniform": _uniform,
}


def weighting_function(
    codes: np.ndarray, *, black_level: float, saturation: float, kind: Weighting = "gaussian"
) -> np.ndarray:
    """Certainty weight ``w(code)`` of pixel values for Robertson's estimator.

    Parameters
    ----------
    codes
        Pixel values [DN], any shape.
    black_level
        Codes at or below it are under-exposed (dark noise) and get weight 0.
    saturation
        Codes at or above it are saturated and get weight 0.
    kind
        ``"gaussian"``: Robertson's ``exp(-4 (z - c)^2 / h^2)`` with ``c`` the middle and
        ``h`` the half width of ``(black_level, saturation)``, shifted to be 0 at both ends;
        ``"hat"``: Debevec's triangle; ``"uniform"``: 1 inside the interval.

    Returns
    -------
    numpy.ndarray
        Weights in [0, 1], float64, the shape of ``codes``.

    Notes
    -----
    Domain: any real codes. Range: [0, 1]; exactly 0 outside the open interval
    ``(black_level, saturation)``.

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003, section 3 (weighting function).
    .. [2] Debevec, Malik 1997 (the hat function).
    """
    if kind not in WEIGHTING_FUNCTIONS:
        raise CalibrationError(f"weighting {kind!r} is unknown; known: {', '.join(WEIGHTING_FUNCTIONS)}")
    if not saturation > black_level:
        raise CalibrationError(f"saturation ({saturation}) must be above black_level ({black_level})")
    codes = np.asarray(codes, dtype=np.float64)
    u = (codes - black_level) / (saturation - black_level)
    inside = (u > 0.0) & (u < 1.0)
    w = np.where(inside, WEIGHTING_FUNCTIONS[kind](np.clip(u, 0.0, 1.0)), 0.0)
    return np.clip(w, 0.0, 1.0)
