"""What every hard scene is made of: a sub-pixel material layout, and how it is rendered.

A :class:`SceneLayout` holds, on a grid ``supersample`` times finer than the pixels, the
material of every sub-pixel sample, a height field (bumps, yarns, domes) and an occlusion
factor (shadows, gaps: the large dark regions). :func:`render_layout` lights and views it
with the normalised Blinn-Phong model of
:func:`~spectralize.nodes.simulation.ground_truth.shading` (highlights have the illuminant's
spectrum) and averages each pixel's samples, so materials mix at sub-pixel scale exactly as
a camera integrates them. The layout is in texel coordinates: rendering it for other light
and view directions gives the rectified images of a BTF set.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 5 (materials, highlights, BTF sets).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..ground_truth import direction

__all__ = ["SceneLayout", "render_layout", "normals_from_height", "box_average", "smooth_field"]


@dataclass
class SceneLayout:
    """A scene in texel coordinates on a ``supersample``-times finer grid.

    Attributes
    ----------
    reflectance
        ``(n_materials, n_wavelength)`` diffuse reflectances.
    label
        ``(size * supersample, size * supersample)`` int material index per sample.
    height
        Same shape, height in sample units (its gradient gives the normal).
    occlusion
        Same shape, in [0, 1]: light reaching the sample (shadows, gaps, vignetting).
    specular, shininess
        ``(n_materials,)`` Blinn-Phong specular albedo and exponent per material.
    supersample
        Samples per pixel along each axis.
    metamers
        Pairs ``(a, b)`` of material indices with the same camera RGB, placed apart.
    notes
        Per material, how it was made.
    """

    reflectance: np.ndarray
    label: np.ndarray
    height: np.ndarray
    occlusion: np.ndarray
    specular: np.ndarray
    shininess: np.ndarray
    supersample: int
    metamers: list[tuple[int, int]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def size(self) -> int:
        """Image height and width in pixels."""
        return self.label.shape[0] // self.supersample

    def material_fractions(self, material: int) -> np.ndarray:
        """``(size, size)`` fraction of each pixel's samples that are ``material``."""
        return box_average((self.label == material).astype(np.float64), self.supersample)


def box_average(samples: np.ndarray, factor: int) -> np.ndarray:
    """Mean over ``factor x factor`` blocks of the last two axes."""
    *lead, h, w = samples.shape
    return samples.reshape(*lead, h // factor, factor, w // factor, factor).mean(axis=(-3, -1))


def smooth_field(rng: np.random.Generator, shape: tuple[int, int], scale: float) -> np.ndarray:
    """A smooth random field in [0, 1] with features of about ``scale`` samples (Fourier sum)."""
    y, x = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    field_ = np.zeros(shape)
    for _ in range(10):
        f = rng.normal(size=2) / scale
        field_ += np.cos(2 * np.pi * (f[0] * y + f[1] * x) + rng.uniform(0, 2 * np.pi))
    field_ -= field_.min()
    return field_ / max(float(field_.max()), 1e-12)


def normals_from_height(height: np.ndarray) -> np.ndarray:
    """Unit normals ``(3, h, w)`` (x, y, z) of a height field in sample units."""
    gy, gx = np.gradient(height)
    n = np.stack([-gx, -gy, np.ones_like(height)])
    return (n / np.linalg.norm(n, axis=0, keepdims=True)).astype(np.float32)


def render_layout(
    layout: SceneLayout,
    illuminant: np.ndarray,
    *,
    theta_i: float,
    phi_i: float,
    theta_o: float,
    phi_o: float,
    intensity: float = 1.0,
) -> np.ndarray:
    """Spectral radiance ``(n_wavelength, size, size)`` of the layout lit and viewed as given.

    ``radiance = intensity * L * (rho * max(n.l, 0) * occlusion + k_s (m + 8) / 8
    max(n.h, 0)**m max(n.l, 0) * occlusion)`` per sample, then averaged per pixel.
    """
    normal = normals_from_height(layout.height)
    light = direction(theta_i, phi_i).astype(np.float32)
    view = direction(theta_o, phi_o).astype(np.float32)
    half = (light + view) / np.linalg.norm(light + view)
    nl = np.maximum(np.tensordot(light, normal, axes=1), 0.0) * layout.occlusion
    nh = np.maximum(np.tensordot(half, normal, axes=1), 0.0)
    nv = np.tensordot(view, normal, axes=1)
    m = layout.shininess[layout.label]
    spec = layout.specular[layout.label] * (m + 8) / 8 * nh**m * nl * (nv > 0)
    s = layout.supersample
    ell = np.asarray(illuminant, dtype=np.float64)
    out = np.empty((ell.size, layout.size, layout.size))
    for b in range(ell.size):
        sample = layout.reflectance[layout.label, b] * nl + spec
        out[b] = box_average(sample, s)
    return intensity * ell[:, None, None] * out
