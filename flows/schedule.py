"""Scheduled processing: every night, process the run folders that arrived.

A lab serves :func:`process_new_runs` as a Prefect deployment with a cron schedule::

    prefect server start --background            # Prefect's API and UI on 127.0.0.1:4200
    prefect config set PREFECT_API_URL=http://127.0.0.1:4200/api
    spectralize serve /data/btf-runs --flow btf --cron "0 2 * * *"

With ``--output-root``, ROOT holds *capture folders* (``datasets/README.md``, "Capture
folders"), as a gantry's software writes them::

    spectralize serve /data/captures --output-root /data/runs --cron "0 2 * * *"

Each night a new or grown capture folder is ingested into ``/data/runs/<folder>.zarr``
(incrementally: only new frames are read) and processed; its report is written beside the
store. A folder still being written (files its manifest lists not there yet, or any file
changed within ``--settle-minutes``) is left for the next night, and the log says so.

Because every flow resumes from the fingerprints in its store, processing "new" runs is
simply processing all of them: finished runs are skipped node by node in seconds, half-done
runs continue where they stopped, and new runs are processed from scratch.
"""

from __future__ import annotations

from pathlib import Path

from prefect import flow, get_run_logger

from spectralize.schemas import SpectralizeError
from spectralize.store import RunStore, StoreBusyError

__all__ = [
    "find_run_stores",
    "find_capture_folders",
    "ingest_captures",
    "process_new_runs",
    "serve_nightly",
    "failure_line",
]


def find_run_stores(root: str | Path, pattern: str = "*.zarr") -> list[Path]:
    """Run stores directly under ``root`` (or matching ``pattern``), sorted by name."""
    found = []
    for path in sorted(Path(root).glob(pattern)):
        try:
            RunStore.open(path)
        except SpectralizeError:
            continue
        found.append(path)
    return found


def find_capture_folders(root: str | Path) -> list[Path]:
    """Folders directly under ``root`` that are (or are becoming) capture folders, by name.

    A folder counts once it has a ``manifest.csv`` or a ``capture.toml``; whether it is
    complete is :func:`spectralize.flows.ingest.capture_state`'s question.
    """
    return sorted(
        p
        for p in Path(root).iterdir()
        if p.is_dir() and ((p / "manifest.csv").is_file() or (p / "capture.toml").is_file())
    )


def ingest_captures(
    root: str | Path, output_root: str | Path, *, settle_seconds: float = 300.0, log=None
) -> dict[str, str]:
    """Ingest every complete capture folder under ``root`` into ``output_root/<name>.zarr``.

    Returns ``{folder: outcome}``: ``"waiting: ..."`` (still being written),
    ``"ingested: ..."``, ``"up to date"`` or ``"failed: ..."`` (bad input; nothing written).
    """
    from spectralize.flows.ingest import capture_state, ingest

    say = log.info if log is not None else print
    output = Path(output_root)
    output.mkdir(parents=True, exist_ok=True)
    outcome: dict[str, str] = {}
    for folder in find_capture_folders(root):
        state = capture_state(folder, settle_seconds=settle_seconds)
        if not state.ready:
            outcome[str(folder)] = f"waiting: {state.reason}"
            say(f"{folder.name}: still being written, left for the next run ({state.reason})")
            continue
        try:
            report = ingest(folder, output / f"{folder.name}.zarr", progress=None)
        except StoreBusyError as error:
            outcome[str(folder)] = f"waiting: {error.summary}"
            say(f"{folder.name}: its store is busy, left for the next run")
            continue
        except SpectralizeError as error:
            outcome[str(folder)] = f"failed: {error}"
            (log.error if log is not None else print)(f"{folder.name}: cannot ingest: {error}")
            continue
        written = [g for g, status in report.groups.items() if status == "written"]
        outcome[str(folder)] = (
            f"ingested: {', '.join(written)} ({report.frames_read} new frame(s))"
            if written
            else "up to date"
        )
        say(f"{folder.name}: {outcome[str(folder)]}")
    return outcome


