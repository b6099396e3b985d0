"""Scene ``"woven-fabric"``: a tartan of dyed yarns woven at sub-pixel scale.

Warp and weft threads about 2 px apart (so every pixel mixes 2 to 4 yarns), each yarn a
material of the library with a stripe sequence (tartan); plain weave, the thread on top
alternating; round yarn profiles give strong shading, the gaps between threads are dark,
and a fold casts a shadow over a third of the cloth. Two stripes of metameric yarns lie in
opposite corners.
"""

from __future__ import annotations

import numpy as np

from .layout import SceneLayout, smooth_field
from .materials import material_library, metameric_pair

__all__ = ["woven_fabric"]


def woven_fabric(
    size: int,
    rng: np.random.Generator,
    wavelength: np.ndarray,
    camera_matrix: np.ndarray,
    illuminant: np.ndarray,
) -> SceneLayout:
    """The layout of the woven-fabric scene (see the module docstring)."""
    s = 4
    n = size * s
    reflectance, notes = material_library(wavelength, 18, rng)
    twin = metameric_pair(reflectance[0], camera_matrix, illuminant, rng)
    reflectance = np.vstack([reflectance, twin])
    notes.append("metamer of material 0")
    period = rng.uniform(7.0, 9.0)  # samples per thread: about 2 px
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    warp_index = np.floor(x / period).astype(int)
    weft_index = np.floor(y / period).astype(int)
    stripes = rng.integers(1, 18, size=64)
    widths = rng.integers(2, 9, size=64)
    sequence = np.repeat(stripes, widths)
    warp_colour = sequence[warp_index % sequence.size]
    weft_colour = sequence[(weft_index * 3 + 7) % sequence.size]
    # metamer stripes: material 0 near the top left, its metamer near the bottom right
    corner = n // 4
    warp_colour = np.where((x < corner) & (y < corner) & (warp_index % 5 < 3), 0, warp_colour)
    warp_colour = np.where((x > n - corner) & (y > n - corner) & (warp_index % 5 < 3), 18, warp_colour)
    warp_on_top = (warp_index + weft_index) % 2 == 0
    label = np.where(warp_on_top, warp_colour, weft_colour)
    u = (x / period) % 1.0
    v = (y / period) % 1.0
    across = np.where(warp_on_top, u, v)
    along = np.where(warp_on_top, v, u)
    profile = np.sqrt(np.clip(1 - (2 * across - 1) ** 2, 0, 1))
    height = 2.5 * profile + 1.0 * np.sin(np.pi * along)
    gaps = np.clip(profile * 1.6, 0.25, 1.0)
    fold = smooth_field(rng, (n, n), n / 2.5)
    shadow = np.where(fold > 0.62, 0.12, 1.0)
    occlusion = gaps * shadow
    specular = rng.uniform(0.0, 0.08, size=len(reflectance))
    shininess = rng.uniform(8.0, 30.0, size=len(reflectance))
    return SceneLayout(reflectance, label, height, occlusion, specular, shininess, s, [(0, 18)], notes)
