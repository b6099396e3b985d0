"""Scene ``"dark-still-life"``: glossy objects on black velvet, dimly lit.

Thirty domes (balls, beads, buttons) of library materials, some iridescent (thin films),
some speckled (two materials mixed per sample), on a near-black cloth that fills most of
the frame; strong shading over the domes, sharp highlights, vignetting: a low mean
intensity with a few bright spots. Two metameric balls lie in opposite corners.
"""

from __future__ import annotations

import numpy as np

from .layout import SceneLayout, smooth_field
from .materials import material_library, metameric_pair

__all__ = ["dark_still_life"]


def dark_still_life(
    size: int,
    rng: np.random.Generator,
    wavelength: np.ndarray,
    camera_matrix: np.ndarray,
    illuminant: np.ndarray,
) -> SceneLayout:
    """The layout of the dark-still-life scene (see the module docstring)."""
    s = 3
    n = size * s
    reflectance, notes = material_library(wavelength, 32, rng)
    twin = metameric_pair(reflectance[2], camera_matrix, illuminant, rng)
    velvet = np.clip(0.02 + 0.015 * np.sin(wavelength / 40.0), 0.005, 1)
    reflectance = np.vstack([reflectance, twin, velvet])
    notes += ["metamer of material 2", "black velvet"]
    background = 33
    label = np.full((n, n), background, dtype=np.int64)
    height = 0.8 * smooth_field(rng, (n, n), 2.0 * s)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    centres = [(0.13 * n, 0.13 * n, 2), (0.87 * n, 0.87 * n, 32)]
    centres += [(rng.uniform(0, n), rng.uniform(0, n), int(rng.integers(3, 32))) for _ in range(28)]
    speckle = rng.random((n, n))
    for j, (cy, cx, material) in enumerate(centres):
        radius = (0.09 if j < 2 else rng.uniform(0.03, 0.11)) * n
        r2 = ((y - cy) ** 2 + (x - cx) ** 2) / radius**2
        inside = r2 < 1
        dome = radius * np.sqrt(np.clip(1 - r2, 0, 1))
        height = np.where(inside, np.maximum(height, dome), height)
        mat = np.full((n, n), material)
        if j >= 2 and rng.random() < 0.4:
            mat = np.where(speckle < 0.35, int(rng.integers(3, 32)), mat)
        label = np.where(inside, mat, label)
    vignette = 1 - 0.7 * (((y - n / 2) ** 2 + (x - n / 2) ** 2) / (n / 2) ** 2).clip(0, 1)
    occlusion = vignette * (0.5 + 0.5 * smooth_field(rng, (n, n), n / 2))
    specular = np.concatenate([rng.uniform(0.1, 0.5, size=33), [0.01]])
    shininess = np.concatenate([rng.uniform(40.0, 300.0, size=33), [2.0]])
    return SceneLayout(reflectance, label, height, occlusion, specular, shininess, s, [(2, 32)], notes)
