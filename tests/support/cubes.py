"""Spectral cubes in the ``spectra`` group's layout, around given values."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

WAVELENGTH = np.arange(410.0, 721.0, 10.0)
"""The paper's 32 bands [nm]."""


def cube_dataset(
    values: np.ndarray,
    *,
    theta_o: Sequence[float] | None = None,
    first_led: int = 0,
    attrs: dict | None = None,
) -> xr.Dataset:
    """A spectra-group Dataset around ``values`` (image, wavelength, y, x) with per-image coords.

    ``theta_o`` defaults to 45 degrees for every image; LEDs count up from ``first_led``.
    """
    n = values.shape[0]
    deg = {"units": "degree"}
    theta_o = np.full(n, 45.0) if theta_o is None else np.asarray(theta_o, float)[:n]
    return xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                values.astype(np.float32),
                {"units": "1", "long_name": "relative spectral radiance"},
            )
        },
        coords={
            "wavelength": ("wavelength", WAVELENGTH, {"units": "nm"}),
            "camera": ("image", np.arange(n)),
            "rotation": ("image", np.zeros(n, int)),
            "led": ("image", np.arange(n) + first_led),
            "theta_i": ("image", np.full(n, 30.0), deg),
            "phi_i": ("image", np.zeros(n), deg),
            "theta_o": ("image", theta_o, deg),
            "phi_o": ("image", np.arange(n) * 15.0, deg),
        },
        attrs=attrs or {},
    )
