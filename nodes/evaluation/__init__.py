"""Evaluation (paper sec. 5): accuracy metrics, colorimetry and sRGB, capture time, figures.

=========================  ===================================================================
``metrics``                nRMSE, spectral angle, CIEDE2000, statistics, :func:`evaluate`
                           (Figures 5-7), :func:`compare_methods` (baselines)
``colorimetry``            spectra -> CIE XYZ -> sRGB for display (Figures 5, 6 and 8)
``capture_time``           total exposure of the reference and the fast capture (Figure 8)
``figures``                matplotlib figures of an evaluation (Figures 5-8)
``figures_calibration``    the colour-checker cross-validation figure (Figure 4)
``declarations``           the ``evaluate`` node
=========================  ===================================================================

The figure modules are imported on their own, so that the metrics do not load matplotlib.
"""

from .capture_time import capture_time
from .colorimetry import render_srgb, spectra_to_xyz
from .metrics import (
    colour_difference,
    compare_methods,
    evaluate,
    normalised_rmse,
    spectral_angle,
)

__all__ = [
    "capture_time",
    "colour_difference",
    "compare_methods",
    "evaluate",
    "normalised_rmse",
    "render_srgb",
    "spectra_to_xyz",
    "spectral_angle",
]
