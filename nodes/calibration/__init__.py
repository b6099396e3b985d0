"""Calibration at the noise floor (paper section 4).

Dark frames, the OECF (Robertson 2003 and its low-SNR extension), the HDR merge, spectral
calibration (QE, camera matrix C, cross-validation), registration and band radiance.
"""

from .dark import average_dark_frames
from .hdr import merge_hdr
from .oecf import recover_oecf, recover_oecf_low_snr
from .registration import estimate_shift, register_frames
from .spectral import camera_matrix, cross_validate, quantum_efficiency

__all__ = [
    "average_dark_frames",
    "merge_hdr",
    "recover_oecf",
    "recover_oecf_low_snr",
    "estimate_shift",
    "register_frames",
    "camera_matrix",
    "cross_validate",
    "quantum_efficiency",
]
