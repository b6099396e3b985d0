"""Quantum efficiency at the band shot's own signal level: band ripple removed at its cause.

Band radiance is ``f(I - dark) / (t Q_lambda)`` (eq. 5), ``Q_lambda`` from the white
reference. A recovered spectral response is never exact: a few per cent of level-dependent
error remain (largest where the camera compresses near full scale). When ``Q_lambda`` comes
from the white reference's longest unsaturated exposure, every band's ``Q`` carries the
error at another signal level (the white's exposure series lands each band at a different
fraction of full scale), and the band shots at theirs: the ratio ripples from band to band by
as much as the response's error, and a weak band, whose white reference and band shots sit at
very different levels, is biased.

The white reference is recorded at every exposure of its series. :func:`level_table` keeps,
per band and exposure, ``Q`` and the linearised level ``f(I - dark)`` it was measured at;
:func:`matched_quantum_efficiency` gives each band shot the ``Q`` of its own band at its own
level (linear in log level between the white's exposures, the nearest one outside them). The
response's error then divides out of the band radiance: the same ``f`` at the same level in
the numerator and the denominator.

The benchmark of the calibrated chain on the foreign gantries (``tests/support``) reports the
band-to-band ripple it removes.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration"), eq. 5 and Fig. 3.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

__all__ = ["level_table", "matched_quantum_efficiency"]


def level_table(
    signal: np.ndarray,
    exposure_time: np.ndarray,
    usable: np.ndarray,
    light: np.ndarray,
    wavelength: np.ndarray,
) -> xr.Dataset:
    """``Q`` of every band at every usable exposure of the white reference, and its level.

    Parameters
    ----------
    signal
        (wavelength, exposure) mean linearised dark-subtracted signal per second of the
        white reference, ``f(I - dark) / t`` over its region.
    exposure_time
        (exposure,) [s].
    usable
        (wavelength, exposure) bool: unsaturated and well above the noise.
    light
        (wavelength,) reflectance times illuminant of the white reference.
    wavelength
        (wavelength,) [nm].

    Returns
    -------
    xarray.Dataset
        ``qe_by_level`` (wavelength, spectral_exposure) ``signal / light`` and ``qe_level``
        (wavelength, spectral_exposure) ``signal * t``, NaN where not usable.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 5.
    """
    signal = np.asarray(signal, dtype=np.float64)
    q = np.where(usable, signal / np.asarray(light, dtype=np.float64)[:, None], np.nan)
    level = np.where(usable, signal * np.asarray(exposure_time, dtype=np.float64)[None, :], np.nan)
    dims = ("wavelength", "spectral_exposure")
    return xr.Dataset(
        {
            "qe_by_level": (
                dims,
                q,
                {"units": "1", "long_name": "quantum efficiency from each white-reference exposure"},
            ),
            "qe_level": (
                dims,
                level,
                {"units": "1", "long_name": "linearised level f(I - dark) of that exposure"},
            ),
        },
        coords={"wavelength": ("wavelength", np.asarray(wavelength, dtype=np.float64), {"units": "nm"})},
    )


def matched_quantum_efficiency(
    table: xr.Dataset, wavelength: np.ndarray, level: np.ndarray, fallback: np.ndarray
) -> np.ndarray:
    """``Q`` for shots at ``wavelength`` whose mean linearised level is ``level``.

    Linear in ``log(level)`` between the white reference's usable exposures of the band,
    the nearest exposure's ``Q`` outside them; ``fallback`` (per shot) where the band has no
    usable exposure or the shot's level is not positive.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 5.
    """
    grid = np.asarray(table["wavelength"].values, dtype=np.float64)
    q_table = np.asarray(table["qe_by_level"].values, dtype=np.float64)
    level_table_ = np.asarray(table["qe_level"].values, dtype=np.float64)
    out = np.asarray(fallback, dtype=np.float64).copy()
    for i, (w, v) in enumerate(
        zip(np.asarray(wavelength, float), np.asarray(level, float), strict=True)
    ):
        b = int(np.argmin(np.abs(grid - w)))
        ok = np.isfinite(q_table[b]) & (level_table_[b] > 0)
        if abs(grid[b] - w) > 1e-6 or not ok.any() or not v > 0:
            continue
        x, y = np.log(level_table_[b, ok]), q_table[b, ok]
        order = np.argsort(x)
        out[i] = float(np.interp(np.log(v), x[order], y[order]))
    return out
