"""A node's value check (Node.check): run before its function, and over a graph on a store."""

import pytest
import xarray as xr

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Node, Step, check_graph, value_refusals
from spectralize.schemas import CalibrationError, SpectralizeError

CALLS: list[str] = []


def refuse_long(inputs, parameters) -> list[SpectralizeError]:
    """Refuses exposure times above ``longest``; a second rule: fewer than ``frames`` frames."""
    CALLS.append("check")
    raw = inputs.get("raw_dark")
    if raw is None:
        return []
    found: list[SpectralizeError] = []
    top = float(raw["exposure_time"].max())
    if top > parameters.longest:
        found.append(
            CalibrationError(f"raw/dark: exposure_time {top:g} s is above {parameters.longest:g} s")
        )
    if raw.sizes["frame"] < parameters.frames:
        found.append(
            CalibrationError(f"raw/dark: {raw.sizes['frame']} frame(s), need {parameters.frames}")
        )
    return found


def average(raw_dark: xr.Dataset, *, longest: float = 1.0, frames: int = 2) -> xr.Dataset:
    CALLS.append("average")
    return xr.Dataset({"mean": raw_dark["frames"].mean("frame")})


def level(dark: xr.Dataset) -> xr.Dataset:
    return xr.Dataset({"level": dark["mean"].mean(("y", "x"))})


AVERAGE = Node(
    name="average",
    function=average,
    inputs={"raw_dark": "raw/dark"},
    outputs=("dark",),
    check=refuse_long,
)
LEVEL = Node(name="level", function=level, inputs={"dark": "dark"}, outputs=("level",))


def test_the_check_runs_before_the_function_and_its_refusal_is_raised():
    CALLS.clear()
    raw = make_raw_dark(frames=1, shape=(3, 4), exposure_times=(0.1, 2.0))
    with pytest.raises(CalibrationError, match=r"exposure_time 2 s is above 1 s") as info:
        AVERAGE({"raw_dark": raw})
    assert CALLS == ["check"]  # the function never ran
    assert info.value.__notes__ == ["and: raw/dark: 1 frame(s), need 2"]  # every refusal is said


def test_an_accepted_input_runs_and_the_parameters_reach_the_check():
    CALLS.clear()
    raw = make_raw_dark(frames=2, shape=(3, 4), exposure_times=(0.1, 2.0))
    assert set(AVERAGE({"raw_dark": raw}, {"longest": 5.0})) == {"dark"}
    assert CALLS == ["check", "average"]
    assert AVERAGE.refusals({"raw_dark": raw}, {"longest": 5.0}) == []
    assert [str(e) for e in AVERAGE.refusals({"raw_dark": raw})] == [
        "raw/dark: exposure_time 2 s is above 1 s"
    ]


def test_value_refusals_run_each_steps_check_on_the_groups_there_with_its_parameters():
    nodes = {"average": AVERAGE, "level": LEVEL}
    steps = [Step("average", {"longest": 0.5}), Step("level")]
    planned = check_graph(steps, available={"raw/dark": "raw/dark"}, nodes=nodes)
    raw = make_raw_dark(frames=2, shape=(3, 4), exposure_times=(0.1, 0.3))
    read = {"raw/dark": raw}.get
    assert value_refusals(planned, read) == []
    steps[0] = Step("average", {"longest": 0.2})
    planned = check_graph(steps, available={"raw/dark": "raw/dark"}, nodes=nodes)
    found = value_refusals(planned, read)
    assert [(item.node.name, str(error)) for item, error in found] == [
        ("average", "raw/dark: exposure_time 0.3 s is above 0.2 s")
    ]