@flow(name="spectralize-nightly", log_prints=True)
def process_new_runs(
    root: str,
    flow_name: str = "btf",
    pattern: str = "*.zarr",
    dask_address: str | None = None,
    output_root: str | None = None,
    settle_seconds: float = 300.0,
) -> dict[str, str]:
    """Run ``flow_name`` on every run store under ``root``; report each store's outcome.

    With ``output_root``, ``root`` holds capture folders: the complete ones are ingested
    first (:func:`ingest_captures`) and the run stores under ``output_root`` are processed,
    each with its HTML report. A store that fails does not stop the others; the flow run
    fails at the end if any did, so the failure is visible in Prefect's UI.
    """
    from spectralize.flows import run_flow

    log = get_run_logger()
    outcome: dict[str, str] = {}
    if output_root is not None:
        outcome.update(ingest_captures(root, output_root, settle_seconds=settle_seconds, log=log))
        root = output_root
    stores = find_run_stores(root, pattern)
    log.info(f"{len(stores)} run store(s) under {root}")
    for index, store in enumerate(stores, start=1):
        log.info(f"[{index}/{len(stores)}] {store.name}")
        try:
            report = run_flow(flow_name, store, dask_address=dask_address)
        except StoreBusyError as error:  # another run writes it (a manual one): not a failure
            log.warning(f"{store.name}: skipped, {error.summary}")
            outcome[str(store)] = f"skipped: {error.summary}"
            continue
        except Exception as error:  # reported per store, raised below
            log.error(f"{store.name}: {type(error).__name__}: {error}")
            outcome[str(store)] = f"failed: {error}"
            continue
        ran = sum(step.status == "ran" for step in report.steps)
        outcome[str(store)] = f"{ran} node(s) ran, {len(report.steps) - ran} up to date"
        if report.report is not None:  # the flow writes it, with or without ground truth
            outcome[str(store)] += f", report {report.report}"
        log.info(f"{store.name}: {outcome[str(store)]}")
    failed = [name for name, result in outcome.items() if result.startswith("failed")]
    if failed:
        raise SpectralizeError(failure_line(outcome, set(map(str, stores))))
    return outcome


def failure_line(outcome: dict[str, str], stores: set[str]) -> str:
    """``"1 of 3 capture folder(s) and 1 of 2 run store(s) failed: [...]"``: each counted apart.

    ``outcome`` holds both the capture folders ingested and the run stores processed;
    ``stores`` names the latter.
    """
    parts = []
    for what, names in (
        ("capture folder(s)", [n for n in outcome if n not in stores]),
        ("run store(s)", [n for n in outcome if n in stores]),
    ):
        bad = [n for n in names if outcome[n].startswith("failed")]
        if names and (bad or what == "run store(s)"):
            parts.append(f"{len(bad)} of {len(names)} {what}")
    failed = [n for n, result in outcome.items() if result.startswith("failed")]
    return f"{' and '.join(parts)} failed: {failed}"


def serve_nightly(
    root: str,
    *,
    flow_name: str = "btf",
    cron: str = "0 2 * * *",
    pattern: str = "*.zarr",
    dask_address: str | None = None,
    name: str = "nightly",
    output_root: str | None = None,
    settle_seconds: float = 300.0,
) -> None:
    """Serve :func:`process_new_runs` on a cron schedule (needs a Prefect server)."""
    process_new_runs.serve(
        name=name,
        cron=cron,
        parameters={
            "root": str(Path(root).absolute()),
            "flow_name": flow_name,
            "pattern": pattern,
            "dask_address": dask_address,
            "output_root": str(Path(output_root).absolute()) if output_root else None,
            "settle_seconds": float(settle_seconds),
        },
        description=f"process run stores under {root} with the {flow_name!r} flow",
    )
