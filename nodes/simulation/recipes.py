"""The recipe of a simulated gantry run: what the run contains, and the named sample runs.

A :class:`GantryRecipe` fixes everything a simulated run depends on: image size and chunking,
spectra, the gantry's geometry (RGB camera arc, switched LEDs of :data:`GANTRY_LED_RINGS`,
rotation stage, spectral camera pose and misregistration), both cameras (sensitivities,
responses, offsets, noise; eq. 5), the exposure plan's parameters (eq. 2, 3) and the
calibration shots.  It is data only: :mod:`~spectralize.nodes.simulation.schedule` derives
what is shot from it, :mod:`~spectralize.nodes.simulation.rendering` renders the shots and
:mod:`~spectralize.nodes.simulation.assembly` builds the run's groups.  Equal recipes give
equal runs, bit for bit.

The named recipes:

===========  =====================================================================
``tiny``     32 x 32 px, 2 RGB cameras (15, 45 deg), 5 LEDs, 2 rotations; for tests
             (generated in about a second).
``demo``     the bundled sample run: 64 x 64 px, 3 RGB cameras (15, 45, 75 deg), 11 LEDs
             of the 40 deg ring around the mirror direction, 3 rotations, one sparse set
             of 32 bands over 10 LED positions per rotation after the first.
``paper``    the paper's gantry: 2048 x 2048 px, 11 RGB cameras (0..75 deg), 198 LEDs,
             24 rotations; lazy (dask) only: terabytes of raw RGB data if computed.
===========  =====================================================================

Measured sizes and times are in ``datasets/README.md``.  Use :func:`get_recipe` with
overrides, e.g. ``get_recipe("demo", seed=3, size=96)``.

References
----------
Fast Capture of Spectral Image Series, sec. 4 ("RGB Measurement Setup", "Spectral
Integration") and 5 (eq. 2, 3, 5).
"""

from __future__ import annotations

import hashlib
import math
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from spectralize.engine import Choices
from spectralize.nodes.simulation.camera_model import (
    RESPONSE_MODELS,
    SimulationParameterError,
    response_model,
)
from spectralize.nodes.simulation.ground_truth import wavelength_grid
from spectralize.schemas import Problem

__all__ = [
    "GANTRY_LED_RINGS",
    "led_positions",
    "ring_leds",
    "ResponseSpec",
    "GantryRecipe",
    "RECIPES",
    "DESCRIPTIONS",
    "get_recipe",
    "recipe_names",
]

#: The gantry's LED layout as (polar angle [deg], count) rings; 6 + 8 x 24 = 198 LEDs on the
#: hemisphere, the rings of 24 at 15 deg steps in azimuth (paper sec. 4).
GANTRY_LED_RINGS: tuple[tuple[float, int], ...] = (
    (3.0, 6),
    (10.0, 24),
    (20.0, 24),
    (30.0, 24),
    (40.0, 24),
    (50.0, 24),
    (60.0, 24),
    (70.0, 24),
    (80.0, 24),
)


def led_positions(
    rings: tuple[tuple[float, int], ...] = GANTRY_LED_RINGS,
) -> tuple[np.ndarray, np.ndarray]:
    """Polar angle and azimuth [deg] of every LED, ring by ring, azimuth from 0.

    An LED's index into these arrays is its index in the gantry layout (``GantryRecipe.leds``,
    the ``led`` coordinate of the run).
    """
    theta, phi = [], []
    for t, n in rings:
        theta += [float(t)] * n
        phi += list(np.arange(n) * 360.0 / n)
    return np.asarray(theta), np.asarray(phi)


def ring_leds(
    theta: float,
    azimuths: list[float] | np.ndarray,
    rings: tuple[tuple[float, int], ...] = GANTRY_LED_RINGS,
) -> tuple[int, ...]:
    """Indices of the LEDs of the ring at polar angle ``theta`` at the given azimuths [deg].

    Raises
    ------
    SimulationParameterError
        If the layout has no LED (or more than one) at one of the positions.
    """
    th, ph = led_positions(rings)
    out = []
    for a in azimuths:
        hit = np.flatnonzero(np.isclose(th, theta) & np.isclose(ph, float(a) % 360.0))
        if hit.size != 1:
            raise SimulationParameterError(
                f"no LED at theta={theta:g}, phi={a:g} deg in the gantry layout."
            )
        out.append(int(hit[0]))
    return tuple(out)


