"""Calibration at the noise floor (paper section 4): one method per module.

====================  =====================================================================
module                what
====================  =====================================================================
``dark``              dark-frame averaging and the one dark-frame lookup per exposure time
``exposure_series``   checks shared by every exposure series (bit depth, times, saturation)
``oecf/``             the camera response: ``weighting``, ``robertson`` (Robertson 2003),
                      ``low_snr`` (the paper's extension), ``response`` (response algebra)
``hdr``               HDR merge of RGB exposure series (Robertson's estimator)
``spectral``          the ``calibrate_spectral`` node: Q, C and the cross-validation (Fig. 4)
``band_shots``        band-filtered shots: dark-subtracted, linearised band signal
``white_reference``   quantum efficiency Q and the measured illuminant L on the bands
``camera_smooth``     C by a second-difference penalty
``camera_lobes``      C as a non-negative sum of smooth lobes (the default fit of C)
``camera_matrices``   C of every RGB camera from its HDR RGB of the colour checker
``chart_patches``     the colour checker's patch labels and patch means
``cross_validation``  the spectral capture of the chart through C against the RGB (Fig. 4)
``matched_level_qe``  Q of the white reference at each band shot's own signal level
``registration``      spectral-to-RGB misregistration (phase correlation) and resampling
``band_radiance``     calibrated, registered band radiance of every shot
``declarations``      the calibration nodes: parameters and :class:`~spectralize.engine.Node` s
====================  =====================================================================
"""

from .band_radiance import calibrate_bands
from .band_shots import band_signal
from .camera_smooth import camera_matrix
from .cross_validation import cross_validate
from .dark import average_dark_frames, dark_frames_at
from .hdr import merge_hdr
from .oecf import apply_response, combine_responses, recover_oecf, recover_oecf_low_snr
from .registration import estimate_registration, estimate_shift, register_frames
from .white_reference import quantum_efficiency

__all__ = [
    "average_dark_frames",
    "dark_frames_at",
    "recover_oecf",
    "recover_oecf_low_snr",
    "apply_response",
    "combine_responses",
    "merge_hdr",
    "band_signal",
    "quantum_efficiency",
    "camera_matrix",
    "cross_validate",
    "estimate_shift",
    "estimate_registration",
    "register_frames",
    "calibrate_bands",
]
