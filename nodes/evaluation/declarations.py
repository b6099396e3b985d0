"""Node declarations of the evaluation stage."""

from spectralize.nodes.evaluation.metrics import EVALUATE

__all__ = ["EVALUATE"]
