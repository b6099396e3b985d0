"""spectralize.nodes: the science, as pure functions, one sub-package per stage of the paper.

- :mod:`~spectralize.nodes.simulation`: the capture model (eq. 2, 3, 5), ground truth, gantry
  and sample-run recipes;
- :mod:`~spectralize.nodes.calibration`: dark frames, OECF, HDR merge, spectral calibration,
  registration, band radiance (section 4);
- :mod:`~spectralize.nodes.reconstruction`: eq. 1 and its baselines, image sets, warm start;
- :mod:`~spectralize.nodes.evaluation`: metrics, colorimetry, capture-time accounting.

Each stage declares its nodes in its ``declarations`` module. Nothing here imports Prefect, and
no pipeline stage imports :mod:`~spectralize.nodes.simulation`.
"""
