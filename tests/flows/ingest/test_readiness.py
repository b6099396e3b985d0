"""Nightly runs: a capture folder is ingested once complete, then processed and reported."""

import shutil

import numpy as np
import pytest
from support.capture_folders import rows

from spectralize.flows.ingest import capture_state
from spectralize.store import RunStore


def test_a_folder_still_being_written_waits(capture):
    assert capture_state(capture, settle_seconds=0).ready
    fresh = capture_state(capture, settle_seconds=3600)
    assert not fresh.ready and "changed" in fresh.reason
    first = rows(capture)[0]["file"]
    (capture / first).unlink()
    missing = capture_state(capture, settle_seconds=0)
    assert not missing.ready and "not present yet" in missing.reason and first in missing.reason


@pytest.mark.slow
def test_nightly_run_ingests_complete_capture_folders_processes_and_reports_them(
    prefect_api, sample, tmp_path
):
    """The whole path a lab takes: capture folders in, btf, a report without ground truth."""
    from spectralize.flows.export import export
    from spectralize.flows.runtime import report_directory
    from spectralize.flows.schedule import process_new_runs

    captures = tmp_path / "captures"
    shutil.copytree(sample, captures / "night1", copy_function=shutil.copy2)
    growing = shutil.copytree(sample, captures / "night2", copy_function=shutil.copy2)
    (growing / rows(growing)[-1]["file"]).unlink()  # the gantry is still writing
    outcome = process_new_runs(
        root=str(captures), output_root=str(tmp_path / "runs"), settle_seconds=0.0
    )
    assert outcome[str(captures / "night2")].startswith("waiting:")
    assert "not present yet" in outcome[str(captures / "night2")]
    assert not (tmp_path / "runs" / "night2.zarr").exists()
    assert outcome[str(captures / "night1")].startswith("ingested: raw/rgb")
    store = RunStore.open(tmp_path / "runs" / "night1.zarr")
    assert "11 node(s) ran" in outcome[str(store.path)]  # btf without the evaluation (no truth)
    assert {"spectra", "calibration/spectral", "registration"} <= set(store.groups())
    page = report_directory(store.path) / "index.html"
    assert page.is_file() and f"report {page}" in outcome[str(store.path)]
    text = page.read_text()
    for section in ('id="reconstruction"', 'id="calibration"', 'id="response_histograms"', 'id="oecf"'):
        assert section in text
    assert 'id="accuracy"' not in text  # no accuracy section without ground truth
    (path,) = export(store, tmp_path / "night1.nc", format="netcdf")
    import xarray as xr

    with xr.open_dataset(path) as ds:
        assert ds["radiance"].sizes["image"] == 20 and np.isfinite(ds["radiance"].values).mean() > 0.9
