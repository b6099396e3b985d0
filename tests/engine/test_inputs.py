"""The engine checks each input against its declared schema before a node runs."""

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Node, Step, check_graph
from spectralize.schemas import PipelineError, SchemaError
from spectralize.schemas.run import TRUTH_CAMERA

CALLS: list[str] = []


def average(raw_dark: xr.Dataset, *, ddof: int = 1) -> xr.Dataset:
    CALLS.append("average")
    return xr.Dataset({"mean": raw_dark["frames"].mean("frame")})


AVERAGE = Node(name="average", function=average, inputs={"raw_dark": "raw/dark"}, outputs=("dark",))


def camera_rows(calibration: xr.Dataset) -> xr.Dataset:
    CALLS.append("camera_rows")
    return calibration


CAMERA_ROWS = Node(
    name="camera_rows", function=camera_rows, inputs={"calibration": "camera_matrix"}, outputs=("rows",)
)


def test_a_valid_input_runs_the_node():
    CALLS.clear()
    out = AVERAGE({"raw_dark": make_raw_dark(frames=4, shape=(3, 4))})
    assert set(out) == {"dark"} and CALLS == ["average"]


def test_a_missing_variable_is_named_with_the_node_and_argument_and_nothing_runs():
    CALLS.clear()
    raw = make_raw_dark(frames=4, shape=(3, 4)).drop_vars("frames")
    with pytest.raises(SchemaError) as info:
        AVERAGE({"raw_dark": raw})
    text = str(info.value)
    assert "node 'average': inputs do not follow their declared schemas" in text
    assert (
        "average(raw_dark: raw/dark):frames: expected data variable with dims "
        "('exposure_time', 'frame', 'y', 'x'), found nothing"
    ) in text
    assert CALLS == []


def test_every_problem_of_an_input_is_listed():
    raw = make_raw_dark(frames=4, shape=(3, 4))
    raw = raw.assign(frames=raw["frames"].astype(np.float32).assign_attrs(units="counts"))
    raw.attrs.pop("bit_depth")
    with pytest.raises(SchemaError) as info:
        AVERAGE({"raw_dark": raw})
    wheres = [p.where for p in info.value.problems]
    assert wheres.count("average(raw_dark: raw/dark):frames") == 2  # dtype and units
    assert "average(raw_dark: raw/dark).attrs" in wheres
    assert any("dtype uint16" in p.expected and "float32" in p.found for p in info.value.problems)


def test_a_missing_or_wrongly_typed_input_is_a_schema_error():
    with pytest.raises(
        SchemaError,
        match="node 'average' input 'raw_dark': expected a Dataset of schema 'raw/dark', found nothing",
    ):
        AVERAGE({})
    with pytest.raises(SchemaError, match="expected an xarray.Dataset, found DataArray"):
        AVERAGE({"raw_dark": xr.DataArray([1])})


def test_lazy_inputs_are_checked_without_computing_them():
    def explode(*_):
        raise AssertionError("the input check computed a dask array")

    lazy = da.from_delayed(dask.delayed(explode)(), shape=(2, 4, 3, 4), dtype=np.uint16)
    raw = make_raw_dark(frames=4, shape=(3, 4), exposure_times=(0.1, 0.2))
    raw = raw.assign(frames=(raw["frames"].dims, lazy, raw["frames"].attrs))
    AVERAGE.check_inputs({"raw_dark": raw})  # passes: structure only, nothing computed
    with pytest.raises(SchemaError, match="attr 'camera'"):
        AVERAGE.check_inputs({"raw_dark": raw.drop_attrs(deep=False)})


def test_a_group_of_a_providing_schema_is_checked_against_the_declared_one():
    CALLS.clear()
    names = [spec.name for spec in TRUTH_CAMERA.variables]
    matrix = xr.DataArray(
        np.ones((3, 2), np.float32), dims=("channel", "wavelength"), attrs={"units": "1"}
    )
    extra = xr.DataArray(np.zeros(2, np.float32), dims=("wavelength",))
    data = xr.Dataset(
        {"camera_matrix": matrix, "something_else": extra},
        coords={
            "channel": ["R", "G", "B"],
            "wavelength": ("wavelength", [500.0, 600.0], {"units": "nm"}),
        },
    )
    assert "camera_matrix" in names
    out = CAMERA_ROWS({"calibration": data})  # extra variables of a wider schema are fine
    assert CALLS == ["camera_rows"] and "something_else" in out["rows"]
    with pytest.raises(
        SchemaError,
        match=r"camera_rows\(calibration: camera_matrix\)"
        r":camera_matrix: expected data variable",
    ):
        CAMERA_ROWS({"calibration": data.drop_vars("camera_matrix")})


def test_a_two_node_cycle_is_found_by_the_graph_check():
    def step(dark: xr.Dataset) -> xr.Dataset:
        return dark

    nodes = {
        "a": Node(name="a", function=step, inputs={"dark": "x"}, outputs=("ga",)),
        "b": Node(name="b", function=step, inputs={"dark": "x"}, outputs=("gb",)),
    }
    steps = [Step("a", inputs={"dark": "gb"}), Step("b", inputs={"dark": "ga"})]
    with pytest.raises(PipelineError) as info:
        check_graph(steps, nodes=nodes)
    [problem] = info.value.problems
    assert problem.where == "graph" and problem.expected == "no cycles"
    assert problem.found in ("a cycle among nodes a -> b -> a", "a cycle among nodes b -> a -> b")


def test_independent_steps_keep_their_given_order():
    def source() -> xr.Dataset:
        return xr.Dataset()

    nodes = {
        name: Node(name=name, function=source, inputs={}, outputs=(name,)) for name in ("c", "a", "b")
    }
    order = check_graph([Step("c"), Step("a"), Step("b")], nodes=nodes)
    assert [p.node.name for p in order] == ["c", "a", "b"]
