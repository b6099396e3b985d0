"""Named recipes of the simulated sample runs (generated deterministically, never stored).

===========  =====================================================================
``tiny``     32 x 32 px, 2 RGB cameras (15, 45 deg), 5 LEDs, 2 rotations; for tests
             (generated in about a second).
``demo``     the bundled sample run: 64 x 64 px, 3 RGB cameras (15, 45, 75 deg), 11 LEDs
             of the 40 deg ring around the mirror direction, 3 rotations, one sparse set
             of 32 bands over 10 LED positions per rotation after the first.
``paper``    the paper's gantry: 2048 x 2048 px, 11 RGB cameras (0..75 deg), 198 LEDs,
             24 rotations; lazy (dask) only: about 5 TB of raw RGB data if computed.
===========  =====================================================================

Measured sizes and times are in ``datasets/README.md``.  Use :func:`get_recipe` with
overrides, e.g. ``get_recipe("demo", seed=3, size=96)``.
"""

from __future__ import annotations

from typing import Any

from pydantic import ValidationError

from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.gantry import GantryRecipe, ring_leds
from spectralize.schemas import Problem

__all__ = ["RECIPES", "DESCRIPTIONS", "get_recipe", "recipe_names"]

TINY = GantryRecipe(
    name="tiny",
    description="32 x 32 px, 2 RGB cameras, 5 LEDs, 2 rotations: a run in about a second, for tests.",
    size=32,
    rgb_camera_thetas=(15.0, 45.0),
    n_rotations=2,
    leds=ring_leds(40.0, [165, 180, 195, 210, 225]),
    spectral_set_size=4,
    n_dark_frames=4,
    n_materials=4,
)

DEMO = GantryRecipe(
    name="demo",
    description="The bundled sample run: 64 x 64 px, 3 RGB cameras (15, 45, 75 deg), 11 LEDs "
    "on the 40 deg ring, 3 rotations; 32 noisy bands spread over 10 LED "
    "positions per rotation (sparse mode, as in the paper).",
    size=64,
    rgb_camera_thetas=(15.0, 45.0, 75.0),
    n_rotations=3,
    leds=ring_leds(40.0, [120 + 15 * k for k in range(11)]),
    spectral_set_size=10,
    n_dark_frames=16,
)

PAPER = GantryRecipe(
    name="paper",
    description="The paper's gantry at full scale: 2048 x 2048 px, 11 RGB cameras on an arc "
    "0..75 deg, 198 LEDs, 24 rotations, 200 dark frames per exposure time. "
    "Lazy: compute chunks, never the whole run.",
    size=2048,
    chunk_size=512,
    noise_tile=256,
    frames_per_chunk=1,
    n_rotations=24,
    n_dark_frames=200,
)

#: The named recipes.
RECIPES: dict[str, GantryRecipe] = {r.name: r for r in (TINY, DEMO, PAPER)}
#: One-line description per recipe.
DESCRIPTIONS: dict[str, str] = {k: v.description for k, v in RECIPES.items()}


def recipe_names() -> list[str]:
    """Names of the recipes."""
    return sorted(RECIPES)


def get_recipe(name: str, **overrides: Any) -> GantryRecipe:
    """A named recipe, optionally with fields overridden (validated; unknown keys fail).

    Raises
    ------
    SimulationParameterError
        For an unknown name (listing the known ones) or an invalid override.
    """
    try:
        base = RECIPES[name]
    except KeyError:
        raise SimulationParameterError.single(
            "recipe", f"one of {recipe_names()}", repr(name), hint=f"recipe {name!r} is unknown"
        ) from None
    if not overrides:
        return base
    data = base.model_dump() | overrides
    try:
        return GantryRecipe.model_validate(data)
    except ValidationError as exc:
        problems = [
            Problem(".".join(str(p) for p in item["loc"]), item["msg"], repr(item["input"]))
            if item["loc"]
            # a rule across fields: its message says what and why
            else Problem("recipe", "a consistent recipe", item["msg"].removeprefix("Value error, "))
            for item in exc.errors()
        ]
        raise SimulationParameterError(
            f"invalid override(s) {sorted(overrides)} for recipe {name!r}:", problems
        ) from None
