"""Node declarations of the evaluation stage (paper sec. 5).

``evaluate``: nRMSE, spectral angle and CIEDE2000 of the reconstruction against the ground
truth, with statistics, histograms and representative spectra
(:func:`spectralize.nodes.evaluation.accuracy.evaluate`). Its parameters are the function's
keyword-only arguments, derived by the engine from their annotations (constraints, the
illuminant table) and numpydoc descriptions. Registered through the entry point
``spectralize.nodes: evaluate = spectralize.nodes.evaluation.declarations:EVALUATE``.
"""

from __future__ import annotations

from spectralize.engine import Node
from spectralize.nodes.evaluation.accuracy import evaluate

__all__ = ["EVALUATE"]

EVALUATE = Node(
    name="evaluate",
    version="1",
    function=evaluate,
    inputs={"spectra": "spectra", "truth": "truth/spectra", "shots": "raw/spectral"},
    outputs=("evaluation",),
    description="nRMSE / spectral angle / CIEDE2000 maps and statistics against the ground "
    "truth (sec. 5, Fig. 5-7).",
)
