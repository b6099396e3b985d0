"""Simulated captures for the reconstruction benchmark.

Ground truth and exposure plan come from the project's simulator modules:

* :func:`spectralize.nodes.simulation.ground_truth.spectral_texture` / ``render``: measured
  ColorChecker reflectances laid out by smooth random fields (sharp and soft material
  boundaries), albedo detail, bump shading and specular highlights, lit by ``LED-B3``;
* :func:`spectralize.nodes.simulation.exposure_plan.exposure_plan`: eq. 2 (omega = 0.8, ``t0`` for
  6 s per set of 32 bands as in the ``demo``/``paper`` recipes) and eq. 3 with the spectral
  camera's quantum efficiency
  :func:`spectralize.nodes.simulation.camera_model.spectral_quantum_efficiency`;
* RGB camera matrix ``C``: :func:`spectralize.nodes.simulation.camera_model.camera_sensitivities`
  (Nikon 5100).

Capture noise follows eq. 5 with a linear response after calibration: a band shot of
exposure ``t_i`` records ``S_b(p) Q_i t_i`` of full scale (10 bit) plus Gaussian noise of
3 DN (the paper's measured dark noise); the calibrated band radiance is that divided by
``Q_i t_i`` (negative values kept, never clipped). With these constants a 20 % grey pixel
has a single-shot SNR of about 1.4 to 4.6 depending on the band. The HDR RGB gets 0.5 %
Gaussian noise.

A second layout, ``"voronoi"`` (flat ColorChecker patches on Voronoi cells with smooth
shading), is kept for comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr
from scipy import ndimage
from scipy.spatial import cKDTree

__all__ = ["SimulatedCapture", "simulate_capture", "nrmse_per_pixel", "PAPER_VIEW_THETA"]

PAPER_VIEW_THETA = 45.0
"""Elevation of the spectral camera (and its paired RGB camera) in degrees."""

FULL_SCALE_DN = 1023.0
NOISE_DN = 3.0


@dataclass
class SimulatedCapture:
    """A simulated capture and its ground truth, as the reconstruction API takes them."""

    rgb: xr.DataArray  # (image, y, x, channel)
    bands: xr.DataArray  # (shot, y, x), coords wavelength, image, filter_size
    camera_matrix: xr.DataArray  # (channel, wavelength)
    truth: xr.DataArray  # (image, wavelength, y, x)
    plan: xr.Dataset  # the exposure plan (eq. 2, 3)


def _voronoi_truth(
    rng: np.random.Generator,
    size: int,
    n_images: int,
    wavelength: np.ndarray,
    illuminant: np.ndarray,
    cell: float = 40.0,
) -> np.ndarray:
    import colour

    shape = colour.SpectralShape(
        float(wavelength[0]), float(wavelength[-1]), float(wavelength[1] - wavelength[0])
    )
    checker = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    reflectances = np.stack([sd.copy().align(shape).values for sd in checker.values()])
    n_cells = max(4, int(round(size * size / cell**2)))
    seeds = rng.uniform(0, size, size=(n_cells, 2))
    material = rng.integers(0, len(reflectances), size=n_cells)
    yy, xx = np.mgrid[0:size, 0:size]
    _, cell_of = cKDTree(seeds).query(np.stack([yy.ravel(), xx.ravel()], axis=1))
    labels = material[cell_of].reshape(size, size)
    truth = np.empty((n_images, wavelength.size, size, size))
    y, x = np.mgrid[0:size, 0:size] / size
    for m in range(n_images):
        field = np.zeros((size, size))
        for _ in range(6):
            fy, fx = rng.uniform(-2.5, 2.5, size=2)
            field += np.cos(2 * np.pi * (fy * y + fx * x) + rng.uniform(0, 2 * np.pi))
        field = (field - field.min()) / np.ptp(field)
        cube = (reflectances[labels] * illuminant).transpose(2, 0, 1) * (0.3 + 0.7 * field)
        cube *= 0.8 if m == 0 else rng.uniform(0.4, 0.9)
        truth[m] = ndimage.gaussian_filter(cube, sigma=(0, 0.5, 0.5), mode="nearest")
    return truth


def simulate_capture(
    size: int = 256,
    *,
    n_images: int = 1,
    images_with_bands: int | None = None,
    scene: str = "texture",
    n_materials: int = 6,
    max_filter_size: float | None = 25.0,
    spectral_total_time: float = 6.0,
    rgb_noise: float = 0.005,
    seed: int = 0,
) -> SimulatedCapture:
    """Simulate HDR RGB images and noisy band shots with ground truth.

    Parameters
    ----------
    size
        Image height and width in pixels.
    n_images
        Images in the set. Image 0 is seen by the RGB camera paired with the spectral
        camera (45 deg) with the light in the mirror direction; a set adds images under
        other LEDs of the 40 deg ring, the first ``images_with_bands`` from the paired
        camera, the rest from the other RGB cameras (0 .. 75 deg) without band shots (the
        paper's sparse case, sec. 5).
    images_with_bands
        Images that get band shots; the 32 bands are spread round-robin over them (one shot
        per band in all). Default: 1 for a single image, ``n_images // 2`` for a set.
    scene
        ``"texture"`` (the project's ground truth) or ``"voronoi"``.
    n_materials
        Materials of the texture.
    max_filter_size
        Eq. 3's ``s0`` is chosen so that the largest filter is this many pixels (``None``:
        the recipes' ``s0 = 0.25``, which gives 4.5 .. 14.6 px).
    spectral_total_time
        Seconds for one set of 32 band shots (sets ``t0`` of eq. 2).
    rgb_noise
        Relative Gaussian noise of the HDR RGB.
    seed
        Seed of texture and noise.
    """
    from spectralize.nodes.simulation.camera_model import (
        camera_sensitivities,
        spectral_quantum_efficiency,
    )
    from spectralize.nodes.simulation.exposure_plan import exposure_plan, t0_for_total_time
    from spectralize.nodes.simulation.ground_truth import (
        WAVELENGTHS,
        illuminant_spd,
        render,
        spectral_texture,
    )

    rng = np.random.default_rng(seed)
    wavelength = np.asarray(WAVELENGTHS, dtype=np.float64)
    illuminant = illuminant_spd(wavelength, name="LED-B3")
    quantum_efficiency = spectral_quantum_efficiency(wavelength, peak=2.5)
    t0 = t0_for_total_time(quantum_efficiency, illuminant, total_time=spectral_total_time)
    plan = exposure_plan(quantum_efficiency, illuminant, t0=t0, s0=0.25)
    if max_filter_size is not None:
        s0 = 0.25 * max_filter_size / float(plan["filter_size"].max())
        plan = exposure_plan(quantum_efficiency, illuminant, t0=t0, s0=s0)

    if images_with_bands is None:
        images_with_bands = 1 if n_images == 1 else max(1, n_images // 2)
    if scene == "texture":
        texture = spectral_texture(size, seed=seed, n_materials=n_materials)
        truth = np.empty((n_images, wavelength.size, size, size), dtype=np.float64)
        other_views = np.linspace(0.0, 75.0, 11)
        other_views = other_views[~np.isclose(other_views, PAPER_VIEW_THETA)]
        for m in range(n_images):
            phi_i = 180.0 + 15.0 * (m % 12)
            theta_o = (
                PAPER_VIEW_THETA if m < max(images_with_bands, 1) else other_views[m % other_views.size]
            )
            truth[m] = render(
                texture, illuminant, theta_i=40.0, phi_i=phi_i, theta_o=theta_o, phi_o=0.0
            ).values
    elif scene == "voronoi":
        truth = _voronoi_truth(rng, size, n_images, wavelength, illuminant.values)
    else:
        raise ValueError(f"scene must be 'texture' or 'voronoi', got {scene!r}")

    sensitivities = camera_sensitivities(wavelength)
    camera_matrix = sensitivities.values
    rgb = np.einsum("cw,mwyx->myxc", camera_matrix, truth)
    rgb += rng.normal(size=rgb.shape) * rgb_noise * np.abs(rgb)

    exposure = plan["exposure_time"].values
    per_radiance_dn = quantum_efficiency.values * exposure * FULL_SCALE_DN
    shot_image = np.arange(wavelength.size) % images_with_bands
    shots = np.empty((wavelength.size, size, size), dtype=np.float64)
    for b in range(wavelength.size):
        counts = truth[shot_image[b], b] * per_radiance_dn[b]
        counts += rng.normal(scale=NOISE_DN, size=counts.shape)
        shots[b] = counts / per_radiance_dn[b]

    image = np.arange(n_images)
    channel = ["R", "G", "B"]
    wl_attrs = {"units": "nm", "long_name": "wavelength"}
    rgb_da = xr.DataArray(
        rgb.astype(np.float32),
        dims=("image", "y", "x", "channel"),
        coords={"image": image, "channel": channel},
        attrs={"units": "1", "long_name": "relative RGB radiance"},
    )
    bands_da = xr.DataArray(
        shots.astype(np.float32),
        dims=("shot", "y", "x"),
        coords={
            "wavelength": ("shot", wavelength, wl_attrs),
            "image": ("shot", shot_image),
            "filter_size": ("shot", plan["filter_size"].values, {"units": "px"}),
            "exposure_time": ("shot", exposure, {"units": "s"}),
        },
        attrs={"units": "1", "long_name": "relative band radiance"},
    )
    c_da = xr.DataArray(
        camera_matrix,
        dims=("channel", "wavelength"),
        coords={"channel": channel, "wavelength": ("wavelength", wavelength, wl_attrs)},
    )
    truth_da = xr.DataArray(
        truth.astype(np.float32),
        dims=("image", "wavelength", "y", "x"),
        coords={"image": image, "wavelength": ("wavelength", wavelength, wl_attrs)},
        attrs={"units": "1", "long_name": "relative spectral radiance"},
    )
    return SimulatedCapture(rgb_da, bands_da, c_da, truth_da, plan)


def nrmse_per_pixel(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-pixel RMSE over wavelengths divided by the mean ground-truth intensity of the
    pixel's image (paper Fig. 5). Arrays ``(image, wavelength, y, x)``; returns
    ``(image, y, x)``."""
    estimate = np.asarray(estimate, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    rmse = np.sqrt(np.mean((estimate - truth) ** 2, axis=1))
    return rmse / truth.mean(axis=(1, 2, 3))[:, None, None]
