"""Tests of the named sample-run recipes and the ``simulate`` node."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.simulation.assembly import GROUPS, Gantry
from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.declarations import SIMULATE
from spectralize.nodes.simulation.recipes import DESCRIPTIONS, RECIPES, get_recipe, recipe_names
from spectralize.schemas import ParameterError


def test_named_recipes_with_descriptions():
    assert recipe_names() == ["demo", "paper", "tiny"]
    for name, recipe in RECIPES.items():
        assert recipe.name == name and len(DESCRIPTIONS[name]) > 20
    paper = RECIPES["paper"]
    assert paper.size == 2048 and len(paper.rgb_camera_thetas) == 11 and paper.leds is None
    assert paper.n_rotations * paper.rotation_step == 360
    assert max(paper.rgb_camera_thetas) == 75 and paper.n_dark_frames == 200


def test_paper_gantry_geometry():
    schedule = Gantry(RECIPES["paper"]).schedule
    assert schedule.led_theta.size == 198
    assert len(schedule.images) == 11 * 198 * 24
    plan = schedule.plan
    assert plan.sizes["wavelength"] == 32
    # the 226 s reference versus 7.5 s noisy capture of the paper (sec. 5, "Real Data")
    one_image = float(plan.exposure_time.sum()) + float(plan.rgb_exposure_time.sum())
    reference = float(schedule.reference.exposure_time.sum())
    assert 15 < reference / one_image < 60


def test_overrides_are_validated():
    r = get_recipe("tiny", seed=5, size=40)
    assert (r.seed, r.size, r.name) == (5, 40, "tiny")
    assert get_recipe("tiny") is RECIPES["tiny"]
    with pytest.raises(
        SimulationParameterError,
        match=r"recipe: expected one of \['demo', 'paper', 'tiny'\], found 'huge'",
    ):
        get_recipe("huge")
    with pytest.raises(SimulationParameterError, match="sizee"):
        get_recipe("tiny", sizee=3)
    with pytest.raises(SimulationParameterError, match="size"):
        get_recipe("tiny", size=2)


def test_demo_recipe_sizes():
    gantry = Gantry(RECIPES["demo"])
    groups = gantry.groups()
    rgb = groups["raw/rgb"]
    assert rgb.sizes["image"] == 3 * 11 * 3 and rgb.sizes["y"] == 64
    assert groups["raw/spectral"].sizes["shot"] == 2 * 32  # rotations 1 and 2, one set each
    assert set(groups["raw/rgb"].theta_o.values.tolist()) >= {15.0, 45.0, 75.0}
    total = sum(ds.nbytes for ds in groups.values())
    assert total < 200e6


def test_simulate_node_is_seeded_and_deterministic():
    assert SIMULATE.inputs == {} and set(SIMULATE.outputs) == set(GROUPS)
    out = SIMULATE({}, {"recipe": "tiny", "seed": 2, "overrides": {"n_dark_frames": 2}})
    loaded = {k: v.load() for k, v in out.items()}
    assert set(loaded) == set(GROUPS)
    assert loaded["raw/rgb"].attrs["seed"] == 2
    assert loaded["raw/dark"].sizes["frame"] == 2
    again = SIMULATE({}, {"recipe": "tiny", "seed": 2, "overrides": {"n_dark_frames": 2}})
    np.testing.assert_array_equal(
        again["raw/spectral"].counts.values, loaded["raw/spectral"].counts.values
    )


def test_simulate_parameters_reject_unknown_keys():
    with pytest.raises(ParameterError, match="frames"):
        SIMULATE.parse_parameters({"frames": 3})
    with pytest.raises(
        ParameterError,
        match=r"simulate.recipe: expected one of: 'demo', "
        r"'paper', 'tiny' \(recipe\), found 'huge'",
    ):
        SIMULATE.parse_parameters({"recipe": "huge"})
    assert SIMULATE.parse_parameters({}).recipe == "demo"
    assert SIMULATE.parameter_choices()["recipe"] == tuple(sorted(RECIPES))
    with pytest.raises(SimulationParameterError, match="noise_tile"):
        SIMULATE({}, {"recipe": "tiny", "overrides": {"noise_tile": 3}})
    with pytest.raises(SimulationParameterError, match="max_gigabytes"):
        SIMULATE({}, {"recipe": "paper"})


def test_recipe_overrides_report_each_problem_and_response_models_come_from_the_table():
    with pytest.raises(SimulationParameterError) as info:
        get_recipe("tiny", size=2, spectral_response={"model": "lgo"})
    problems = {p.where: p for p in info.value.problems}
    assert set(problems) == {"size", "spectral_response.model"}
    assert problems["spectral_response.model"].expected == (
        "one of: 'gamma', 'linear', 'log', 's_curve' (response model)"
    )
    assert problems["spectral_response.model"].found == "'lgo'"
    with pytest.raises(SimulationParameterError) as info:
        get_recipe("tiny", rgb_exposure_times=(0.01, 0.001))
    [problem] = info.value.problems
    assert problem.where == "recipe" and "must be increasing" in problem.found
