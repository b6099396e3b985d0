"""Node declarations of the reconstruction stage: image sets, seed set, all sets."""

from spectralize.nodes.reconstruction.image_sets import SELECT_IMAGE_SETS
from spectralize.nodes.reconstruction.set_reconstruction import (
    RECONSTRUCT_IMAGE_SETS,
    RECONSTRUCT_SEED_SET,
)

__all__ = ["SELECT_IMAGE_SETS", "RECONSTRUCT_SEED_SET", "RECONSTRUCT_IMAGE_SETS"]
