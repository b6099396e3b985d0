"""Simulated captures for the reconstruction benchmark (and nothing else).

Built directly from colour-science data until the project's capture simulator exists:

* materials: the 24 reflectances of ``ColorChecker N Ohta``;
* light: ``LED-B3`` (the paper's gantry has LEDs); camera: ``Nikon 5100 (NPL)``
  sensitivities as the camera matrix ``C``;
* layout: a random Voronoi tiling of materials, a smooth multiplicative shading field per
  image, and a slight optical blur (sigma 0.5 px) so that edge pixels mix materials;
* RGB: ``C S`` plus 0.5 % Gaussian noise (a good HDR merge);
* bands: one shot per band with the exposure plan of eq. 2 (omega = 0.8) and the filter
  sizes of eq. 3, photon noise plus 3 e- read noise, calibrated back to radiance; the
  constants put a mid-grey pixel's single-shot SNR at about 1 to 3, as in the paper.

All spectra are on 410..720 nm in 10 nm steps. The scene's radiance is scaled to about
1e-2 .. 1e0 relative units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = ["SimulatedCapture", "simulate_capture", "spectral_setup", "nrmse_per_pixel"]

WAVELENGTHS = np.arange(410.0, 721.0, 10.0)


def spectral_setup(wavelength: np.ndarray = WAVELENGTHS) -> dict[str, np.ndarray]:
    """Reflectances ``(24, W)``, illuminant ``(W,)`` (max 1), camera matrix ``(3, W)`` and
    monochrome quantum efficiency ``(W,)`` on ``wavelength``."""
    import colour

    shape = colour.SpectralShape(float(wavelength[0]), float(wavelength[-1]),
                                 float(wavelength[1] - wavelength[0]))
    checker = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    reflectances = np.stack([sd.copy().align(shape).values for sd in checker.values()])
    illuminant = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(shape).values
    illuminant = illuminant / illuminant.max()
    sensitivities = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"].copy().align(shape)
    camera_matrix = np.asarray(sensitivities.values).T
    # a CCD-like QE behind a tunable filter: broad, peaking in the green, weak at both ends
    qe = 0.15 + 0.85 * np.exp(-0.5 * ((wavelength - 560.0) / 90.0) ** 2)
    return {"reflectances": reflectances, "illuminant": illuminant,
            "camera_matrix": camera_matrix, "quantum_efficiency": qe}


@dataclass
class SimulatedCapture:
    """A simulated capture and its ground truth, as the reconstruction API takes them."""

    rgb: xr.DataArray            # (image, y, x, channel)
    bands: xr.DataArray          # (shot, y, x), coords wavelength, image, filter_size
    camera_matrix: xr.DataArray  # (channel, wavelength)
    truth: xr.DataArray          # (image, wavelength, y, x)


def _smooth_field(rng: np.random.Generator, height: int, width: int, n_waves: int = 6
                  ) -> np.ndarray:
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    field = np.zeros((height, width))
    for _ in range(n_waves):
        fy, fx = rng.uniform(-2.5, 2.5, size=2)
        field += rng.uniform(0.5, 1.0) * np.cos(2 * np.pi * (fy * y + fx * x)
                                                + rng.uniform(0, 2 * np.pi))
    field -= field.min()
    return field / max(field.max(), 1e-12)


def _labels(rng: np.random.Generator, height: int, width: int, cell: float,
            n_materials: int) -> np.ndarray:
    n_cells = max(4, int(round(height * width / cell**2)))
    seeds = rng.uniform(0, 1, size=(n_cells, 2)) * (height, width)
    material = rng.integers(0, n_materials, size=n_cells)
    material[:min(n_cells, n_materials)] = rng.permutation(n_materials)[:min(n_cells,
                                                                             n_materials)]
    yy, xx = np.mgrid[0:height, 0:width]
    _, cell_of = cKDTree(seeds).query(np.stack([yy.ravel(), xx.ravel()], axis=1))
    return material[cell_of].reshape(height, width)


def simulate_capture(size: int | tuple[int, int] = 128, *, n_images: int = 1,
                     images_with_bands: int | None = None, cell: float = 40.0,
                     brightness: float = 0.6, snr_grey: float = 2.0,
                     filter_size_range: tuple[float, float] = (5.0, 25.0),
                     seed: int = 0) -> SimulatedCapture:
    """Simulate RGB and noisy band shots of a piecewise-constant, shaded scene.

    Parameters
    ----------
    size
        Image height and width (one int: square).
    n_images
        Images in the set; they share the material layout and differ in shading and
        overall brightness (like one material under several lights and views).
    images_with_bands
        How many of the images get band shots (default all for one image, half for a set);
        the 32 bands are spread round-robin over them (one shot per band in all).
    cell
        Typical Voronoi cell size in pixels.
    brightness
        Radiance scale (a white patch under the brightest light is about this bright).
    snr_grey
        Single-shot SNR of a 20 % grey pixel in the band with the median exposure.
    filter_size_range
        ``(s_min, s_max)``: eq. 3's constant ``s0`` makes the largest filter ``s_max``;
        the smallest follows from eq. 2/3 and is clipped to ``s_min`` from below.
    seed
        Random seed.
    """
    rng = np.random.default_rng(seed)
    height, width = (size, size) if np.isscalar(size) else size
    setup = spectral_setup()
    reflectances, illuminant = setup["reflectances"], setup["illuminant"]
    camera_matrix, qe = setup["camera_matrix"], setup["quantum_efficiency"]
    n_wavelength = WAVELENGTHS.size

    labels = _labels(rng, height, width, cell, reflectances.shape[0])
    truth = np.empty((n_images, n_wavelength, height, width))
    for m in range(n_images):
        shading = 0.3 + 0.7 * _smooth_field(rng, height, width)
        level = brightness * (1.0 if m == 0 else rng.uniform(0.4, 1.0))
        cube = (reflectances[labels] * illuminant).transpose(2, 0, 1) * shading * level
        truth[m] = ndimage.gaussian_filter(cube, sigma=(0, 0.5, 0.5), mode="nearest")

    rgb = np.einsum("cw,mwyx->myxc", camera_matrix, truth)
    rgb += rng.normal(size=rgb.shape) * 0.005 * np.abs(rgb)

    # eq. 2 (omega = 0.8) and eq. 3
    ql = qe * illuminant
    exposure = (1.0 / ql) ** 0.8
    exposure /= np.median(exposure)
    signal_level = ql * exposure                 # electrons per unit reflectance, relative
    filter_size = 1.0 / signal_level
    filter_size *= filter_size_range[1] / filter_size.max()
    filter_size = np.clip(filter_size, filter_size_range[0], None)
    # photo-electrons of a 20 % grey pixel in the median band are g (SNR = g / sqrt(g + 9))
    read_noise = 3.0
    grey = (snr_grey**2 + np.sqrt(snr_grey**4 + 4 * snr_grey**2 * read_noise**2)) / 2
    gain = grey / (0.2 * brightness * np.median(signal_level))  # e- per unit radiance/illum.

    if images_with_bands is None:
        images_with_bands = 1 if n_images == 1 else max(1, n_images // 2)
    shot_image = np.arange(n_wavelength) % images_with_bands
    shots = np.empty((n_wavelength, height, width))
    for b in range(n_wavelength):
        radiance = truth[shot_image[b], b]
        electrons_per_radiance = gain * signal_level[b] / illuminant[b]
        electrons = radiance * electrons_per_radiance
        noisy = rng.poisson(np.maximum(electrons, 0)) + rng.normal(scale=read_noise,
                                                                   size=electrons.shape)
        shots[b] = noisy / electrons_per_radiance

    image = np.arange(n_images)
    channel = ["R", "G", "B"]
    rgb_da = xr.DataArray(rgb.astype(np.float32), dims=("image", "y", "x", "channel"),
                          coords={"image": image, "channel": channel},
                          attrs={"units": "1", "long_name": "relative RGB radiance"})
    bands_da = xr.DataArray(
        shots.astype(np.float32), dims=("shot", "y", "x"),
        coords={"wavelength": ("shot", WAVELENGTHS), "image": ("shot", shot_image),
                "filter_size": ("shot", filter_size),
                "exposure_time": ("shot", exposure)},
        attrs={"units": "1", "long_name": "relative band radiance"})
    c_da = xr.DataArray(camera_matrix, dims=("channel", "wavelength"),
                        coords={"channel": channel, "wavelength": WAVELENGTHS})
    truth_da = xr.DataArray(truth.astype(np.float32), dims=("image", "wavelength", "y", "x"),
                            coords={"image": image, "wavelength": WAVELENGTHS},
                            attrs={"units": "1", "long_name": "relative spectral radiance"})
    return SimulatedCapture(rgb_da, bands_da, c_da, truth_da)


def nrmse_per_pixel(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-pixel RMSE over wavelengths divided by the mean ground-truth intensity of the
    pixel's image (paper Fig. 5). Arrays ``(image, wavelength, y, x)``; returns
    ``(image, y, x)``."""
    estimate = np.asarray(estimate, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    rmse = np.sqrt(np.mean((estimate - truth) ** 2, axis=1))
    return rmse / truth.mean(axis=(1, 2, 3))[:, None, None]
