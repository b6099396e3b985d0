"""Evaluation (paper section 5): accuracy metrics, colorimetry and sRGB, capture-time accounting."""

from .capture_time import capture_time
from .colorimetry import render_srgb, spectra_to_xyz
from .metrics import colour_difference, evaluate, normalised_rmse, spectral_angle

__all__ = [
    "capture_time",
    "render_srgb",
    "spectra_to_xyz",
    "colour_difference",
    "evaluate",
    "normalised_rmse",
    "spectral_angle",
]
