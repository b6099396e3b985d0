"""The ``simulate`` node: a complete raw run store from a named recipe (paper sec. 5).

``spectralize run simulate run.zarr --set simulate.recipe=demo --set simulate.seed=3``
writes every raw group of a gantry run plus the evaluation-only truth groups, lazily, chunk
by chunk (see :mod:`spectralize.nodes.simulation.gantry` and ``datasets/README.md``).
"""

from __future__ import annotations

from typing import Any, Literal

import xarray as xr
from pydantic import Field

from spectralize.engine import Node, Parameters
from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.gantry import GROUPS, simulate_run
from spectralize.nodes.simulation.recipes import RECIPES, get_recipe

__all__ = ["SimulateParameters", "simulate", "SIMULATE"]


class SimulateParameters(Parameters):
    """Parameters of :func:`simulate`: a recipe name plus overrides."""

    recipe: Literal["tiny", "demo", "paper"] = Field(
        "demo", description=f"named recipe: {', '.join(sorted(RECIPES))}")
    seed: int | None = Field(None, ge=0, description="seed of texture and noise "
                             "(default: the recipe's)")
    size: int | None = Field(None, ge=8, description="image height = width [px]")
    n_rotations: int | None = Field(None, ge=1, description="rotation stage positions")
    spectral_mode: Literal["sparse", "dense"] | None = Field(
        None, description="sparse: 32 bands over a set of LEDs; dense: all bands per LED")
    noise: Literal["gaussian", "shot"] | None = Field(
        None, description="gaussian (the paper's eq. 5) or photon shot noise")
    overrides: dict[str, Any] = Field(
        default_factory=dict, description="any other GantryRecipe field, e.g. "
        '{"misregistration": [0.5, 0.0]}')
    max_gigabytes: float = Field(
        50.0, gt=0, description="refuse runs larger than this (the paper recipe is 33 TB)")


def simulate(
    *,
    recipe: str = "demo",
    seed: int | None = None,
    size: int | None = None,
    n_rotations: int | None = None,
    spectral_mode: str | None = None,
    noise: str | None = None,
    overrides: dict[str, Any] | None = None,
    max_gigabytes: float = 50.0,
) -> dict[str, xr.Dataset]:
    """Simulate a raw gantry run from a named recipe with optional overrides.

    Parameters
    ----------
    recipe
        Name in ``spectralize.nodes.simulation.recipes.RECIPES``.
    seed, size, n_rotations, spectral_mode, noise
        Common overrides of the recipe (``None``: keep the recipe's value).
    overrides
        Further recipe fields by name.
    max_gigabytes
        Size limit of the whole run (uncompressed); a larger run raises before anything is
        computed. The groups stay lazy, so ``simulate_run`` itself has no such limit.

    Returns
    -------
    dict of str to xarray.Dataset
        ``{group: Dataset}`` for every group in
        :data:`spectralize.nodes.simulation.gantry.GROUPS`, dask-backed.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 4 and 5 (eq. 2, 3, 5).
    """
    changes: dict[str, Any] = dict(overrides or {})
    for key, value in (("seed", seed), ("size", size), ("n_rotations", n_rotations),
                       ("spectral_mode", spectral_mode), ("noise", noise)):
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
            "spectralize.nodes.simulation.gantry.simulate_run(...) lazily instead.")
    return run


SIMULATE = Node(
    name="simulate",
    version="1",
    function=simulate,
    inputs={},
    outputs=tuple(GROUPS),
    parameters=SimulateParameters,
    description="Simulate a raw gantry run (RGB series, noisy bands, darks, calibration "
                "shots) and its ground truth from a named recipe (sec. 4, 5; eq. 2, 3, 5).",
)
