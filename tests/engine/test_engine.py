import warnings
from importlib.metadata import EntryPoint

import pytest
import xarray as xr
from pydantic import Field, ValidationError

from spectralize.engine import (
    ENTRY_POINT_GROUP,
    Node,
    Parameters,
    Step,
    check_graph,
    discover_nodes,
    get_node,
    registry,
)
from spectralize.nodes.simulation.declarations import SIMULATE
from spectralize.schemas import (
    NodeDeclarationError,
    NodeNotFoundError,
    ParameterError,
    PipelineError,
    SpectralizeError,
)


class ScaleParameters(Parameters):
    factor: float = Field(2.0, gt=0)


def scale(dark: xr.Dataset, *, factor: float = 2.0) -> xr.Dataset:
    return dark * factor


SCALE = Node(
    name="scale",
    function=scale,
    inputs={"dark": "dark"},
    outputs=("scaled",),
    parameters=ScaleParameters,
)
NOT_A_NODE = object()


def average(raw_dark: xr.Dataset) -> xr.Dataset:
    return xr.Dataset({"mean": raw_dark["frames"].mean("frame")})


# Stands in for the calibration stage's dark_average: same schemas, no dependency on its code.
DARK_AVERAGE = Node(
    name="dark_average", function=average, inputs={"raw_dark": "raw/dark"}, outputs=("dark",)
)


def ep(name, value):
    return EntryPoint(name=name, value=value, group=ENTRY_POINT_GROUP)


def test_discovery_from_fake_entry_points_warns_on_broken_plugins():
    eps = [
        ep("scale", f"{__name__}:SCALE"),
        ep("broken", "spectralize_no_such_module:NODE"),
        ep("wrong_type", f"{__name__}:NOT_A_NODE"),
        ep("scale_again", f"{__name__}:SCALE"),
    ]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        found = discover_nodes(eps)
    assert list(found) == ["scale"]
    assert found["scale"].node is SCALE
    assert found["scale"].source.startswith(f"entry point {ENTRY_POINT_GROUP}: scale = ")
    messages = [str(w.message) for w in caught]
    assert any(
        "'broken'" in m and "failed to load" in m and "ModuleNotFoundError" in m for m in messages
    )
    assert any("'wrong_type'" in m and "not a spectralize Node" in m for m in messages)
    assert any("duplicates" in m for m in messages)


def test_installed_entry_points_include_the_simulate_node():
    nodes = registry(refresh=True)
    assert nodes["simulate"].node is SIMULATE
    assert "spectralize.nodes:" in nodes["simulate"].source
    assert "simulate = spectralize.nodes.simulation.declarations:SIMULATE" in nodes["simulate"].source
    assert get_node("simulate") is SIMULATE


def test_unknown_node_lists_the_installed_ones():
    with pytest.raises(NodeNotFoundError, match="unknown node 'nope'; installed nodes: .*simulate"):
        get_node("nope")


def test_parameters_are_frozen_and_unknown_keys_are_errors():
    params = SCALE.parse_parameters({"factor": 3})
    assert params.factor == 3.0
    with pytest.raises(ValidationError, match="frozen"):
        params.factor = 4
    with pytest.raises(ParameterError) as info:
        SCALE.parse_parameters({"factr": 3, "factor": -1})
    text = str(info.value)
    assert "scale.factr: expected one of: factor, found an unknown parameter" in text
    assert "scale.factor: expected Input should be greater than 0, found -1" in text


def test_declaration_errors_are_caught_when_the_node_is_declared():
    with pytest.raises(
        NodeDeclarationError, match="input 'raw': expected an argument of scale, found no such argument"
    ):
        Node(name="bad", function=scale, inputs={"raw": "raw/dark"}, outputs=("x",))

    class Extra(Parameters):
        gain: int = 1

    with pytest.raises(NodeDeclarationError, match="parameter 'gain': expected a keyword of scale"):
        Node(name="bad", function=scale, inputs={"dark": "dark"}, outputs=("x",), parameters=Extra)
    with pytest.raises(NodeDeclarationError, match="outputs: expected at least one output"):
        Node(name="bad", function=scale, inputs={"dark": "dark"}, outputs=())
    with pytest.raises(NodeDeclarationError, match="read_by_shard 'raw': expected one of the inputs"):
        Node(name="bad", function=scale, inputs={"dark": "dark"}, outputs=("x",), read_by_shard=("raw",))


def test_node_call_checks_what_the_function_returns():
    def two(dark: xr.Dataset) -> xr.Dataset:
        return dark

    node = Node(name="two", function=two, inputs={"dark": "unregistered"}, outputs=("a", "b"))
    with pytest.raises(SpectralizeError, match="returned one Dataset but declares outputs"):
        node({"dark": xr.Dataset()})


