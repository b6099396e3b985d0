"""The capture-folder format: what a gantry's control software writes for ``spectralize ingest``.

A capture folder holds the image files of one measurement run plus three descriptions
(``datasets/README.md``, "Capture folders", is the whole contract):

- :mod:`.model`: file names, columns and kinds, :class:`Row` (a manifest row),
  :class:`Config` (``capture.toml``), :class:`Capture` (a checked folder), :class:`CaptureError`;
- :mod:`.manifest`, :mod:`.config`, :mod:`.calibration`: the parsers of ``manifest.csv``,
  ``capture.toml`` and the calibration tables (text in, result and listed problems out);
- :mod:`.checks`: the rules the rows keep, by row and together;
- :mod:`.images`: reading an image file and probing it against its camera;
- :mod:`.read`: :func:`read_capture`, a whole folder read and checked, every problem listed;
- :mod:`.write`: the writers (image files, manifest, ``capture.toml``, tables);
- :mod:`.sample`: a simulated run written as a capture folder
  (``python -m spectralize.datasets.capture.sample OUT``).

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the gantry) and sec. 4 (its calibration).
"""

from .images import read_image
from .model import (
    ANGLES,
    CALIBRATION,
    CAPTURE_FORMAT,
    CONFIG,
    KINDS,
    MANIFEST,
    MANIFEST_COLUMNS,
    Capture,
    CaptureError,
    Config,
    Row,
)
from .read import read_capture

__all__ = [
    "MANIFEST",
    "CONFIG",
    "CALIBRATION",
    "CAPTURE_FORMAT",
    "MANIFEST_COLUMNS",
    "KINDS",
    "ANGLES",
    "CaptureError",
    "Row",
    "Config",
    "Capture",
    "read_capture",
    "read_image",
]
