"""Baseline spectral reconstructions, for comparison with eq. 1 on the same data.

Every baseline takes a :class:`~spectralize.nodes.reconstruction.inputs.ReconstructionInputs`
and returns a cube ``(n_wavelength, n_image, height, width)``; one method per module, all
of them listed in :data:`~spectralize.nodes.reconstruction.methods.BASELINE_METHODS` (for
benchmarks and evaluation, not the production nodes) and run through
:func:`~spectralize.nodes.reconstruction.reconstruct`:

``"pseudo-inverse"`` (:mod:`.pseudo_inverse`)
    ``S = C^+ R`` (Imai and Berns): the minimum-norm spectrum with the measured RGB.
``"wiener"`` (:mod:`.wiener`)
    Wiener estimation / linear regression ``S = K C^T (C K C^T + s I)^-1 R`` with the
    second-moment matrix ``K`` of the 190 training reflectances colour-science ships
    (RAW to ACES v1) lit by an illuminant estimated from the bands (:mod:`.training`).
``"mallett2019"`` (:mod:`.mallett2019`)
    colour-science's Mallett and Yuksel (2019) reflectance basis, lit by the same illuminant
    estimate, with coefficients that reproduce the camera RGB exactly.
``"filtered-bands"`` (:mod:`.filtered_bands`)
    The band images filtered by their Gaussian (``sigma_i = s_i / 5``) alone; a band an image
    has no shot of is predicted from its RGB by a linear fit on the images that have it.
``"filtered-projected"`` (:mod:`.filtered_bands`)
    ``filtered-bands`` projected per pixel onto the RGB constraint ``C S = R``
    (:mod:`.projection`): ``S = B + C^T (C C^T)^-1 (R - C B)``. Eq. 1's start.
``"guided-projected"`` (:mod:`.guided_filter`)
    Every band image filtered with the RGB image as guide (He et al.'s guided filter with
    Gaussian windows), then projected onto ``C S = R``. The PCG solvers' guided estimate
    ``S_0`` (start and prior centre, :mod:`..solvers.guided_estimate`).
``"hysure"`` (:mod:`.hysure`)
    Hyperspectral-multispectral fusion as remote sensing does it (Simoes et al.): the
    filtered bands (each blurred by its own Gaussian) and the RGB fused in a subspace
    learnt from the filtered bands, with vector total variation, by ADMM (:mod:`.fusion`).
``"cnmf"`` (:mod:`.cnmf`)
    Coupled nonnegative matrix factorisation unmixing (Yokoya et al.): the filtered bands
    and the RGB unmixed alternately into endmembers and abundances, coupled by the blurs
    and ``C``; ``S = W_h H_m``.

References
----------
.. [1] Imai, F. H., Berns, R. S. (1998). High-resolution multi-spectral image archives: a
   hybrid approach. Color Imaging Conference.
.. [2] Hardeberg, J. Y., Schmitt, F., Brettel, H. (1999). Multispectral image capture using
   a tunable filter. (Wiener-type estimation with prior knowledge of spectra.)
.. [3] Mallett, I., Yuksel, C. (2019). Spectral Primary Decomposition for Rendering with
   sRGB Reflectance. Eurographics Symposium on Rendering.
.. [4] Fast Capture of Spectral Image Series, section 2 ("Hybrid Methods") and section 3.
.. [5] He, K., Sun, J., Tang, X. (2013). Guided Image Filtering. IEEE TPAMI 35(6).
.. [6] Simoes, M., Bioucas-Dias, J., Almeida, L. B., Chanussot, J. (2015). A convex
   formulation for hyperspectral image superresolution via subspace-based regularization.
   IEEE TGRS 53(6).
.. [7] Yokoya, N., Yairi, T., Iwasaki, A. (2012). Coupled nonnegative matrix factorization
   unmixing for hyperspectral and multispectral data fusion. IEEE TGRS 50(2).
"""

from .cnmf import cnmf
from .filtered_bands import filtered_bands, filtered_bands_projected
from .fusion import FusionData, fusion_data
from .guided_filter import (
    GUIDED_EPSILON,
    GUIDED_WINDOW_SCALE,
    guided_filtered_bands,
    guided_filtered_projected,
)
from .hysure import hysure
from .mallett2019 import mallett2019_basis
from .projection import project_onto_rgb
from .pseudo_inverse import pseudo_inverse
from .training import estimate_illuminant, training_reflectances
from .wiener import wiener_estimation

__all__ = [
    "pseudo_inverse",
    "wiener_estimation",
    "mallett2019_basis",
    "filtered_bands",
    "filtered_bands_projected",
    "guided_filtered_bands",
    "guided_filtered_projected",
    "GUIDED_WINDOW_SCALE",
    "GUIDED_EPSILON",
    "hysure",
    "cnmf",
    "FusionData",
    "fusion_data",
    "project_onto_rgb",
    "training_reflectances",
    "estimate_illuminant",
]
