"""This project's own direct estimators: inputs straight to a cube, no iterations of eq. 1.

Unlike :mod:`..baselines` (published methods, for comparison), these are building blocks
of the default solver; each is also a method of
:data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`:

``"endmember-mixture"`` (:mod:`.endmember_mixture`)
    Every pixel a non-negative mixture of a few endmember spectra learnt from all pixels'
    band shots; the abundances from the RGB. The prior of ``"mixture-prior-pcg"``.
``"sparse-choice"`` (:mod:`.sparse_choice`)
    Each texel of a set chooses its few endmembers once, with the evidence of all its
    images; the abundances per image from the RGB.

Not a method: :mod:`.evidence_blend` weighs a set's two estimates, the default's spectra and
the choice's, per texel by the posterior of its band shots.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 2 and 3.
"""

from .endmember_mixture import endmember_mixture
from .sparse_choice import sparse_choice

__all__ = ["endmember_mixture", "sparse_choice"]
