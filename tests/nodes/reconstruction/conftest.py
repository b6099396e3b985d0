"""Small synthetic captures for the reconstruction tests (fast: tens of pixels, few bands)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import xarray as xr


@dataclass
class Scene:
    rgb: xr.DataArray
    bands: xr.DataArray
    camera_matrix: xr.DataArray
    truth: np.ndarray  # (image, wavelength, y, x)
    labels: np.ndarray  # (y, x) material index


def camera_matrix_for(wavelength: np.ndarray) -> np.ndarray:
    """Three broad Gaussian channels (R, G, B) with peak 1."""
    centres = np.array([600.0, 540.0, 460.0])
    return np.exp(-0.5 * ((wavelength[None, :] - centres[:, None]) / 40.0) ** 2)


def smooth_spectra(rng: np.random.Generator, wavelength: np.ndarray, count: int) -> np.ndarray:
    """``count`` smooth positive spectra (count, n_wavelength), values about 0.05 .. 1."""
    t = (wavelength - wavelength.min()) / max(np.ptp(wavelength), 1.0)
    out = []
    for _ in range(count):
        c = rng.uniform(0.2, 0.6) + rng.uniform(-0.3, 0.3) * np.cos(
            np.pi * t * rng.uniform(0.5, 2.0) + rng.uniform(0, np.pi)
        )
        out.append(np.clip(c, 0.05, None))
    return np.asarray(out)


def make_scene(
    *,
    size: int = 24,
    n_wavelength: int = 8,
    n_images: int = 1,
    n_materials: int = 3,
    shading: bool = False,
    noise: float = 0.0,
    filter_size: float = 3.0,
    shots: dict[int, list[int]] | None = None,
    brightness: list[float] | None = None,
    rgb_noise: float = 0.0,
    blend: bool = False,
    shading_shift: float = 1.0,
    mirror_odd: bool = False,
    seed: int = 0,
) -> Scene:
    """Vertical stripes of materials; optional smooth shading, band noise and relative RGB
    noise. ``blend=True`` blends the materials continuously from left to right instead
    (every pixel then has its own spectrum and the RGB neighbour graph is connected).
    ``shading_shift`` moves the shading pattern from one image to the next;
    ``mirror_odd`` mirrors the layout of every second image (same materials elsewhere).
    ``shots`` maps image -> band indices it has (default: image 0 has all)."""
    rng = np.random.default_rng(seed)
    wavelength = np.linspace(450.0, 650.0, n_wavelength)
    c = camera_matrix_for(wavelength)
    spectra = smooth_spectra(rng, wavelength, n_materials)
    labels = np.repeat((np.arange(size) * n_materials // size)[None, :], size, axis=0)
    truth = np.empty((n_images, n_wavelength, size, size))
    brightness = brightness or [1.0] * n_images
    if blend:
        position = np.linspace(0, n_materials - 1, size)
        lower = np.minimum(position.astype(int), n_materials - 2)
        t = position - lower
        row = (1 - t)[:, None] * spectra[lower] + t[:, None] * spectra[lower + 1]
        base = np.repeat(row.T[:, None, :], size, axis=1)  # (wavelength, y, x)
    else:
        base = spectra[labels].transpose(2, 0, 1)
    for m in range(n_images):
        cube = (base[:, :, ::-1] if mirror_odd and m % 2 else base) * brightness[m]
        if shading:
            y, x = np.mgrid[0:size, 0:size] / size
            cube = cube * (0.6 + 0.4 * np.cos(3.0 * y + 0.5 * x + shading_shift * m))
        truth[m] = cube
    rgb = np.einsum("cw,mwyx->myxc", c, truth)
    rgb = rgb * (1.0 + rgb_noise * rng.normal(size=rgb.shape))
    shots = shots if shots is not None else {0: list(range(n_wavelength))}
    shot_image, shot_band, data = [], [], []
    for m, band_list in shots.items():
        for b in band_list:
            shot_image.append(m)
            shot_band.append(b)
            data.append(truth[m, b] + noise * rng.normal(size=(size, size)))
    bands = xr.DataArray(
        np.asarray(data),
        dims=("shot", "y", "x"),
        coords={
            "wavelength": ("shot", wavelength[shot_band]),
            "image": ("shot", np.asarray(shot_image)),
            "filter_size": ("shot", np.full(len(data), float(filter_size))),
        },
    )
    rgb_da = xr.DataArray(
        rgb,
        dims=("image", "y", "x", "channel"),
        coords={"image": np.arange(n_images), "channel": ["R", "G", "B"]},
    )
    c_da = xr.DataArray(
        c, dims=("channel", "wavelength"), coords={"channel": ["R", "G", "B"], "wavelength": wavelength}
    )
    return Scene(rgb_da, bands, c_da, truth, labels)


@pytest.fixture
def scene_factory():
    """``scene_factory(**options)`` -> :class:`Scene` (see :func:`make_scene`)."""
    return make_scene
