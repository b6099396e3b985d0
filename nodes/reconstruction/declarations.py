"""Node declarations of the reconstruction stage: image sets, the run's endmember library,
seed set, all sets.

The science lives beside this module (:mod:`.image_sets`, :mod:`.endmember_library`,
:mod:`.set_reconstruction`); each
node's parameters are its function's keyword-only arguments, from which the engine derives
the frozen parameter model (``method`` takes exactly the production methods of
:data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`, checked when the
graph is checked; the comparison baselines are not the nodes'; a solver setting left None
is the method's). The engine also checks every input group against its schema before a
node runs.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 4 and 5.
"""

from spectralize.engine import Node
from spectralize.nodes.reconstruction.endmember_library import endmember_library
from spectralize.nodes.reconstruction.image_sets import select_image_sets
from spectralize.nodes.reconstruction.set_reconstruction import (
    DISK_TILE,
    reconstruct_image_sets,
    reconstruct_seed_set,
)

__all__ = ["SELECT_IMAGE_SETS", "ENDMEMBER_LIBRARY", "RECONSTRUCT_SEED_SET", "RECONSTRUCT_IMAGE_SETS"]

SELECT_IMAGE_SETS = Node(
    name="select_image_sets",
    version="1",
    function=select_image_sets,
    inputs={"images": "raw/rgb", "shots": "raw/spectral"},
    outputs=("image_sets",),
    description="Split the run into sets of images with band shots plus similar-light images.",
)

ENDMEMBER_LIBRARY = Node(
    name="endmember_library",
    version="1",
    function=endmember_library,
    inputs={"hdr": "hdr", "bands": "bands", "calibration": "camera_matrix", "image_sets": "image_sets"},
    outputs=("endmember_library",),
    description="Learn the run's endmember library once from the pooled band shots of a "
    "sample of its image sets.",
)

RECONSTRUCT_SEED_SET = Node(
    name="reconstruct_seed_set",
    # 2: tiled (parameter ``tile``), iterations per image instead of an attr; 3: confidence;
    # 4: the mixture's band-noise estimate robust to texture, brightness-weighted prior;
    # 5: gamma_hat and max_iterations default to the method's settings, no baselines;
    # 6: each image's RGB mapped into the paired camera's (calibration/spectral rgb_transform)
    # 7: each image through its own camera's C (T_k C_k from camera_matrices)
    # 8: the mixture prior's compiled passes (box windows, 3 x 3 inverses: float noise)
    # 9: the default's set model 'material-pooled' where the calibration has the illuminant
    # 10: the run's endmember library (input endmember_library) mixed instead of the set's own
    # 11: 'material-pooled' trusts the RGB as far as the set shows (its noise per image, the
    # sandwich variance in the gain, the fit moved towards the RGB by that noise)
    # 12: the default's set model 'evidence-blend' (with the run's library, the material
    # choice weighed in per texel by the band evidence)
    # 13: the material choice's fits compiled (float noise in its support costs)
    version="13",
    function=reconstruct_seed_set,
    inputs={
        "hdr": "hdr",
        "bands": "bands",
        "calibration": "camera_matrix",
        "image_sets": "image_sets",
        "endmember_library": "endmember_library",
    },
    outputs=("spectra_seed",),
    chunks={"spectra_seed": {"y": DISK_TILE, "x": DISK_TILE}},
    description="Solve eq. 1 for the seed image set from a cold start, tile by tile.",
)

RECONSTRUCT_IMAGE_SETS = Node(
    name="reconstruct_image_sets",
    # 2: tiled (parameter ``tile``), warm start from a strided seed sample; 3: as the seed
    # set's version 4; 4: as the seed set's version 5; 5: as the seed set's version 6;
    # 6: as the seed set's version 7; 7: as the seed set's version 8; 8: as its version 9;
    # 9: as its version 10; 10: as its version 11; 11: as its version 12; 12: as its version 13
    version="12",
    function=reconstruct_image_sets,
    inputs={
        "hdr": "hdr",
        "bands": "bands",
        "calibration": "camera_matrix",
        "image_sets": "image_sets",
        "spectra_seed": "spectra_seed",
        "endmember_library": "endmember_library",
    },
    outputs=("spectra",),
    chunks={"spectra": {"y": DISK_TILE, "x": DISK_TILE}},  # the tiles line up with them
    resumable_along={"spectra": "image"},
    description="All image sets, warm-started from the seed, in parallel tile by tile; "
    "written set by set.",
)
