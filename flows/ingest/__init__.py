"""``spectralize ingest`` and the readiness question of ``spectralize serve``: orchestration only.

The capture-folder format (its model, parsers, checks, image reader and writers) is
:mod:`spectralize.datasets.capture`; here it is put into a run store:

- :mod:`.write`: :func:`ingest`, incremental (only new files read, unchanged groups skipped);
- :mod:`.raw_groups`: the raw groups built from a checked capture folder, and their fingerprints;
- :mod:`.readiness`: :func:`capture_state`, whether a folder is complete (nightly runs).

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the measurement run a capture folder holds).
"""

from .raw_groups import INGEST_VERSION, RAW_GROUPS
from .readiness import CaptureState, capture_state
from .write import IngestReport, ingest

__all__ = ["INGEST_VERSION", "RAW_GROUPS", "IngestReport", "ingest", "CaptureState", "capture_state"]
