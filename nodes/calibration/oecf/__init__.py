"""OECF recovery (paper section 4): one method per module.

======================  ===================================================================
module                  what
======================  ===================================================================
``weighting``           certainty weights of pixel values: ``WEIGHTING_FUNCTIONS`` +
                        dispatcher
``robertson``           Robertson et al. 2003 on raw integer codes: :func:`recover_oecf`
``low_snr``             the paper's low-SNR extension: :func:`recover_oecf_low_snr`
``reverse_regression``  the mean code per exposure ``E[v | X]``, which both low ends use
``low_end``             the RGB response's codes just above black (a toe) from it
``response``            response algebra: :func:`apply_response`,
                        :func:`response_at_codes`, :func:`combine_responses`
``log_spline``          a response smoothed to a spline in the log code:
                        :func:`log_spline_response`, its coefficients chosen per channel
                        on the camera's own series: :func:`chosen_log_spline_response`
======================  ===================================================================

References
----------
.. [1] M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2),
   219-228, 2003.
.. [2] Fast Capture of Spectral Image Series, section 4 ("Calibration") and eq. 5.
"""

from .low_snr import recover_oecf_low_snr
from .response import apply_response, combine_responses, response_at_codes
from .robertson import RobertsonResult, recover_oecf, robertson_response
from .weighting import WEIGHTING_FUNCTIONS, Weighting, weighting_function

__all__ = [
    "WEIGHTING_FUNCTIONS",
    "Weighting",
    "weighting_function",
    "RobertsonResult",
    "robertson_response",
    "recover_oecf",
    "recover_oecf_low_snr",
    "apply_response",
    "response_at_codes",
    "combine_responses",
]
