"""spectralize: calibrated spectral image cubes from the runs of a spectral BTF gantry.

The method is that of *Fast Capture of Spectral Image Series*: short, noisy band images of a
monochrome camera behind a tunable filter and good HDR images of RGB cameras are reconstructed
into spectra (eq. 1). The sub-packages are the design card's folders, each a room of its own,
imported one way::

    spectralize.schemas   the data contract of a run store (groups, dims, units, errors)
    spectralize.store     the run store on disk (zarr): integrity, staging, lock, reading
    spectralize.engine    node declarations, the registry and the graph check
    spectralize.nodes     the science, by paper stage (simulation, calibration,
                          reconstruction, evaluation)
    spectralize.datasets  the capture-folder format and sample data
    spectralize.flows     Prefect flows, the command line, ingest, report and export

``import spectralize`` loads none of them; import what you use, for example
``from spectralize.store import open_run``.
"""

from importlib.metadata import PackageNotFoundError, version

__all__ = ["__version__"]

try:
    __version__: str = version("spectralize")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
