"""The estimates the PCG solvers start from and pull towards, and where the bands were shot.

``S_0``, the RGB-guided filtered bands projected onto ``C S = R`` (per window every band is
an affine function of RGB, which is exact for a material's mix of diffuse and
illuminant-coloured specular reflection), is the start and the guided prior's centre; the
filtered bands projected onto ``C S = R`` are eq. 1's own start. Both come from the
baselines of the same names.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3.
.. [2] He, K., Sun, J., Tang, X. (2013). Guided Image Filtering. IEEE TPAMI 35(6).
"""

from __future__ import annotations

import numpy as np

from ..baselines import filtered_bands_projected, guided_filtered_projected
from ..operators import ReconstructionProblem

__all__ = ["shot_mask", "guided_initial", "projected_filtered_initial"]


def shot_mask(problem: ReconstructionProblem) -> np.ndarray:
    """``(n_wavelength, n_image, 1, 1)``: 1 where the image has a shot of the band, else 0
    (the guided prior acts only there: elsewhere ``S_0`` is a guess, not a measurement)."""
    mask = np.zeros(problem.shape[:2] + (1, 1))
    mask[problem.filters.band, problem.filters.image] = 1.0
    return mask


def projected_filtered_initial(problem: ReconstructionProblem) -> np.ndarray:
    """The filtered bands projected onto ``C S = R`` (baseline ``"filtered-projected"``);
    zeros for a problem built without its inputs."""
    inputs = problem.extras.get("inputs")
    if inputs is None:
        return np.zeros(problem.shape, dtype=problem.dtype)
    return filtered_bands_projected(inputs)


def guided_initial(problem: ReconstructionProblem) -> np.ndarray:
    """``S_0``: the RGB-guided filtered bands projected onto ``C S = R`` (baseline
    ``"guided-projected"``); zeros for a problem built without its inputs."""
    inputs = problem.extras.get("inputs")
    if inputs is None:
        return np.zeros(problem.shape, dtype=problem.dtype)
    return guided_filtered_projected(inputs)
