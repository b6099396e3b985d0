"""Scene ``"glossy-mosaic"``: glazed tiles of many materials with fine grain and highlights.

About 90 Voronoi tiles of 40 library materials, each tile a fine-grained mix of two
materials (grain of about a pixel), bumpy glossy glaze with sharp highlights in the LED's
spectrum, dark grout lines, and a deep shadow over 40 % of the wall. Two tiles of metameric
glazes sit in opposite corners.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .layout import SceneLayout, smooth_field
from .materials import material_library, metameric_pair

__all__ = ["glossy_mosaic"]


def glossy_mosaic(
    size: int,
    rng: np.random.Generator,
    wavelength: np.ndarray,
    camera_matrix: np.ndarray,
    illuminant: np.ndarray,
) -> SceneLayout:
    """The layout of the glossy-mosaic scene (see the module docstring)."""
    s = 3
    n = size * s
    reflectance, notes = material_library(wavelength, 40, rng)
    twin = metameric_pair(reflectance[1], camera_matrix, illuminant, rng)
    grout = np.full(wavelength.size, 0.04)
    reflectance = np.vstack([reflectance, twin, grout])
    notes += ["metamer of material 1", "grout"]
    n_tiles = 90
    seeds = rng.uniform(0, n, size=(n_tiles, 2))
    seeds[0] = (n * 0.1, n * 0.1)
    seeds[1] = (n * 0.9, n * 0.9)
    y, x = np.mgrid[0:n, 0:n]
    points = np.stack([y.ravel(), x.ravel()], axis=1)
    distance, nearest = cKDTree(seeds).query(points, k=2)
    tile = nearest[:, 0].reshape(n, n)
    edge = (distance[:, 1] - distance[:, 0]).reshape(n, n) < 1.5 * s
    first = rng.integers(2, 40, size=n_tiles)
    second = rng.integers(2, 40, size=n_tiles)
    first[0], second[0] = 1, 1
    first[1], second[1] = 40, 40
    share = rng.uniform(0.0, 0.6, size=n_tiles)
    grain = rng.random((n // 2 + 1, n // 2 + 1)).repeat(2, 0).repeat(2, 1)[:n, :n]
    label = np.where(grain < share[tile], second[tile], first[tile])
    label = np.where(edge, 41, label)
    bumps = smooth_field(rng, (n, n), 4.0 * s)
    dome = np.clip(1 - (distance[:, 0].reshape(n, n) / (n / 7)) ** 2, 0, 1)
    height = 3.0 * s * dome + 1.5 * bumps
    shadow = smooth_field(rng, (n, n), n / 2)
    occlusion = np.where(shadow > np.quantile(shadow, 0.6), 1.0, 0.06)
    occlusion = np.where(edge, occlusion * 0.5, occlusion)
    specular = np.concatenate([rng.uniform(0.02, 0.12, size=41), [0.0]])
    shininess = np.concatenate([rng.uniform(20.0, 120.0, size=41), [1.0]])
    return SceneLayout(reflectance, label, height, occlusion, specular, shininess, s, [(1, 40)], notes)
