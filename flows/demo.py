"""``spectralize demo``: the sample run, processed.

Two ways, both resumable (a second call finds everything up to date):

- :func:`run_capture_demo` (``spectralize demo --capture DIR``, ``make demo``): the real path.
  A sample capture folder (image files, ``manifest.csv``, ``capture.toml``, ``calibration/``)
  is written from the simulator (deterministic, nothing kept in git), ingested into a run
  store, processed by the ``btf`` flow and reported, exactly as a lab's capture would be.
- :func:`run_demo` (``spectralize demo``): the ``demo`` flow, which simulates the run straight
  into the store (with ground truth) and processes it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from spectralize.store import RunStore

from . import run_flow
from .steps import RunReport

__all__ = ["DEMO_STORE", "DEMO_CAPTURE", "run_demo", "run_capture_demo", "write_sample_capture"]

DEMO_STORE = Path("demo") / "run.zarr"
DEMO_CAPTURE = Path("demo") / "capture"


def run_demo(
    path: str | Path = DEMO_STORE, *, parameters: dict | None = None
) -> tuple[RunStore, RunReport]:
    """Run the ``demo`` flow: simulate the sample run (recipe ``demo``) and process it.

    Both halves resume: a second call finds every group up to date and skips every node.
    ``parameters`` overrides node parameters (``{"simulate.recipe": "tiny"}``).
    """
    report = run_flow("demo", path, parameters=parameters)
    return RunStore.open(path), report


def write_sample_capture(
    folder: str | Path = DEMO_CAPTURE,
    *,
    recipe: str = "demo",
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write the sample capture folder unless it is there (its ``manifest.csv`` exists)."""
    from spectralize.datasets.capture.sample import write_capture_folder

    folder = Path(folder)
    if (folder / "manifest.csv").is_file():
        return folder
    return write_capture_folder(folder, recipe=recipe, progress=progress)


def run_capture_demo(
    capture: str | Path = DEMO_CAPTURE,
    store: str | Path = DEMO_STORE,
    *,
    recipe: str = "demo",
    parameters: dict | None = None,
    progress: Callable[[str], None] | None = print,
) -> tuple[RunStore, RunReport, Path]:
    """Write the sample capture folder, ingest it, run ``btf`` and write the report.

    Returns the store, the flow's report and the path of the HTML report.
    """
    from .ingest import ingest
    from .pipelines import report_directory
    from .report import write_run_report

    write_sample_capture(capture, recipe=recipe, progress=progress)
    ingest(capture, store, progress=progress)
    report = run_flow("btf", store, parameters=parameters)
    page = write_run_report(store, directory=report_directory(store))
    report.report = str(page)
    return RunStore.open(store), report, page
