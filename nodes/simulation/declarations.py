"""The ``simulate`` node: a complete raw run store from a named recipe (paper sec. 5).

``spectralize run simulate run.zarr --set simulate.recipe=demo --set simulate.seed=3``
writes every raw group of a gantry run plus the evaluation-only truth groups, lazily, chunk
by chunk (see :mod:`spectralize.nodes.simulation.assembly` and ``datasets/README.md``).
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import xarray as xr
from pydantic import Field

from spectralize.engine import Choices, Node
from spectralize.nodes.simulation.assembly import GROUPS, simulate_run
from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.recipes import RECIPES, get_recipe

__all__ = ["simulate", "SIMULATE"]


def simulate(
    *,
    recipe: Annotated[str, Choices(RECIPES, "recipe")] = "demo",
    seed: Annotated[int | None, Field(ge=0)] = None,
    size: Annotated[int | None, Field(ge=8)] = None,
    n_rotations: Annotated[int | None, Field(ge=1)] = None,
    spectral_mode: Literal["sparse", "dense"] | None = None,
    noise: Literal["gaussian", "shot"] | None = None,
    overrides: dict[str, Any] | None = None,
    max_gigabytes: Annotated[float, Field(gt=0)] = 50.0,
) -> dict[str, xr.Dataset]:
    """Simulate a raw gantry run from a named recipe with optional overrides.

    The node's parameters are this signature (the engine derives them): ``recipe`` must be
    a key of :data:`~spectralize.nodes.simulation.recipes.RECIPES`, checked before anything
    runs.

    Parameters
    ----------
    recipe
        Named recipe, a key of ``RECIPES`` (``tiny`` for tests, ``demo``, ``paper``).
    seed
        Seed of texture and noise (``None``: the recipe's).
    size
        Image height = width [px] (``None``: the recipe's).
    n_rotations
        Rotation stage positions (``None``: the recipe's).
    spectral_mode
        ``sparse``: 32 bands over a set of LEDs; ``dense``: all bands per LED (``None``: the recipe's).
    noise
        ``gaussian`` (the paper's eq. 5) or photon ``shot`` noise (``None``: the recipe's).
    overrides
        Further recipe fields by name, e.g. ``{"misregistration": [0.5, 0.0]}``.
    max_gigabytes
        Refuse runs larger than this (uncompressed; the paper recipe is 33 TB).
        A larger run raises before anything is computed; the groups stay lazy, so
        ``simulate_run`` itself has no such limit.

    Returns
    -------
    dict of str to xarray.Dataset
        ``{group: Dataset}`` for every group in
        :data:`spectralize.nodes.simulation.assembly.GROUPS`, dask-backed.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 4 and 5 (eq. 2, 3, 5).
    """
    changes: dict[str, Any] = dict(overrides or {})
    for key, value in (
        ("seed", seed),
        ("size", size),
        ("n_rotations", n_rotations),
        ("spectral_mode", spectral_mode),
        ("noise", noise),
    ):
        if value is not None:
            changes[key] = value
    run = simulate_run(get_recipe(recipe, **changes))
    total = sum(ds.nbytes for ds in run.values()) / 1e9
    if total > max_gigabytes:
        raise SimulationParameterError(
            f"recipe {recipe!r} would write {total:,.1f} GB (more than max_gigabytes="
            f"{max_gigabytes:g}); make it smaller (simulate.size, simulate.n_rotations, "
            "or 'leds' and 'rgb_camera_thetas' in simulate.overrides), raise "
            "simulate.max_gigabytes, or compute chunks of "
            "spectralize.nodes.simulation.assembly.simulate_run(...) lazily instead."
        )
    return run


SIMULATE = Node(
    name="simulate",
    version="1",
    function=simulate,
    inputs={},
    outputs=tuple(GROUPS),
    description="Simulate a raw gantry run (RGB series, noisy bands, darks, calibration "
    "shots) and its ground truth from a named recipe (sec. 4, 5; eq. 2, 3, 5).",
)
