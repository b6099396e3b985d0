"""A finished group that lost its checksum manifest is damaged, not trusted: a group rewritten
with xarray keeps its attrs (xarray's default), its fingerprint among them, but not the
manifest beside them. ``validate`` and ``run`` agree: a derived group is recomputed, a raw one
refused."""

import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Step
from spectralize.flows import cli
from spectralize.flows.runtime import run_steps
from spectralize.schemas import StoreError
from spectralize.store import RunStore
from spectralize.store.integrity import MANIFEST_FILE

NO_MANIFEST = "its checksum manifest (spectralize_manifest.json, written with its fingerprint)"


def small(path):
    store = RunStore.create(path)
    raw = make_raw_dark(frames=6, shape=(5, 6), exposure_times=(0.1, 0.3))
    store.write("raw/dark", raw, fingerprint="raw-v1")
    return store


def rewritten_with_xarray(store, group, edit):
    """``group`` read with xarray, edited, written back over itself (its attrs kept)."""
    ds = edit(xr.open_zarr(store.path, group=group, consolidated=False).load())
    for var in ds.variables.values():
        var.encoding = {}
    ds.to_zarr(store.path, group=group, mode="w", consolidated=False, zarr_format=3)


def with_nan(ds):
    ds["mean"][0, 0, 0] = np.nan
    return ds


def test_a_group_rewritten_with_xarray_keeps_its_fingerprint_loses_its_manifest_and_is_damaged(tmp_path):
    store = small(tmp_path / "run.zarr")
    fingerprint = store.fingerprint("raw/dark")
    rewritten_with_xarray(store, "raw/dark", lambda ds: ds.assign(frames=ds["frames"] + 0))
    assert store.fingerprint("raw/dark") == fingerprint  # the attrs came back
    assert store.manifest("raw/dark") is None and not (store.path / "raw/dark" / MANIFEST_FILE).exists()
    problems = store.verify("raw/dark")
    assert [(p.where, p.expected) for p in problems] == [("raw/dark", NO_MANIFEST)], problems
    assert "rewritten by other means" in problems[0].found
    assert problems[0] in store.validate()


def test_a_group_imported_without_a_fingerprint_needs_no_manifest(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    raw = make_raw_dark(frames=4, shape=(4, 5), exposure_times=(0.1, 0.2))
    raw.to_zarr(store.path, group="raw/dark", zarr_format=3, consolidated=False)  # a lab's importer
    assert store.fingerprint("raw/dark").startswith("content:")
    assert store.verify("raw/dark") == [] and store.validate() == []


def test_run_recomputes_a_derived_group_rewritten_with_xarray(prefect_api, tmp_path):
    store = small(tmp_path / "run.zarr")
    run_steps(store.path, [Step("dark_average")])
    want = store.read("dark")["mean"].values
    rewritten_with_xarray(store, "dark", with_nan)
    assert any(p.expected == NO_MANIFEST for p in store.validate())
    again = run_steps(store.path, [Step("dark_average")])
    assert again.steps[0].status == "ran", again.steps[0]
    assert again.steps[0].reason.startswith(f"damaged output dark (dark: expected {NO_MANIFEST}")
    np.testing.assert_array_equal(store.read("dark")["mean"].values, want)
    assert store.validate() == []


def test_validate_and_run_refuse_a_raw_group_rewritten_with_xarray(prefect_api, tmp_path, capsys):
    store = small(tmp_path / "run.zarr")
    run_steps(store.path, [Step("dark_average")])
    rewritten_with_xarray(store, "raw/dark", lambda ds: ds.assign(frames=ds["frames"].astype("float64")))
    capsys.readouterr()
    assert cli.main(["validate", str(store.path)]) == 1
    checked = capsys.readouterr().err
    assert f"raw/dark: expected {NO_MANIFEST}" in checked and "dtype float64" in checked, checked
    assert cli.main(["run", "dark", str(store.path)]) == 2
    ran = capsys.readouterr().err
    assert "input group(s) raw/dark are damaged" in ran and f"expected {NO_MANIFEST}" in ran, ran
    with pytest.raises(StoreError, match="raw/dark are damaged"):
        run_steps(store.path, [Step("dark_average")])