NODES = {"dark_average": DARK_AVERAGE, "scale": SCALE}


def test_graph_is_ordered_by_dependencies():
    order = check_graph(
        [Step("scale"), Step("dark_average")], available={"raw/dark": "raw/dark"}, nodes=NODES
    )
    assert [p.node.name for p in order] == ["dark_average", "scale"]


@pytest.mark.parametrize(
    ("steps", "available", "message"),
    [
        (
            [Step("scale")],
            {},
            "node 'scale' input 'dark': expected group 'dark' in the store or "
            "written by an earlier node, found no such group",
        ),
        (
            [Step("dark_average"), Step("dark_average")],
            {"raw/dark": "raw/dark"},
            "group 'dark': expected one producing node, found nodes 'dark_average' and "
            "'dark_average' both write it",
        ),
        (
            [Step("scale", inputs={"dark": "loop"}, outputs={"scaled": "loop"})],
            {},
            "graph: expected no cycles, found a cycle among nodes scale -> scale",
        ),
        (
            [Step("scale", inputs={"dark": "raw/dark"})],
            {"raw/dark": "raw/dark"},
            "expected schema 'dark', found schema 'raw/dark' in the store",
        ),
        (
            [Step("dark_average", outputs={"dark": "d2"}), Step("scale", inputs={"dark": "d2x"})],
            {"raw/dark": "raw/dark"},
            "input 'dark': expected group 'd2x'",
        ),
        (
            [Step("nope")],
            {},
            "step 'nope': expected an installed node (dark_average, scale), found an unknown node",
        ),
        (
            [Step("scale", parameters={"factor": 0})],
            {"dark": "dark"},
            "scale.factor: expected Input should be greater than 0",
        ),
    ],
)
def test_each_graph_error_is_reported(steps, available, message):
    with pytest.raises(PipelineError) as info:
        check_graph(steps, available=available, nodes=NODES)
    assert message in str(info.value)


def test_schema_mismatch_between_producer_and_consumer():
    with pytest.raises(
        PipelineError, match="expected schema 'dark', found schema 'scaled' written by node 'scale'"
    ):
        check_graph(
            [
                Step("scale", inputs={"dark": "dark"}, outputs={"scaled": "s"}),
                Step("scale", inputs={"dark": "s"}, outputs={"scaled": "t"}),
            ],
            available={"dark": "dark"},
            nodes=NODES,
        )


def test_all_graph_problems_are_reported_together():
    steps = [
        Step("nope"),
        Step("scale", parameters={"bogus": 1}),
        Step("dark_average"),
        Step("dark_average"),
    ]
    with pytest.raises(PipelineError) as info:
        check_graph(steps, available={}, nodes=NODES)
    text = str(info.value)
    assert "(5 problem(s))" in text  # raw/dark is missing for both dark steps
    for fragment in ("unknown node", "scale.bogus", "both write it", "group 'raw/dark'"):
        assert fragment in text


def test_optional_steps_without_their_inputs_are_left_out():
    steps = [
        Step("dark_average", outputs={"dark": "d"}, optional=True),
        Step("scale", inputs={"dark": "d"}, optional=True),
    ]
    assert check_graph(steps, available={}, nodes=NODES) == []  # the chain is dropped
    order = check_graph(steps, available={"raw/dark": "raw/dark"}, nodes=NODES)
    assert [p.node.name for p in order] == ["dark_average", "scale"]
    with pytest.raises(PipelineError, match="no such group"):  # not optional: an error
        check_graph([Step("scale", inputs={"dark": "d"})], available={}, nodes=NODES)


def test_a_group_that_provides_the_wanted_variables_is_accepted():
    from spectralize.schemas.run import CAMERA_MATRIX, TRUTH_CAMERA, TRUTH_SPECTRA

    assert TRUTH_CAMERA.provides(CAMERA_MATRIX)
    assert not TRUTH_SPECTRA.provides(CAMERA_MATRIX)

    def need_c(calibration: xr.Dataset) -> xr.Dataset:
        return calibration

    node = Node(
        name="need_c", function=need_c, inputs={"calibration": "camera_matrix"}, outputs=("out",)
    )
    nodes = {"need_c": node}
    steps = [Step("need_c", inputs={"calibration": "truth/camera"})]
    assert check_graph(steps, available={"truth/camera": "truth/camera"}, nodes=nodes)
    with pytest.raises(
        PipelineError, match="expected schema 'camera_matrix', found schema 'truth/spectra' in the store"
    ):
        check_graph(
            [Step("need_c", inputs={"calibration": "truth/spectra"})],
            available={"truth/spectra": "truth/spectra"},
            nodes=nodes,
        )
