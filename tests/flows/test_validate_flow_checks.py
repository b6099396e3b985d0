"""``validate --flow`` refuses what ``run`` refuses before any numerics: NaN band radiance, which
the reconstruction cannot use, is refused by the contract, so by both, with the same words."""

import functools

import numpy as np
import pytest
import xarray as xr

from spectralize.flows import cli
from spectralize.flows.steps import check_input_values
from spectralize.schemas import SchemaError
from spectralize.store import RunStore


@functools.cache
def simulated_run():
    from spectralize.nodes.simulation.assembly import simulate_run
    from spectralize.nodes.simulation.recipes import get_recipe

    return {group: ds.load() for group, ds in simulate_run(get_recipe("tiny")).items()}


def bands_of(spectral: xr.Dataset) -> xr.Dataset:
    """Band radiance shaped as ``calibrate_bands`` writes it, from the raw band shots."""
    radiance = (spectral["counts"] / 1023.0).astype(np.float32)
    radiance.attrs = {"units": "1", "long_name": "relative band radiance"}
    return spectral.drop_vars("counts").assign(radiance=radiance)


def store_with_bands(path, nan: bool) -> RunStore:
    from spectralize.flows.pipelines import flow_inputs

    run = simulated_run()
    store = RunStore.create(path)
    for group in flow_inputs("btf"):
        store.write(group, run[group], fingerprint=f"sim-{group}")
    bands = bands_of(run["raw/spectral"])
    if nan:
        bands["radiance"][0, 0, 0] = np.nan
    # lazy, as a node's result: the store checks the values of in-memory arrays only
    store.write("bands", bands.chunk({"shot": 8}), fingerprint="bands")
    return store


def listed(stderr: str) -> list[str]:
    return [line[4:] for line in stderr.splitlines() if line.startswith("  - ")]


def test_validate_flow_btf_refuses_nan_bands_as_the_run_refuses_them_before_computing(tmp_path, capsys):
    store = store_with_bands(tmp_path / "run.zarr", nan=True)
    capsys.readouterr()
    assert cli.main(["validate", str(store.path), "--flow", "btf"]) == 1
    problems = listed(capsys.readouterr().err)
    line = "bands:radiance: expected finite values, found 1 NaN/inf value(s)"
    assert [p for p in problems if p.startswith(line)] == problems, problems
    with pytest.raises(SchemaError) as info:  # what run checks of a node's inputs, first
        check_input_values(store, "endmember_library", ["bands"])
    assert [str(p) for p in info.value.problems] == problems


def test_finite_bands_pass_both(tmp_path, capsys):
    store = store_with_bands(tmp_path / "run.zarr", nan=False)
    assert store.validate() == []
    assert cli.main(["validate", str(store.path), "--flow", "btf"]) == 0, capsys.readouterr().err
    check_input_values(store, "endmember_library", ["bands"])
