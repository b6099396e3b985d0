"""The capture-folder format and sample data of spectralize (nothing large is stored in git).

- :mod:`spectralize.nodes.simulation.recipes`: the named simulated gantry runs (``tiny``, ``demo``,
  ``paper``); generate one with ``spectralize run simulate STORE --set simulate.recipe=demo``
  or ``spectralize.nodes.simulation.assembly.simulate_run(get_recipe("demo"))``. See ``README.md`` here.
- :mod:`spectralize.datasets.dark_stack`: a small raw dark stack.
- :mod:`spectralize.datasets.capture`: the capture-folder format (the files a gantry's
  software writes for ``spectralize ingest``; ``README.md`` here, "Capture folders"): its data
  model, parsers and checks, image reader and writers, and a simulated run written as a
  capture folder (``python -m spectralize.datasets.capture.sample OUT``).
"""
