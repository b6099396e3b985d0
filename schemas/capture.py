"""The capture-folder contract: what a gantry's software writes for ``spectralize ingest``.

One place for the names both sides use: the reader (:mod:`spectralize.flows.ingest`) and the
sample writer (:mod:`spectralize.datasets.capture_folder`). The whole format is described in
``datasets/README.md``, "Capture folders".
"""

from __future__ import annotations

__all__ = ["MANIFEST_COLUMNS", "KINDS"]

MANIFEST_COLUMNS: tuple[str, ...] = (
    "file",
    "kind",
    "camera",
    "rotation",
    "led",
    "exposure_time_s",
    "wavelength_nm",
    "theta_i",
    "phi_i",
    "theta_o",
    "phi_o",
)
"""The columns of ``manifest.csv``, one row per image file (more columns are ignored)."""

KINDS: tuple[str, ...] = ("rgb", "spectral", "dark", "white_reference", "colour_checker", "registration")
"""The values of the ``kind`` column."""
