"""Scheduled processing: every night, process the run folders that arrived.

A lab serves :func:`process_new_runs` as a Prefect deployment with a cron schedule::

    prefect server start --background            # Prefect's API and UI on 127.0.0.1:4200
    prefect config set PREFECT_API_URL=http://127.0.0.1:4200/api
    spectralize serve /data/btf-runs --flow btf --cron "0 2 * * *"

Because every flow resumes from the fingerprints in its store, processing "new" runs is
simply processing all of them: finished runs are skipped node by node in seconds, half-done
runs continue where they stopped, and new runs are processed from scratch.
"""

from __future__ import annotations

from pathlib import Path

from prefect import flow, get_run_logger

from spectralize.schemas import RunStore, SpectralizeError

__all__ = ["find_run_stores", "process_new_runs", "serve_nightly"]


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


@flow(name="spectralize-nightly", log_prints=True)
def process_new_runs(
    root: str, flow_name: str = "btf", pattern: str = "*.zarr", dask_address: str | None = None
) -> dict[str, str]:
    """Run ``flow_name`` on every run store under ``root``; report each store's outcome.

    A store that fails does not stop the others; the flow run fails at the end if any did,
    so the failure is visible in Prefect's UI.
    """
    from spectralize.flows import run_flow

    log = get_run_logger()
    stores = find_run_stores(root, pattern)
    log.info(f"{len(stores)} run store(s) under {root}")
    outcome: dict[str, str] = {}
    for index, store in enumerate(stores, start=1):
        log.info(f"[{index}/{len(stores)}] {store.name}")
        try:
            report = run_flow(flow_name, store, dask_address=dask_address)
        except Exception as error:  # reported per store, raised below
            log.error(f"{store.name}: {type(error).__name__}: {error}")
            outcome[str(store)] = f"failed: {error}"
            continue
        ran = sum(step.status == "ran" for step in report.steps)
        outcome[str(store)] = f"{ran} node(s) ran, {len(report.steps) - ran} up to date"
        log.info(f"{store.name}: {outcome[str(store)]}")
    failed = [name for name, result in outcome.items() if result.startswith("failed")]
    if failed:
        raise SpectralizeError(f"{len(failed)} of {len(stores)} run(s) failed: {failed}")
    return outcome


def serve_nightly(
    root: str,
    *,
    flow_name: str = "btf",
    cron: str = "0 2 * * *",
    pattern: str = "*.zarr",
    dask_address: str | None = None,
    name: str = "nightly",
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
        },
        description=f"process run stores under {root} with the {flow_name!r} flow",
    )
