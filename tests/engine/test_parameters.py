"""Parameters derived from a node function's signature, and Choices from a method table."""

from typing import Annotated, Literal

import pytest
import xarray as xr
from pydantic import Field, ValidationError

from spectralize.engine import Choices, Node, Parameters, Step, check_graph
from spectralize.nodes.simulation.declarations import SIMULATE
from spectralize.schemas import NodeDeclarationError, ParameterError, PipelineError

SOLVER_METHODS = {"cg": object(), "lsqr": object()}
RAN: list[str] = []


def reconstruct(
    bands: xr.Dataset,
    *,
    method: Annotated[str, Choices(SOLVER_METHODS, "solver method")] = "cg",
    alpha_hat: Annotated[float, Field(gt=0, description="weight of the prior")] = 1.0,
    iterations: Annotated[int, Field(ge=1, le=1000)] = 50,
    baseline: Annotated[str | None, Choices(SOLVER_METHODS)] = None,
    mode: Literal["sparse", "dense"] = "sparse",
) -> xr.Dataset:
    """Reconstruct spectra (test stand-in).

    Parameters
    ----------
    bands
        Band radiance.
    method
        Solver of eq. 8.
        Second line, not the description.
    iterations
        Most solver iterations.

    Returns
    -------
    xarray.Dataset
    """
    RAN.append(method)
    return bands


RECONSTRUCT = Node(
    name="reconstruct", function=reconstruct, inputs={"bands": "unregistered"}, outputs=("spectra",)
)


def test_the_model_is_derived_from_the_keyword_only_arguments():
    fields = RECONSTRUCT.parameters.model_fields
    assert list(fields) == ["method", "alpha_hat", "iterations", "baseline", "mode"]  # not bands
    assert issubclass(RECONSTRUCT.parameters, Parameters)
    params = RECONSTRUCT.parse_parameters({})
    assert (params.method, params.alpha_hat, params.iterations, params.baseline, params.mode) == (
        "cg",
        1.0,
        50,
        None,
        "sparse",
    )
    with pytest.raises(ValidationError, match="frozen"):
        params.method = "lsqr"
    rows = {row[0]: row for row in RECONSTRUCT.describe_parameters()}
    assert rows["alpha_hat"][1:] == ("float", 1.0, "weight of the prior")  # Field wins
    assert rows["method"][3] == "Solver of eq. 8."  # first line of the numpydoc entry
    assert rows["iterations"][3] == "Most solver iterations."
    assert rows["mode"][3] == ""


def test_annotated_constraints_and_unknown_keys_are_all_reported():
    with pytest.raises(ParameterError) as info:
        RECONSTRUCT.parse_parameters(
            {"alpha_hat": 0, "iterations": 5000, "itterations": 3, "mode": "medium"}
        )
    text = str(info.value)
    assert "reconstruct.alpha_hat: expected Input should be greater than 0, found 0" in text
    assert "reconstruct.iterations: expected Input should be less than or equal to 1000" in text
    assert (
        "reconstruct.itterations: expected one of: method, alpha_hat, iterations, "
        "baseline, mode, found an unknown parameter"
    ) in text
    assert "reconstruct.mode: expected Input should be 'sparse' or 'dense'" in text
    assert len(info.value.problems) == 4


def test_choices_list_the_table_keys_and_follow_the_table():
    with pytest.raises(ParameterError) as info:
        RECONSTRUCT.parse_parameters({"method": "fastest", "baseline": "nope"})
    text = str(info.value)
    assert ("reconstruct.method: expected one of: 'cg', 'lsqr' (solver method), found 'fastest'") in text
    assert "reconstruct.baseline: expected one of: 'cg', 'lsqr', found 'nope'" in text
    assert RECONSTRUCT.parse_parameters({"baseline": "lsqr"}).baseline == "lsqr"
    assert RECONSTRUCT.parameter_choices() == {
        "method": ("cg", "lsqr"),
        "baseline": ("cg", "lsqr"),
        "mode": ("sparse", "dense"),
    }
    SOLVER_METHODS["fastest"] = object()  # a method registered later is accepted
    try:
        assert RECONSTRUCT.parse_parameters({"method": "fastest"}).method == "fastest"
    finally:
        del SOLVER_METHODS["fastest"]
    schema = RECONSTRUCT.parameters.model_json_schema()
    assert schema["properties"]["method"]["enum"] == ["cg", "lsqr"]


def test_choices_work_in_an_explicit_model_too():
    class Explicit(Parameters):
        method: Annotated[str, Choices(SOLVER_METHODS)] = "cg"

    node = Node(
        name="explicit",
        function=reconstruct,
        inputs={"bands": "unregistered"},
        outputs=("spectra",),
        parameters=Explicit,
    )
    assert node.parameters is Explicit
    with pytest.raises(ParameterError, match="explicit.method: expected one of: 'cg', 'lsqr'"):
        node.parse_parameters({"method": "CG"})


def test_a_method_typo_fails_in_the_graph_check_before_anything_runs():
    RAN.clear()
    steps = [Step("reconstruct", parameters={"method": "fastest"})]
    with pytest.raises(PipelineError) as info:
        check_graph(steps, available={"unregistered": None}, nodes={"reconstruct": RECONSTRUCT})
    assert "reconstruct.method: expected one of: 'cg', 'lsqr'" in str(info.value)
    assert RAN == []


def test_a_recipe_typo_of_the_registered_simulate_node_fails_in_the_graph_check():
    steps = [Step("simulate", parameters={"recipe": "dmeo", "seed": -1})]
    with pytest.raises(PipelineError) as info:
        check_graph(steps, nodes={"simulate": SIMULATE})
    text = str(info.value)
    assert "simulate.recipe: expected one of: 'demo', 'paper', 'tiny' (recipe), found 'dmeo'" in text
    assert "simulate.seed: expected Input should be greater than or equal to 0" in text
    [planned] = check_graph(
        [Step("simulate", parameters={"recipe": "tiny"})], nodes={"simulate": SIMULATE}
    )
    assert planned.parameters.recipe == "tiny"


def test_a_keyword_without_default_is_a_required_parameter():
    def needs(bands: xr.Dataset, *, level: float) -> xr.Dataset:
        return bands

    node = Node(name="needs", function=needs, inputs={"bands": "x"}, outputs=("y",))
    with pytest.raises(ParameterError, match="needs.level: expected Field required"):
        node.parse_parameters({})
    assert node.parse_parameters({"level": 2}).level == 2.0


def test_an_unresolvable_annotation_is_a_declaration_error():
    def broken(bands: xr.Dataset, *, level: "NoSuchType" = 1) -> xr.Dataset:  # noqa: F821
        return bands

    with pytest.raises(NodeDeclarationError, match="annotations that resolve"):
        Node(name="broken", function=broken, inputs={"bands": "x"}, outputs=("y",))


def test_a_method_typo_in_the_demo_flow_is_the_only_problem_reported():
    from spectralize.flows.pipelines import FLOWS, step_parameters

    steps = step_parameters(
        FLOWS["demo"].steps, {"reconstruct_image_sets.method": "fastest", "simulate.recipe": "tiyn"}
    )
    with pytest.raises(PipelineError) as info:
        check_graph(steps)  # the installed registry: the real nodes
    wheres = [p.where for p in info.value.problems]
    assert wheres == ["simulate.recipe", "reconstruct_image_sets.method"]  # nothing cascades
    method = info.value.problems[1]
    assert method.expected.startswith("one of: ") and method.found == "'fastest'"
    assert len(check_graph(step_parameters(FLOWS["demo"].steps, {}))) == len(steps)