class ResponseSpec(BaseModel):
    """A camera's true response model (``f`` in eq. 5) by name and parameters.

    Kept as data (a name of ``RESPONSE_MODELS`` and its parameters) so that the recipe stays
    serialisable and its fingerprint stable; :meth:`build` makes the model.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")
    model: Annotated[str, Choices(RESPONSE_MODELS, "response model")] = "linear"
    parameters: dict[str, float] = Field(default_factory=dict)

    def build(self):  # -> ResponseModel
        """The response model this spec names."""
        return response_model(self.model, **self.parameters)


_DEFAULT_RGB_RESPONSES = (
    ResponseSpec(model="s_curve", parameters={"contrast": 4.0, "midpoint": 0.35}),
    ResponseSpec(model="s_curve", parameters={"contrast": 4.4, "midpoint": 0.33}),
    ResponseSpec(model="s_curve", parameters={"contrast": 3.6, "midpoint": 0.38}),
)


class GantryRecipe(BaseModel):
    """Everything that defines a simulated run; frozen, unknown keys are an error.

    Sizes, geometry, cameras, noise, exposure planning (eq. 2, 3: ``omega``, ``t0``, ``s0``)
    and chunking.  The named instances are :data:`RECIPES`.  Times in s, angles in deg,
    offsets and noise in DN.  The validator rejects recipes that could not be captured
    (e.g. a spectral camera whose azimuth offset is not one rotation step, which breaks the
    pairing of band shots with RGB images), so every valid recipe simulates.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = "custom"
    description: str = ""
    seed: int = Field(0, ge=0, description="seed of the texture and all noise")
    # sizes and chunking
    size: int = Field(64, ge=8, description="image height = width [px]")
    chunk_size: int | None = Field(None, ge=8, description="spatial chunk [px]; None: size up to 512")
    noise_tile: int = Field(256, ge=8, description="noise is drawn per tile of this size")
    frames_per_chunk: int = Field(8, ge=1, description="frames (images, shots) per chunk")
    # spectra
    wavelength_start: float = 410.0
    wavelength_stop: float = 720.0
    wavelength_step: float = 10.0
    illuminant: str = "LED-B3"
    n_materials: int = Field(6, ge=2, le=18)
    # geometry
    rgb_camera_thetas: tuple[float, ...] = tuple(np.linspace(0.0, 75.0, 11).tolist())
    spectral_camera_theta: float = 45.0
    spectral_camera_phi: float = 15.0
    rotation_step: float = 15.0
    n_rotations: int = Field(24, ge=1)
    leds: tuple[int, ...] | None = Field(
        None, description="LED indices into the gantry layout switched in the run; None: all 198"
    )
    misregistration: tuple[float, float] = Field(
        (0.35, -0.6), description="(dy, dx) px shift of the spectral image content"
    )
    # RGB cameras
    camera_sensitivities: str = "Nikon 5100 (NPL)"
    # Exposure series with unequal ratios (3, 3.33, 4): with equal ratios (a geometric
    # bracket) Robertson's response is determined only up to a factor periodic in log
    # exposure (Grossberg & Nayar 2003).
    rgb_exposure_times: tuple[float, ...] = (0.001, 0.003, 0.010, 0.040)
    rgb_saturation_time: float = Field(
        0.02, gt=0, description="exposure at which a white diffuse target at normal incidence saturates"
    )
    rgb_responses: tuple[ResponseSpec, ResponseSpec, ResponseSpec] = _DEFAULT_RGB_RESPONSES
    rgb_bit_depth: int = Field(10, ge=8, le=16)
    rgb_adc_offset: float = Field(16.0, ge=0)
    rgb_noise_sigma: float = Field(1.0, ge=0)
    # spectral camera
    spectral_response: ResponseSpec = ResponseSpec(model="log", parameters={"a": 0.5})
    spectral_bit_depth: int = Field(10, ge=8, le=16)
    spectral_adc_offset: float = Field(32.0, ge=0, description="mean ADC offset")
    spectral_offset_pattern: float = Field(
        1.5, ge=0, description="std of the fixed pattern of the offset"
    )
    spectral_dark_current: float = Field(0.05, ge=0, description="mean dark signal per s (a cooled CCD)")
    spectral_noise_sigma: float = Field(3.0, ge=0, description="the paper measured 3 DN")
    spectral_peak_qe: float = Field(2.5, gt=0)
    bandpass_fwhm: float = Field(10.0, ge=0)
    noise: Literal["gaussian", "shot"] = "gaussian"
    full_well: float = Field(20000.0, gt=0)
    # exposure plan (eq. 2, 3)
    omega: float = Field(0.8, gt=0, le=1)
    t0: float | None = Field(None, gt=0, description="None: from spectral_total_time")
    spectral_total_time: float = Field(6.0, gt=0, description="time of one set of bands")
    s0: float = Field(0.25, ge=0)
    exposure_resolution: float = Field(1e-4, gt=0, description="shutter time step [s]")
    spectral_mode: Literal["sparse", "dense"] = "sparse"
    spectral_set_size: int = Field(
        10, ge=1, description="LED positions a set of bands is spread over (sparse mode)"
    )
    # calibration shots
    n_dark_frames: int = Field(16, ge=1)
    reference_exposure: float = Field(0.8, gt=0, le=1)
    calibration_exposure_ratios: tuple[float, ...] = Field(
        (2.0, 3.0),
        description="ratios between consecutive exposure times of the "
        "calibration series (RGB and spectral), used in turn; unequal ratios make the "
        "response identifiable (Robertson), many small steps give the low-SNR extension "
        "several unsaturated exposures at low signal",
    )
    calibration_exposure_span: float = Field(
        256.0,
        ge=1,
        description="the spectral series starts this factor below the shortest reference time",
    )

    @model_validator(mode="after")
    def _check(self) -> GantryRecipe:
        # A SimulationParameterError is a ValueError: pydantic reports it in the
        # ValidationError, which get_recipe turns into a SimulationParameterError again.
        if (
            self.chunk_size is not None
            and self.chunk_size < self.size
            and (self.chunk_size % self.noise_tile)
        ):
            raise SimulationParameterError(
                f"chunk_size ({self.chunk_size}) must be a multiple of noise_tile "
                f"({self.noise_tile}) so that noise does not depend on chunking."
            )
        if not self.rgb_exposure_times or min(self.rgb_exposure_times) <= 0:
            raise SimulationParameterError(
                f"rgb_exposure_times must be non-empty and > 0 s; received {self.rgb_exposure_times}."
            )
        if list(self.rgb_exposure_times) != sorted(self.rgb_exposure_times):
            raise SimulationParameterError(
                f"rgb_exposure_times must be increasing; received {self.rgb_exposure_times}."
            )
        if not self.calibration_exposure_ratios or min(self.calibration_exposure_ratios) <= 1:
            raise SimulationParameterError(
                "calibration_exposure_ratios must be non-empty and > 1; "
                f"received {self.calibration_exposure_ratios}."
            )
        if not self.rgb_camera_thetas or any(not 0 <= t < 90 for t in self.rgb_camera_thetas):
            raise SimulationParameterError(
                "rgb_camera_thetas must be polar angles in [0, 90) deg; "
                f"received {self.rgb_camera_thetas}."
            )
        if not any(math.isclose(t, self.spectral_camera_theta) for t in self.rgb_camera_thetas):
            raise SimulationParameterError(
                f"rgb_camera_thetas {self.rgb_camera_thetas} must contain the spectral "
                f"camera's polar angle {self.spectral_camera_theta} (the paired camera)."
            )
        if not math.isclose(self.spectral_camera_phi, self.rotation_step):
            raise SimulationParameterError(
                f"spectral_camera_phi ({self.spectral_camera_phi}) must equal rotation_step "
                f"({self.rotation_step}) so the spectral camera sees, one rotation later, "
                "what the RGB camera saw."
            )
        n_leds = sum(n for _, n in GANTRY_LED_RINGS)
        if self.leds is not None:
            if (
                not self.leds
                or len(set(self.leds)) != len(self.leds)
                or any(not 0 <= i < n_leds for i in self.leds)
            ):
                raise SimulationParameterError(
                    f"leds must be distinct indices in 0..{n_leds - 1}; received {self.leds}."
                )
        wavelength_grid(self.wavelength_start, self.wavelength_stop, self.wavelength_step)
        return self

    def fingerprint(self) -> str:
        """Short hash of the recipe (names dask keys; equal recipes give equal keys)."""
        return hashlib.sha256(self.model_dump_json().encode()).hexdigest()[:16]


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
