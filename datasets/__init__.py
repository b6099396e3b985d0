"""Sample data of spectralize, generated deterministically (nothing large is stored in git).

- :mod:`spectralize.nodes.simulation.recipes`: the named simulated gantry runs (``tiny``, ``demo``,
  ``paper``); generate one with ``spectralize run simulate STORE --set simulate.recipe=demo``
  or ``spectralize.nodes.simulation.assembly.simulate_run(get_recipe("demo"))``. See ``README.md`` here.
- :mod:`spectralize.datasets.dark_stack`: a small raw dark stack.
- :mod:`spectralize.datasets.capture_folder`: a simulated run written as a capture folder (the
  format a gantry's software writes; ``README.md`` here, "Capture folders"), for
  ``spectralize ingest``: ``python -m spectralize.datasets.capture_folder OUT``.
"""
