"""Scene ``"halftone-print"``: a four-ink print on brightened paper, dots below a pixel.

A tinted, brightened paper; four process inks and two spot inks (transmittances from the
library, each with a dye band) are screened at rotated angles with a dot pitch of 2.5 to
3.5 px, so every pixel averages several dots of
overlapping inks (subtractive: transmittances multiply, which no linear mixture of the
collections reproduces). Coverage follows smooth images; a rich-black block covers a
quarter of the sheet; two spot inks are metamers, printed in opposite corners; slight
paper relief and a glossy ink give weak highlights.
"""

from __future__ import annotations

import numpy as np

from .layout import SceneLayout, smooth_field
from .materials import _smooth_noise, material_library, metameric_pair

__all__ = ["halftone_print"]


def halftone_print(
    size: int,
    rng: np.random.Generator,
    wavelength: np.ndarray,
    camera_matrix: np.ndarray,
    illuminant: np.ndarray,
) -> SceneLayout:
    """The layout of the halftone-print scene (see the module docstring)."""
    s = 4
    n = size * s
    library, lib_notes = material_library(wavelength, 12, rng)
    paper = 0.8 + 0.15 * np.exp(-0.5 * ((wavelength - 440) / 15) ** 2)  # optical brightener
    paper = np.clip(paper * (1 + 0.45 * _smooth_noise(rng, wavelength, 10.0)), 0, 0.98)  # tinted stock
    inks = np.clip(library[:6] / library[:6].max(axis=1, keepdims=True), 0.01, 0.95)  # transmittances
    for j in range(6):  # every ink's dye has a narrow absorption band
        centre, width = rng.uniform(440, 680), rng.uniform(10, 25)
        inks[j] = inks[j] * 10.0 ** (
            -rng.uniform(1.0, 2.0) * np.exp(-0.5 * ((wavelength - centre) / width) ** 2)
        )
    inks[3] = np.full(wavelength.size, 0.06)  # black
    spot = metameric_pair(library[6] * 0.9, camera_matrix, illuminant, rng)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    dots = []
    for j, angle in enumerate((15.0, 75.0, 0.0, 45.0, 30.0, 60.0)):
        pitch = rng.uniform(10.0, 14.0)
        a = np.deg2rad(angle)
        u = (np.cos(a) * x + np.sin(a) * y) / pitch
        w = (-np.sin(a) * x + np.cos(a) * y) / pitch
        screen = 0.5 * (np.cos(2 * np.pi * u) * np.cos(2 * np.pi * w) + 1)  # 1 at dot centres
        coverage = 0.15 + 0.8 * smooth_field(rng, (n, n), n / (3 + j))
        if j == 3:
            coverage = np.where((x > n * 0.55) & (y < n * 0.5), 0.95, coverage * 0.5)
        if j >= 4:
            coverage = coverage * 0.6
        dots.append(screen > 1 - coverage)
    # every distinct combination of inks is one material (paper x product of transmittances)
    code = sum(d.astype(np.int64) << j for j, d in enumerate(dots))
    # spot inks: the metamer pair solid in two opposite corners, over the paper alone
    corner = n // 5
    code = np.where((x < corner) & (y > n - corner), 64, code)
    code = np.where((x > n - corner) & (y > n - corner), 65, code)
    reflectance = np.empty((66, wavelength.size))
    for c in range(64):
        t = np.ones(wavelength.size)
        for j in range(6):
            if c >> j & 1:
                t = t * inks[j]
        reflectance[c] = np.clip(paper * t, 0.005, 0.98)
    reflectance[64] = library[6] * 0.9
    reflectance[65] = spot
    height = 0.6 * smooth_field(rng, (n, n), 6.0) + 0.3 * dots[3]
    occlusion = 0.35 + 0.65 * smooth_field(rng, (n, n), n)  # uneven light over the sheet
    specular = np.full(66, 0.02)
    specular[[c for c in range(64) if c & 0b1111]] = 0.06
    shininess = np.full(66, 40.0)
    notes = [f"inks {c:06b} on paper" for c in range(64)] + [lib_notes[6], "metamer of spot ink"]
    return SceneLayout(reflectance, code, height, occlusion, specular, shininess, s, [(64, 65)], notes)
