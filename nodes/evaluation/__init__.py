"""Evaluation (paper sec. 5): accuracy metrics, colorimetry and sRGB, capture time, figures.

=========================  ===================================================================
``accuracy``               :func:`evaluate`, the ``evaluate`` node's function (Figures 5-7)
``pixel_metrics``          per-pixel nRMSE, spectral angle and CIEDE2000 maps
``statistics``             per-image and per-subset statistics, nRMSE histograms
``band_shots``             which images have band shots (Figure 7's two subsets)
``representative``         representative spectra at low and high error (Figures 5, 6)
``cubes``                  the checks and alignment of a reconstruction and its truth
``illuminants``            the CIEDE2000 illuminants by name, without colour-science
``comparison``             :func:`compare_methods`: several methods side by side (baselines)
``colorimetry``            spectra -> CIE XYZ -> sRGB for display (Figures 5, 6 and 8)
``relit_colour``           spectra relit under CIE A, FL11, D65 and their CIEDE2000 to the truth
``capture_time``           total exposure of the reference and the fast capture (Figure 8)
``figures``                matplotlib figures of an evaluation (Figures 5-8)
``figures_calibration``    the colour-checker cross-validation figure (Figure 4)
``declarations``           the ``evaluate`` node
=========================  ===================================================================

The figure modules are imported on their own, so that the metrics do not load matplotlib.
"""

from .accuracy import evaluate
from .capture_time import capture_time
from .colorimetry import render_srgb, spectra_to_xyz
from .comparison import compare_methods
from .pixel_metrics import colour_difference, normalised_rmse, spectral_angle
from .relit_colour import relight, relit_delta_e

__all__ = [
    "capture_time",
    "colour_difference",
    "compare_methods",
    "evaluate",
    "normalised_rmse",
    "relight",
    "relit_delta_e",
    "render_srgb",
    "spectra_to_xyz",
    "spectral_angle",
]
