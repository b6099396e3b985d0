"""The one error hierarchy: every error carries its problems; the simulator's errors join it."""

import pickle

import pytest

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.nodes.simulation.camera_model import (
    CameraModelError,
    ShapeMismatchError,
    SimulationParameterError,
    check_bit_depth,
)
from spectralize.nodes.simulation.recipes import GantryRecipe, get_recipe
from spectralize.schemas import (
    CalibrationError,
    NodeDeclarationError,
    NodeNotFoundError,
    ParameterError,
    PipelineError,
    Problem,
    ReconstructionError,
    SchemaError,
    SimulationError,
    SpectralizeError,
    StoreError,
)

ALL = [
    SchemaError,
    StoreError,
    NodeNotFoundError,
    NodeDeclarationError,
    ParameterError,
    PipelineError,
    CalibrationError,
    ReconstructionError,
    SimulationError,
]


@pytest.mark.parametrize("cls", ALL)
def test_every_error_is_a_spectralize_error_with_a_problem_list(cls):
    assert issubclass(cls, SpectralizeError)
    error = cls.single("raw/rgb:counts", "dtype uint16", "float32", hint="cast the counts")
    assert isinstance(error, cls)
    assert error.problems == [Problem("raw/rgb:counts", "dtype uint16", "float32", "cast the counts")]
    assert str(error) == ("raw/rgb:counts: expected dtype uint16, found float32 (cast the counts)")


@pytest.mark.parametrize(
    "cls", [SchemaError, ParameterError, CalibrationError, ReconstructionError, SimulationError]
)
def test_value_errors_stay_value_errors(cls):
    with pytest.raises(ValueError):
        raise cls.single("x", "y", "z")


def test_a_plain_message_still_works_and_has_no_problems():
    error = CalibrationError("the white target is saturated everywhere")
    assert str(error) == "the white target is saturated everywhere"
    assert error.problems == [] and error.summary == str(error)


def test_a_summary_with_problems_lists_them_all():
    error = PipelineError(
        "the node graph cannot run (2 problem(s)):", [Problem("a", "b", "c"), Problem("d", "e", "f")]
    )
    assert str(error).splitlines() == [
        "the node graph cannot run (2 problem(s)):",
        "  - a: expected b, found c",
        "  - d: expected e, found f",
    ]


def test_errors_keep_their_problems_through_pickling():
    error = SchemaError(
        "group 'dark' does not follow schema 'dark':",
        [Problem("dark:mean", "dtype float32", "dtype float64")],
    )
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is SchemaError
    assert back.problems == error.problems and str(back) == str(error)
    missing = pickle.loads(pickle.dumps(NodeNotFoundError("unknown node 'x'")))
    assert str(missing) == "unknown node 'x'"


def test_the_simulators_errors_join_the_hierarchy():
    for cls in (CameraModelError, SimulationParameterError, ShapeMismatchError):
        assert issubclass(cls, SimulationError) and issubclass(cls, ValueError)
    with pytest.raises(SimulationError, match="bit_depth must be in 8..16"):
        check_bit_depth(20)
    with pytest.raises(SimulationError, match="recipe 'huge' is unknown"):
        get_recipe("huge")


def test_a_recipe_that_breaks_its_rules_is_a_simulation_error():
    with pytest.raises(SimulationParameterError, match="rgb_exposure_times must be increasing"):
        get_recipe("tiny", rgb_exposure_times=(0.01, 0.001))
    with pytest.raises(ValueError, match="must be a multiple of noise_tile"):  # pydantic's
        GantryRecipe(size=64, chunk_size=24, noise_tile=16)


def test_the_dark_stack_generator_raises_a_simulation_error():
    with pytest.raises(SimulationError) as info:
        make_raw_dark(exposure_times=(0.2, 0.1))
    [problem] = info.value.problems
    assert problem.where == "exposure_times" and problem.found == "[0.2, 0.1]"
