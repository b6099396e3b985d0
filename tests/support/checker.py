"""The ColorChecker under D65 as small spectral cubes, and band shots pairing with images:
the inputs of the evaluation tests (tests/nodes/evaluation)."""

import colour
import numpy as np
import xarray as xr

from .cubes import cube_dataset

SHAPE = colour.SpectralShape(410, 720, 10)  # the paper's 32 bands
WAVELENGTH = SHAPE.wavelengths
OBSERVER = "CIE 1931 2 Degree Standard Observer"


def cube(values):
    """A ``spectra``-layout Dataset of ``values`` (image, wavelength, y, x)."""
    return cube_dataset(values, first_led=10)


def checker_reflectance() -> np.ndarray:
    """(24, 32) reflectances of the ColorChecker (N Ohta) on the paper's bands."""
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    return np.array([sds[name].copy().align(SHAPE).values for name in sds])


def checker_truth(n_image: int = 3, block: int = 3) -> xr.Dataset:
    """The 24 patches under D65 (max 1) as a 4 x 6 grid of ``block``-pixel squares."""
    light = colour.SDS_ILLUMINANTS["D65"].copy().align(SHAPE).values
    grid = (checker_reflectance() * light / light.max()).reshape(4, 6, -1).transpose(2, 0, 1)
    patches = np.repeat(np.repeat(grid, block, 1), block, 2)
    return cube(np.stack([patches * (1.0 + 0.5 * i) for i in range(n_image)]))


def shots_for(images) -> xr.Dataset:
    n = len(images)
    return xr.Dataset(
        coords={
            "image": ("shot", np.asarray(images, dtype=np.int64)),
            "wavelength": ("shot", np.full(n, 550.0)),
        }
    )


def raw_spectral_for(images) -> xr.Dataset:
    """A ``raw/spectral`` group (what the node's input check asks for) pairing shots with images."""
    n = len(images)
    return xr.Dataset(
        {"counts": (("shot", "y", "x"), np.zeros((n, 2, 2), np.uint16), {"units": "DN"})},
        coords={
            "wavelength": ("shot", np.full(n, 550.0), {"units": "nm"}),
            "exposure_time": ("shot", np.full(n, 0.05), {"units": "s"}),
            "image": ("shot", np.asarray(images, dtype=np.int64)),
            "rotation": ("shot", np.zeros(n, int)),
            "led": ("shot", np.zeros(n, int)),
        },
        attrs={"bit_depth": 12},
    )
