"""spectralize.store: the run store, the data contract of :mod:`spectralize.schemas` on disk.

=================  =======================================================================
``run_store``      :class:`RunStore` (create, open, read, write, verify, validate, clean),
                   :func:`open_run`, the bookkeeping attrs of a finished group
``fingerprint``    :func:`compute_fingerprint`: what makes a finished group up to date
``integrity``      the manifest of a group's files and their CRC-32, :class:`ChecksumError`
``staging``        staged writes: unique temporary names, resumable regions, atomic renames
``layout``         how a Dataset is chunked and typed on disk, and the view on reading
``precision``      float arrays rounded to the precision their schema declares, and its checks
``lock``           one writer per store: :class:`StoreLock`, :class:`StoreBusyError`,
                   :func:`work_dir`
=================  =======================================================================

Nothing here imports Prefect or any node: a notebook opens a run with
``open_run("run.zarr").read("spectra")``.
"""

from .fingerprint import compute_fingerprint
from .integrity import ChecksumError
from .lock import LockHolder, StoreBusyError, StoreLock, work_dir
from .run_store import (
    FINGERPRINT_ATTR,
    MANIFEST_ATTR,
    PROVENANCE_ATTR,
    SCHEMA_ATTR,
    RunStore,
    open_run,
)

__all__ = [
    "RunStore",
    "open_run",
    "compute_fingerprint",
    "ChecksumError",
    "StoreBusyError",
    "StoreLock",
    "LockHolder",
    "work_dir",
    "FINGERPRINT_ATTR",
    "PROVENANCE_ATTR",
    "SCHEMA_ATTR",
    "MANIFEST_ATTR",
]
