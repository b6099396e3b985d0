"""BTF gantry simulator: a complete raw measurement run, generated lazily chunk by chunk.

Geometry (paper sec. 4, "RGB Measurement Setup" and "Spectral Integration"):

- RGB cameras on an arc at azimuth 0 deg, polar angles 0..75 deg from the sample normal;
- LEDs on the hemisphere in rings of 24 (15 deg apart) plus a small top ring (198 in all);
- the sample on a rotation stage, rotated in 15 deg steps;
- the spectral camera (monochrome + tunable filter) at 45 deg with a 15 deg azimuth offset
  from the RGB camera at 45 deg.  Since the offset equals the rotation step, the spectral
  camera at rotation ``r + 1`` with LED ``l'`` (15 deg further in azimuth than LED ``l``)
  sees the sample under exactly the same view and light directions, in the sample's frame,
  as the 45 deg RGB camera at rotation ``r`` with LED ``l``: each band shot "pairs" with
  that RGB image.  A small known misregistration (a sub-pixel shift) separates the two.

Images are rectified to the sample plane (as a BTF pipeline does after detecting the
sample holder), so all images share pixel coordinates except the spectral camera's shift.
Each image's radiance comes from :mod:`spectralize.nodes.simulation.ground_truth` (measured
reflectances, shading, a specular lobe with the illuminant's spectrum), counts from
:mod:`spectralize.nodes.simulation.camera_model` (eq. 5), band exposure times and filter sizes from
:mod:`spectralize.nodes.simulation.exposure_plan` (eq. 2, 3).

Output: :func:`simulate_run` returns ``{group: xarray.Dataset}`` with dask-backed
variables; nothing is computed until a chunk is asked for, so even the paper-scale run
(2048 x 2048 px, 11 cameras, 198 LEDs, 24 rotations) has bounded memory.  Noise is drawn
per frame and per fixed ``noise_tile`` from ``numpy.random.SeedSequence(seed,
spawn_key=...)``, so values do not depend on chunking or scheduling.

The group layout is documented in ``datasets/README.md`` and :data:`GROUPS`.

References
----------
Fast Capture of Spectral Image Series, sec. 4 and 5.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Annotated, Literal

import dask.array as da
import numpy as np
import xarray as xr
from dask.array.core import normalize_chunks
from pydantic import BaseModel, ConfigDict, Field, model_validator

from spectralize.engine import Choices
from spectralize.nodes.simulation.camera_model import (
    RESPONSE_MODELS,
    RGBCamera,
    SimulationParameterError,
    SpectralCamera,
    camera_sensitivities,
    capture_with_generator,
    gaussian_bandpass,
    oecf_table,
    response_model,
    spectral_quantum_efficiency,
)
from spectralize.nodes.simulation.exposure_plan import (
    exposure_plan,
    reference_exposure_plan,
    t0_for_total_time,
)
from spectralize.nodes.simulation.ground_truth import (
    ColourCheckerChart,
    SpectralTexture,
    direction,
    illuminant_spd,
    shading,
    spectral_texture,
    wavelength_grid,
)
from spectralize.schemas import register_schema
from spectralize.schemas.run import (
    RAW_COLOUR_CHECKER,
    RAW_EXPOSURE_PLAN,
    RAW_REGISTRATION,
    RAW_WHITE_REFERENCE,
    TRUTH_CAMERA,
)
from spectralize.schemas.spec import GroupSchema

__all__ = [
    "GROUPS",
    "SCHEMAS",
    "register_schemas",
    "group_schema",
    "GANTRY_LED_RINGS",
    "GantryRecipe",
    "ring_leds",
    "Gantry",
    "simulate_run",
]

#: Groups produced by :func:`simulate_run`, with a one-line description.
GROUPS: dict[str, str] = {
    "raw/dark": "dark frame stacks of the spectral camera, one per exposure time it uses",
    "raw/rgb": "RGB exposure series (4 exposures) per (camera, rotation, LED) image",
    "raw/spectral": "noisy band shots of the spectral camera following the exposure plan",
    "raw/exposure_plan": "the exposure plan (eq. 2, 3) the band shots followed",
    "raw/white_reference": "white diffuse target: RGB and spectral exposure series",
    "raw/colour_checker": "ColorChecker chart: RGB and spectral exposure series",
    "raw/registration": "long-exposure registration shots per rotation (RGB 45 deg, spectral)",
    "truth/spectra": "true spectral radiance of every RGB image (evaluation only)",
    "truth/camera": "true camera parameters: C, Q, L, OECFs, offsets, noise, misregistration",
}


# The contracts of the groups this simulator writes live with the rest of the contract in
# spectralize.schemas.run; SCHEMAS names the ones beyond the core groups.
SCHEMAS: dict[str, GroupSchema] = {
    s.name: s
    for s in (RAW_EXPOSURE_PLAN, RAW_WHITE_REFERENCE, RAW_COLOUR_CHECKER, RAW_REGISTRATION, TRUTH_CAMERA)
}


def register_schemas() -> None:
    """Kept for compatibility: the schemas are registered with the contract on import."""
    for schema in SCHEMAS.values():
        register_schema(schema)


def group_schema(group: str) -> GroupSchema:
    """The schema of one simulated group: the contract's or one of :data:`SCHEMAS`."""
    from spectralize.schemas import GROUP_SCHEMAS

    if group in SCHEMAS:
        return SCHEMAS[group]
    return GROUP_SCHEMAS[group]


#: The gantry's LED layout as (polar angle [deg], count) rings; 6 + 8 x 24 = 198 LEDs.
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

# stream ids of the seed sequence (spawn_key[0]); never reuse one for another purpose
_STREAM_RGB, _STREAM_SPECTRAL, _STREAM_DARK, _STREAM_PATTERN = 1, 2, 3, 4
_STREAM_WHITE_RGB, _STREAM_WHITE_SPEC, _STREAM_CC_RGB, _STREAM_CC_SPEC = 5, 6, 7, 8
_STREAM_REG_RGB, _STREAM_REG_SPEC = 9, 10


def _strings(values) -> np.ndarray:
    """Fixed-width unicode strings: they read back as ``<U`` (the contract's ``kind:U``).

    Object strings would be stored without zarr's UnstableSpecificationWarning but read
    back as numpy ``StringDType`` (kind ``T``), which the contract does not accept yet.
    """
    return np.array([str(v) for v in values], dtype=str)


def led_positions(
    rings: tuple[tuple[float, int], ...] = GANTRY_LED_RINGS,
) -> tuple[np.ndarray, np.ndarray]:
    """Polar angle and azimuth [deg] of every LED, ring by ring, azimuth from 0."""
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
    """Indices of the LEDs of the ring at polar angle ``theta`` at the given azimuths [deg]."""
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
    """A true response model by name and parameters (see ``RESPONSE_MODELS``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    model: Annotated[str, Choices(RESPONSE_MODELS, "response model")] = "linear"
    parameters: dict[str, float] = Field(default_factory=dict)

    def build(self):  # -> ResponseModel
        return response_model(self.model, **self.parameters)


_DEFAULT_RGB_RESPONSES = (
    ResponseSpec(model="s_curve", parameters={"contrast": 4.0, "midpoint": 0.35}),
    ResponseSpec(model="s_curve", parameters={"contrast": 4.4, "midpoint": 0.33}),
    ResponseSpec(model="s_curve", parameters={"contrast": 3.6, "midpoint": 0.38}),
)


class GantryRecipe(BaseModel):
    """Everything that defines a simulated run; frozen, unknown keys are an error.

    Sizes, geometry, cameras, noise, exposure planning and chunking.  Named instances are
    in ``spectralize.nodes.simulation.recipes``.  Times in s, angles in deg, offsets and noise in DN.
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


# --------------------------------------------------------------------------------------
# the run plan: everything small, computed eagerly
# --------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Images:
    camera: np.ndarray
    rotation: np.ndarray
    led: np.ndarray
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray

    def __len__(self) -> int:
        return int(self.camera.size)


@dataclass(frozen=True, eq=False)
class _Shots:
    band: np.ndarray  # index into wavelength
    rotation: np.ndarray
    led: np.ndarray
    image: np.ndarray
    led_set: np.ndarray
    theta_i: np.ndarray
    phi_i: np.ndarray
    theta_o: np.ndarray
    phi_o: np.ndarray

    def __len__(self) -> int:
        return int(self.band.size)


class Gantry:
    """The simulated gantry of one recipe: geometry, cameras, plan and block generators.

    Construct with a :class:`GantryRecipe`; :meth:`groups` returns the lazy run.  The
    block methods (``rgb_block`` etc.) compute one chunk from absolute index slices and
    are what the dask graph calls.
    """

    def __init__(self, recipe: GantryRecipe) -> None:
        self.recipe = recipe
        self._pattern_cache: dict = {}  # per-tile fixed pattern (cleared when pickled)
        r = recipe
        self.wavelength = wavelength_grid(r.wavelength_start, r.wavelength_stop, r.wavelength_step)
        self.illuminant = illuminant_spd(self.wavelength, name=r.illuminant)
        self.texture: SpectralTexture = spectral_texture(
            r.size, wavelength=self.wavelength, seed=r.seed, n_materials=r.n_materials
        )
        self.chart = ColourCheckerChart(r.size, self.wavelength)
        # cameras
        sens = camera_sensitivities(self.wavelength, name=r.camera_sensitivities)
        gain = 1.0 / (r.rgb_saturation_time * float((sens @ self.illuminant).max()))
        cm = (sens * gain).rename("camera_matrix")
        cm.attrs = {
            "units": "s-1",
            "long_name": "RGB camera matrix C (spectral "
            "sensitivity per unit relative radiance and second)",
            "source": sens.attrs["source"],
        }
        self.rgb_camera = RGBCamera(
            camera_matrix=cm,
            responses={c: s.build() for c, s in zip("RGB", r.rgb_responses, strict=True)},
            adc_offset=r.rgb_adc_offset,
            noise_sigma=r.rgb_noise_sigma,
            bit_depth=r.rgb_bit_depth,
            noise=r.noise,
            full_well=r.full_well,
        )
        self.spectral_camera = SpectralCamera(
            quantum_efficiency=spectral_quantum_efficiency(self.wavelength, peak=r.spectral_peak_qe),
            response=r.spectral_response.build(),
            bandpass_fwhm=r.bandpass_fwhm,
            adc_offset=r.spectral_adc_offset,
            noise_sigma=r.spectral_noise_sigma,
            bit_depth=r.spectral_bit_depth,
            noise=r.noise,
            full_well=r.full_well,
        )
        self.bandpass = gaussian_bandpass(self.wavelength, fwhm=r.bandpass_fwhm).values
        ell = self.illuminant.values
        # channel / band weights with the illuminant folded in
        self.rgb_weights = (cm.values * ell[None, :]).astype(np.float32)  # (3, n)
        self.band_weights = (self.bandpass * ell[None, :]).astype(np.float32)  # (n, n)
        self.band_illuminant = self.bandpass @ ell  # L_i seen through band i
        self.q = self.spectral_camera.quantum_efficiency.values
        # geometry
        self.led_theta, self.led_phi = led_positions()
        self.leds = np.arange(self.led_theta.size) if r.leds is None else np.asarray(r.leds)
        self.cameras = np.asarray(r.rgb_camera_thetas, dtype=np.float64)
        self.paired_camera = int(np.flatnonzero(np.isclose(self.cameras, r.spectral_camera_theta))[0])
        self.rotation_angle = np.arange(r.n_rotations) * r.rotation_step
        self.images = self._image_table()
        self.plan = self._plan()
        self.band_time = self._quantise(self.plan["exposure_time"].values)
        self.shots = self._shot_table()
        if len(self.shots) == 0:
            raise SimulationParameterError(
                "the recipe gives the spectral camera nothing to shoot: no switched LED has "
                f"a partner {r.rotation_step:g} deg further round its ring among `leds`, or "
                "n_rotations is 1 on a partial circle. Add the neighbouring LEDs (e.g. "
                "ring_leds(40, [165, 180, 195])) or more rotations."
            )
        self.reference = reference_exposure_plan(
            self.q,
            self.band_illuminant,
            wavelength=self.wavelength,
            target_exposure=r.reference_exposure,
        )
        self.calib_spectral_times = self._calibration_spectral_times()
        self.calib_rgb_times = self._calibration_rgb_times()
        reg_band = int(np.argmax(self.q * self.band_illuminant))
        self.registration_band = reg_band
        self.registration_spectral_time = self._quantise(
            0.5 * r.reference_exposure / (self.q[reg_band] * self.band_illuminant[reg_band])
        )
        self.registration_rgb_time = self._quantise(0.5 * r.rgb_saturation_time)
        self.dark_times = np.unique(
            np.concatenate(
                [
                    self.band_time[np.unique(self.shots.band)] if len(self.shots) else [],
                    self.calib_spectral_times,
                    [self.registration_spectral_time],
                ]
            )
        )

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_pattern_cache"] = {}
        return state

    # -- tables ------------------------------------------------------------------------
    def _quantise(self, t: np.ndarray | float) -> np.ndarray:
        res = self.recipe.exposure_resolution
        return np.maximum(np.round(np.asarray(t, dtype=np.float64) / res), 1) * res

    def _image_table(self) -> _Images:
        r = self.recipe
        rot, led, cam = np.meshgrid(
            np.arange(r.n_rotations), self.leds, np.arange(self.cameras.size), indexing="ij"
        )
        rot, led, cam = rot.ravel(), led.ravel(), cam.ravel()
        rho = self.rotation_angle[rot]
        return _Images(
            camera=cam,
            rotation=rot,
            led=led,
            theta_i=self.led_theta[led],
            phi_i=(self.led_phi[led] - rho) % 360.0,
            theta_o=self.cameras[cam],
            phi_o=(0.0 - rho) % 360.0,
        )

    def image_index(self, camera: int, rotation: int, led: int) -> int:
        """Index along ``image`` of the RGB image (camera, rotation, LED)."""
        li = int(np.flatnonzero(self.leds == led)[0])
        return (rotation * self.leds.size + li) * self.cameras.size + camera

    def partner_led(self, led: int) -> int | None:
        """The LED one rotation step further in azimuth on the same ring, if switched."""
        t, p = self.led_theta[led], (self.led_phi[led] + self.recipe.rotation_step) % 360
        hit = np.flatnonzero(
            np.isclose(self.led_theta, t) & np.isclose((self.led_phi - p + 180.0) % 360.0 - 180.0, 0.0)
        )
        if hit.size == 0 or hit[0] not in set(self.leds.tolist()):
            return None
        return int(hit[0])

    def _plan(self) -> xr.Dataset:
        r = self.recipe
        t0 = (
            r.t0
            if r.t0 is not None
            else t0_for_total_time(
                self.q,
                self.band_illuminant,
                wavelength=self.wavelength,
                total_time=r.spectral_total_time,
                omega=r.omega,
            )
        )
        eligible = [int(k) for k in self.leds if self.partner_led(int(k)) is not None]
        # the full set of bands is shot once per set of LEDs (sparse) or per LED (dense)
        n_sets = math.ceil(len(eligible) / r.spectral_set_size)
        per_rotation = n_sets if r.spectral_mode == "sparse" else len(eligible)
        return exposure_plan(
            self.q,
            self.band_illuminant,
            wavelength=self.wavelength,
            t0=t0,
            s0=r.s0,
            omega=r.omega,
            rgb_exposure_times=r.rgb_exposure_times,
            rgb_images=len(self.images),
            spectral_sets=per_rotation * len(self._spectral_rotations()),
        )

    def _spectral_rotations(self) -> list[int]:
        r = self.recipe
        full = math.isclose(r.n_rotations * r.rotation_step, 360.0)
        return list(range(r.n_rotations)) if full else list(range(1, r.n_rotations))

    def _shot_table(self) -> _Shots:
        r = self.recipe
        eligible = [int(k) for k in self.leds if self.partner_led(int(k)) is not None]
        sets = [
            eligible[i : i + r.spectral_set_size] for i in range(0, len(eligible), r.spectral_set_size)
        ]
        n_bands = self.wavelength.size
        rows = []
        for rot in self._spectral_rotations():
            prev = (rot - 1) % r.n_rotations
            for s_idx, s in enumerate(sets):
                for k, led in enumerate(s):
                    if r.spectral_mode == "sparse":
                        bands = [j for j in range(n_bands) if j % len(s) == k]
                    else:
                        bands = list(range(n_bands))
                    partner = self.partner_led(led)
                    img = self.image_index(self.paired_camera, prev, led)
                    rows += [(j, rot, partner, img, s_idx) for j in bands]
        a = np.asarray(rows, dtype=np.int64).reshape(-1, 5)
        rho = self.rotation_angle[a[:, 1]]
        return _Shots(
            band=a[:, 0],
            rotation=a[:, 1],
            led=a[:, 2],
            image=a[:, 3],
            led_set=a[:, 4],
            theta_i=self.led_theta[a[:, 2]],
            phi_i=(self.led_phi[a[:, 2]] - rho) % 360.0,
            theta_o=np.full(len(a), r.spectral_camera_theta),
            phi_o=(r.spectral_camera_phi - rho) % 360.0,
        )

    def _irregular_series(self, lo: float, hi: float, *, cover: bool) -> np.ndarray:
        """Times from ``lo`` stepping by ``calibration_exposure_ratios`` in turn, quantised.

        ``cover``: the last time is the first at or above ``hi``; else the last at or below.
        """
        ratios = self.recipe.calibration_exposure_ratios
        times = [lo]
        k = 0
        while times[-1] * (1 + 1e-9) < hi:
            nxt = times[-1] * ratios[k % len(ratios)]
            k += 1
            if nxt > hi * (1 + 1e-9) and not cover:
                break
            times.append(nxt)
        return np.unique(self._quantise(np.asarray(times)))

    def _calibration_spectral_times(self) -> np.ndarray:
        r = self.recipe
        t_ref = self.reference["exposure_time"].values
        lo, hi = t_ref.min() / r.calibration_exposure_span, t_ref.max()
        return self._irregular_series(lo, hi, cover=False)

    def _calibration_rgb_times(self) -> np.ndarray:
        r = self.recipe
        lo, hi = r.rgb_exposure_times[0] / 4.0, r.rgb_exposure_times[-1] * 4.0
        return self._irregular_series(lo, hi, cover=True)

    # -- seeded randomness -------------------------------------------------------------
    def rng(self, *key: int) -> np.random.Generator:
        """Generator for one frame tile: ``SeedSequence(seed, spawn_key=key)``."""
        ss = np.random.SeedSequence(self.recipe.seed, spawn_key=tuple(int(k) for k in key))
        return np.random.Generator(np.random.PCG64(ss))

    def _tiles(self, rows: slice, cols: slice):
        """Noise tiles (ty, tx, local row slice, local col slice) covering a chunk."""
        t = self.recipe.noise_tile
        for ty in range(rows.start // t, (rows.stop - 1) // t + 1):
            y0, y1 = max(ty * t, rows.start), min((ty + 1) * t, rows.stop)
            for tx in range(cols.start // t, (cols.stop - 1) // t + 1):
                x0, x1 = max(tx * t, cols.start), min((tx + 1) * t, cols.stop)
                yield (
                    ty,
                    tx,
                    slice(y0 - rows.start, y1 - rows.start),
                    slice(x0 - cols.start, x1 - cols.start),
                )

    def _check_tiles(self, rows: slice, cols: slice) -> None:
        t = self.recipe.noise_tile
        for s in (rows, cols):
            if s.start % t or (s.stop % t and s.stop != self.recipe.size):
                raise SimulationParameterError(
                    f"chunk {s} is not aligned to noise_tile={t}; use chunk sizes that are "
                    "multiples of noise_tile."
                )

    def _capture(
        self,
        x: np.ndarray,
        rows: slice,
        cols: slice,
        key: tuple[int, ...],
        *,
        t: float,
        response,
        q: float = 1.0,
        offset: np.ndarray | float,
        sigma: float,
        bits: int,
    ) -> np.ndarray:
        """Eq. 5 on a chunk, noise drawn per noise tile from ``rng(*key, ty, tx)``."""
        out = np.empty(x.shape, dtype=np.uint16)
        off = np.broadcast_to(np.asarray(offset, dtype=np.float64), x.shape)
        for ty, tx, ry, rx in self._tiles(rows, cols):
            out[ry, rx] = capture_with_generator(
                x[ry, rx],
                t,
                self.rng(*key, ty, tx),
                response=response,
                quantum_efficiency=q,
                adc_offset=off[ry, rx],
                noise_sigma=sigma,
                bit_depth=bits,
                noise=self.recipe.noise,
                full_well=self.recipe.full_well,
            )
        return out

    def dark_pattern(self, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray]:
        """Fixed pattern of the spectral camera: (ADC offset [DN], dark current [DN/s])."""
        r = self.recipe
        key = (rows.start, rows.stop, cols.start, cols.stop)
        hit = self._pattern_cache.get(key)
        if hit is not None:
            return hit
        h, w = rows.stop - rows.start, cols.stop - cols.start
        off = np.empty((h, w))
        dc = np.empty((h, w))
        for ty, tx, ry, rx in self._tiles(rows, cols):
            g = self.rng(_STREAM_PATTERN, ty, tx)
            t = r.noise_tile
            # the whole noise tile (clipped to the image): independent of chunking
            th, tw = min(t, r.size - ty * t), min(t, r.size - tx * t)
            full = g.standard_normal((2, th, tw))
            y0 = (rows.start + ry.start) - ty * t
            x0 = (cols.start + rx.start) - tx * t
            sub = full[:, y0 : y0 + (ry.stop - ry.start), x0 : x0 + (rx.stop - rx.start)]
            off[ry, rx] = r.spectral_adc_offset + r.spectral_offset_pattern * sub[0]
            dc[ry, rx] = r.spectral_dark_current * np.exp(0.3 * sub[1] - 0.045)
        if len(self._pattern_cache) > 16:
            self._pattern_cache.clear()
        self._pattern_cache[key] = (off, dc)
        return off, dc

    # -- rendering helpers -------------------------------------------------------------
    def _diffuse_rgb(self, rows: slice, cols: slice) -> np.ndarray:
        key = ("rgb", rows.start, rows.stop, cols.start, cols.stop)
        hit = self.texture._cache.get(key)
        if hit is None:
            tile = self.texture.evaluate(rows, cols)
            hit = self.texture.remember(
                key, np.tensordot(self.rgb_weights, self.texture.diffuse_reflectance(tile), 1)
            )
        return hit

    def _diffuse_bands(self, rows: slice, cols: slice) -> np.ndarray:
        shift = self.recipe.misregistration
        key = ("bands", rows.start, rows.stop, cols.start, cols.stop)
        hit = self.texture._cache.get(key)
        if hit is None:
            tile = self.texture.evaluate(rows, cols, shift=shift)
            hit = self.texture.remember(
                key, np.tensordot(self.band_weights, self.texture.diffuse_reflectance(tile), 1)
            )
        return hit

    def _shade(self, rows: slice, cols: slice, ti, pi, to, po, shift=(0.0, 0.0)):
        tile = self.texture.evaluate(rows, cols, shift=shift)
        return shading(
            tile.normal,
            direction(ti, pi),
            direction(to, po),
            specular_albedo=tile.specular_albedo,
            shininess=tile.shininess,
        )

    def radiance(self, image: int, rows: slice, cols: slice) -> np.ndarray:
        """True spectral radiance (wavelength, h, w) float32 of RGB image ``image``."""
        im = self.images
        tile = self.texture.evaluate(rows, cols)
        d, s = self._shade(
            rows, cols, im.theta_i[image], im.phi_i[image], im.theta_o[image], im.phi_o[image]
        )
        ell = self.illuminant.values.astype(np.float32)[:, None, None]
        return ell * (self.texture.diffuse_reflectance(tile) * d + s)

    # -- blocks ------------------------------------------------------------------------
    def rgb_block(
        self, images: slice, exposures: slice, rows: slice, cols: slice, channels: slice
    ) -> np.ndarray:
        """raw/rgb counts (image, exposure, y, x, channel) of one chunk."""
        self._check_tiles(rows, cols)
        r, im, cam = self.recipe, self.images, self.rgb_camera
        times = np.asarray(r.rgb_exposure_times)
        rgb_d = self._diffuse_rgb(rows, cols)  # (3, h, w)
        white = self.rgb_weights.sum(axis=1)  # (3,)
        out = np.empty(
            (
                images.stop - images.start,
                exposures.stop - exposures.start,
                rows.stop - rows.start,
                cols.stop - cols.start,
                channels.stop - channels.start,
            ),
            dtype=np.uint16,
        )
        for a, i in enumerate(range(images.start, images.stop)):
            d, s = self._shade(rows, cols, im.theta_i[i], im.phi_i[i], im.theta_o[i], im.phi_o[i])
            x = rgb_d * d[None] + white[:, None, None] * s[None]
            for b, e in enumerate(range(exposures.start, exposures.stop)):
                for c, ch in enumerate(range(channels.start, channels.stop)):
                    out[a, b, :, :, c] = self._capture(
                        x[ch],
                        rows,
                        cols,
                        (_STREAM_RGB, i, e, ch),
                        t=times[e],
                        response=cam.responses["RGB"[ch]],
                        offset=cam.adc_offset,
                        sigma=cam.noise_sigma,
                        bits=cam.bit_depth,
                    )
        return out

    def band_irradiance(self, shot: int, rows: slice, cols: slice) -> np.ndarray:
        """Noiseless band irradiance ``x_i`` (h, w) of a spectral shot (with the shift)."""
        sh = self.shots
        j = int(sh.band[shot])
        d, s = self._shade(
            rows,
            cols,
            sh.theta_i[shot],
            sh.phi_i[shot],
            sh.theta_o[shot],
            sh.phi_o[shot],
            shift=self.recipe.misregistration,
        )
        return self._diffuse_bands(rows, cols)[j] * d + self.band_illuminant[j] * s

    def spectral_block(self, shots: slice, rows: slice, cols: slice) -> np.ndarray:
        """raw/spectral counts (shot, y, x) of one chunk."""
        self._check_tiles(rows, cols)
        cam = self.spectral_camera
        off, dc = self.dark_pattern(rows, cols)
        out = np.empty(
            (shots.stop - shots.start, rows.stop - rows.start, cols.stop - cols.start), dtype=np.uint16
        )
        for a, k in enumerate(range(shots.start, shots.stop)):
            j = int(self.shots.band[k])
            t = float(self.band_time[j])
            out[a] = self._capture(
                self.band_irradiance(k, rows, cols),
                rows,
                cols,
                (_STREAM_SPECTRAL, k),
                t=t,
                response=cam.response,
                q=float(self.q[j]),
                offset=off + dc * t,
                sigma=cam.noise_sigma,
                bits=cam.bit_depth,
            )
        return out

    def dark_block(self, times: slice, frames: slice, rows: slice, cols: slice) -> np.ndarray:
        """raw/dark frames (exposure_time, frame, y, x) of one chunk."""
        self._check_tiles(rows, cols)
        cam = self.spectral_camera
        off, dc = self.dark_pattern(rows, cols)
        zero = np.zeros(off.shape)
        out = np.empty(
            (times.stop - times.start, frames.stop - frames.start) + off.shape, dtype=np.uint16
        )
        for a, ti in enumerate(range(times.start, times.stop)):
            t = float(self.dark_times[ti])
            for b, f in enumerate(range(frames.start, frames.stop)):
                out[a, b] = self._capture(
                    zero,
                    rows,
                    cols,
                    (_STREAM_DARK, ti, f),
                    t=t,
                    response=cam.response,
                    offset=off + dc * t,
                    sigma=cam.noise_sigma,
                    bits=cam.bit_depth,
                )
        return out

    def truth_block(self, images: slice, wl: slice, rows: slice, cols: slice) -> np.ndarray:
        """truth/spectra radiance (image, wavelength, y, x) of one chunk."""
        return np.stack([self.radiance(i, rows, cols)[wl] for i in range(images.start, images.stop)])

    def _target_reflectance(self, target: str, rows: slice, cols: slice, shift=(0.0, 0.0)) -> np.ndarray:
        if target == "white":
            return np.full(
                (self.wavelength.size, rows.stop - rows.start, cols.stop - cols.start),
                0.98,
                dtype=np.float32,
            )
        return self.chart.diffuse_reflectance(self.chart.patch_index(rows, cols, shift=shift))

    def calibration_rgb_block(
        self, target: str, exposures: slice, rows: slice, cols: slice, channels: slice
    ) -> np.ndarray:
        """rgb_counts (rgb_exposure, y, x, channel) of a calibration target (lit from 0 deg)."""
        self._check_tiles(rows, cols)
        cam = self.rgb_camera
        stream = _STREAM_WHITE_RGB if target == "white" else _STREAM_CC_RGB
        x = np.tensordot(self.rgb_weights, self._target_reflectance(target, rows, cols), 1)
        out = np.empty(
            (
                exposures.stop - exposures.start,
                rows.stop - rows.start,
                cols.stop - cols.start,
                channels.stop - channels.start,
            ),
            np.uint16,
        )
        for b, e in enumerate(range(exposures.start, exposures.stop)):
            for c, ch in enumerate(range(channels.start, channels.stop)):
                out[b, :, :, c] = self._capture(
                    x[ch],
                    rows,
                    cols,
                    (stream, e, ch),
                    t=float(self.calib_rgb_times[e]),
                    response=cam.responses["RGB"[ch]],
                    offset=cam.adc_offset,
                    sigma=cam.noise_sigma,
                    bits=cam.bit_depth,
                )
        return out

    def calibration_spectral_block(
        self, target: str, bands: slice, exposures: slice, rows: slice, cols: slice
    ) -> np.ndarray:
        """spectral_counts (wavelength, spectral_exposure, y, x) of a calibration target."""
        self._check_tiles(rows, cols)
        cam = self.spectral_camera
        stream = _STREAM_WHITE_SPEC if target == "white" else _STREAM_CC_SPEC
        refl = self._target_reflectance(target, rows, cols, shift=self.recipe.misregistration)
        x = np.tensordot(self.band_weights, refl, 1)
        off, dc = self.dark_pattern(rows, cols)
        out = np.empty(
            (
                bands.stop - bands.start,
                exposures.stop - exposures.start,
                rows.stop - rows.start,
                cols.stop - cols.start,
            ),
            np.uint16,
        )
        for a, j in enumerate(range(bands.start, bands.stop)):
            for b, e in enumerate(range(exposures.start, exposures.stop)):
                t = float(self.calib_spectral_times[e])
                out[a, b] = self._capture(
                    x[j],
                    rows,
                    cols,
                    (stream, j, e),
                    t=t,
                    response=cam.response,
                    q=float(self.q[j]),
                    offset=off + dc * t,
                    sigma=cam.noise_sigma,
                    bits=cam.bit_depth,
                )
        return out

    def _dome(self, rows: slice, cols: slice, shift=(0.0, 0.0)) -> np.ndarray:
        """Diffuse-dome (many LEDs on) shading factor (1 + n_z) / 2."""
        return 0.5 * (1.0 + self.texture.evaluate(rows, cols, shift=shift).normal[2])

    def registration_rgb_block(
        self, rots: slice, rows: slice, cols: slice, channels: slice
    ) -> np.ndarray:
        self._check_tiles(rows, cols)
        cam = self.rgb_camera
        x = self._diffuse_rgb(rows, cols) * self._dome(rows, cols)[None]
        out = np.empty(
            (
                rots.stop - rots.start,
                rows.stop - rows.start,
                cols.stop - cols.start,
                channels.stop - channels.start,
            ),
            np.uint16,
        )
        for a, rr in enumerate(range(rots.start, rots.stop)):
            for c, ch in enumerate(range(channels.start, channels.stop)):
                out[a, :, :, c] = self._capture(
                    x[ch],
                    rows,
                    cols,
                    (_STREAM_REG_RGB, rr, ch),
                    t=float(self.registration_rgb_time),
                    response=cam.responses["RGB"[ch]],
                    offset=cam.adc_offset,
                    sigma=cam.noise_sigma,
                    bits=cam.bit_depth,
                )
        return out

    def registration_spectral_block(self, rots: slice, rows: slice, cols: slice) -> np.ndarray:
        self._check_tiles(rows, cols)
        cam, j = self.spectral_camera, self.registration_band
        shift = self.recipe.misregistration
        x = self._diffuse_bands(rows, cols)[j] * self._dome(rows, cols, shift)
        off, dc = self.dark_pattern(rows, cols)
        t = float(self.registration_spectral_time)
        out = np.empty(
            (rots.stop - rots.start, rows.stop - rows.start, cols.stop - cols.start), np.uint16
        )
        for a, rr in enumerate(range(rots.start, rots.stop)):
            out[a] = self._capture(
                x,
                rows,
                cols,
                (_STREAM_REG_SPEC, rr),
                t=t,
                response=cam.response,
                q=float(self.q[j]),
                offset=off + dc * t,
                sigma=cam.noise_sigma,
                bits=cam.bit_depth,
            )
        return out

    def pattern_block(self, which: int, rows: slice, cols: slice) -> np.ndarray:
        return self.dark_pattern(rows, cols)[which].astype(np.float32)

    # -- lazy arrays -------------------------------------------------------------------
    @cached_property
    def spatial_chunk(self) -> int:
        r = self.recipe
        if r.chunk_size is not None:
            return min(r.chunk_size, r.size)
        c = min(r.size, 512)
        return c if c >= r.size or c % r.noise_tile == 0 else r.noise_tile

    def lazy(
        self,
        kind: str,
        shape: tuple[int, ...],
        chunks: tuple[int, ...],
        dtype,
        block: Callable[..., np.ndarray],
        *args,
    ) -> da.Array:
        """A dask array whose chunks are computed by ``block(*args, *slices)``."""
        chunks_n = normalize_chunks(chunks, shape)
        name = f"simulate-{kind}-{self.recipe.fingerprint()}"
        starts = [np.concatenate([[0], np.cumsum(c)]).tolist() for c in chunks_n]

        def _block(block_id=None):
            loc = (slice(s[i], s[i + 1]) for s, i in zip(starts, block_id, strict=True))
            return block(*args, *loc)

        # block_id (not block_info): dask then builds no per-block dict, so a graph of a
        # million chunks is made in milliseconds
        return da.map_blocks(
            _block,
            chunks=chunks_n,
            dtype=dtype,
            name=name,
            meta=np.empty((0,) * len(shape), dtype=dtype),
        )

    # -- groups ------------------------------------------------------------------------
    def groups(self) -> dict[str, xr.Dataset]:
        """The whole run as lazy Datasets keyed by group name (see :data:`GROUPS`)."""
        return {
            "raw/dark": self._dark_group(),
            "raw/rgb": self._rgb_group(),
            "raw/spectral": self._spectral_group(),
            "raw/exposure_plan": self._plan_group(),
            "raw/white_reference": self._calibration_group("white"),
            "raw/colour_checker": self._calibration_group("colour_checker"),
            "raw/registration": self._registration_group(),
            "truth/spectra": self._truth_group(),
            "truth/camera": self._camera_group(),
        }

    def _attrs(self, group: str) -> dict:
        r = self.recipe
        return {
            "title": GROUPS[group],
            "recipe": r.name,
            "seed": r.seed,
            "source": "spectralize.nodes.simulation.gantry (simulated capture, paper eq. 2, 3, 5)",
            "recipe_fingerprint": r.fingerprint(),
        }

    @staticmethod
    def _counts_attrs(bits: int, long_name: str) -> dict:
        return {"units": "DN", "long_name": long_name, "bit_depth": int(bits)}

    def _image_coords(self, dim: str = "image", im: _Images | None = None) -> dict:
        im = self.images if im is None else im
        return {
            "camera": (
                dim,
                im.camera.astype(np.int64),
                {"units": "1", "long_name": "RGB camera index (polar angle in theta_o)"},
            ),
            "rotation": (
                dim,
                im.rotation.astype(np.int64),
                {
                    "units": "1",
                    "long_name": "rotation stage position index "
                    f"({self.recipe.rotation_step:g} deg steps)",
                },
            ),
            "led": (
                dim,
                im.led.astype(np.int64),
                {"units": "1", "long_name": "index of the LED in the gantry layout"},
            ),
            "theta_i": (
                dim,
                im.theta_i,
                {"units": "degree", "long_name": "polar angle of the light direction (sample frame)"},
            ),
            "phi_i": (
                dim,
                im.phi_i,
                {"units": "degree", "long_name": "azimuth of the light direction (sample frame)"},
            ),
            "theta_o": (
                dim,
                im.theta_o,
                {"units": "degree", "long_name": "polar angle of the view direction (sample frame)"},
            ),
            "phi_o": (
                dim,
                im.phi_o,
                {"units": "degree", "long_name": "azimuth of the view direction (sample frame)"},
            ),
        }

    def _yx(self) -> tuple[int, int]:
        return self.recipe.size, self.spatial_chunk

    def _rgb_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        n_img, n_exp = len(self.images), len(r.rgb_exposure_times)
        counts = self.lazy(
            "rgb",
            (n_img, n_exp, n, n, 3),
            (r.frames_per_chunk, n_exp, c, c, 3),
            np.uint16,
            self.rgb_block,
        )
        coords = self._image_coords()
        coords["image"] = ("image", np.arange(n_img), {"units": "1", "long_name": "image index"})
        coords["channel"] = ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"})
        coords["exposure_time"] = (
            ("image", "exposure"),
            np.broadcast_to(np.asarray(r.rgb_exposure_times), (n_img, n_exp)).copy(),
            {"units": "s", "long_name": "exposure time"},
        )
        return xr.Dataset(
            {
                "counts": (
                    ("image", "exposure", "y", "x", "channel"),
                    counts,
                    self._counts_attrs(r.rgb_bit_depth, "raw RGB counts"),
                )
            },
            coords=coords,
            attrs=self._attrs("raw/rgb") | {"bit_depth": r.rgb_bit_depth, "camera": "rgb"},
        )

    def _spectral_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        sh = self.shots
        counts = self.lazy(
            "spectral", (len(sh), n, n), (r.frames_per_chunk, c, c), np.uint16, self.spectral_block
        )
        im = _Images(
            camera=np.full(len(sh), -1),
            rotation=sh.rotation,
            led=sh.led,
            theta_i=sh.theta_i,
            phi_i=sh.phi_i,
            theta_o=sh.theta_o,
            phi_o=sh.phi_o,
        )
        coords = self._image_coords("shot", im)
        del coords["camera"]
        coords.update(
            {
                "shot": ("shot", np.arange(len(sh)), {"units": "1", "long_name": "shot index"}),
                "wavelength": (
                    "shot",
                    self.wavelength[sh.band],
                    {"units": "nm", "long_name": "centre wavelength of the filter band"},
                ),
                "exposure_time": (
                    "shot",
                    self.band_time[sh.band],
                    {"units": "s", "long_name": "exposure time (eq. 2, quantised)"},
                ),
                "filter_size": (
                    "shot",
                    self.plan["filter_size"].values[sh.band],
                    {"units": "px", "long_name": "Gaussian filter size s_i (eq. 3)"},
                ),
                "image": (
                    "shot",
                    sh.image,
                    {"units": "1", "long_name": "index of the raw/rgb image this shot pairs with"},
                ),
                "led_set": (
                    "shot",
                    sh.led_set,
                    {
                        "units": "1",
                        "long_name": "index of the set of LED positions the bands are spread over",
                    },
                ),
            }
        )
        attrs = self._attrs("raw/spectral")
        attrs.update(
            bit_depth=r.spectral_bit_depth,
            camera="spectral",
            spectral_mode=r.spectral_mode,
            spectral_set_size=r.spectral_set_size,
            misregistration_note="content is shifted relative to raw/rgb; see raw/registration",
        )
        return xr.Dataset(
            {
                "counts": (
                    ("shot", "y", "x"),
                    counts,
                    self._counts_attrs(r.spectral_bit_depth, "raw band counts"),
                )
            },
            coords=coords,
            attrs=attrs,
        )

    def _dark_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        nt = self.dark_times.size
        frames = self.lazy(
            "dark",
            (nt, r.n_dark_frames, n, n),
            (1, r.frames_per_chunk, c, c),
            np.uint16,
            self.dark_block,
        )
        return xr.Dataset(
            {
                "frames": (
                    ("exposure_time", "frame", "y", "x"),
                    frames,
                    self._counts_attrs(
                        r.spectral_bit_depth, "raw dark frames of the spectral camera (closed shutter)"
                    ),
                )
            },
            coords={
                "exposure_time": (
                    "exposure_time",
                    self.dark_times,
                    {"units": "s", "long_name": "exposure time"},
                )
            },
            attrs=self._attrs("raw/dark") | {"camera": "spectral", "bit_depth": r.spectral_bit_depth},
        )

    def _plan_group(self) -> xr.Dataset:
        ds = self.plan.copy()
        ds["exposure_time_quantised"] = (
            "wavelength",
            self.band_time,
            {"units": "s", "long_name": "exposure time used (quantised to the shutter step)"},
        )
        ds["band_illuminant"] = (
            "wavelength",
            self.band_illuminant,
            {"units": "1", "long_name": "illuminant seen through each filter band"},
        )
        ds["reference_exposure_time"] = (
            "wavelength",
            self.reference["exposure_time"].values,
            {"units": "s", "long_name": "long-exposure reference plan (omega = 1)"},
        )
        ds["reference_capture_time"] = (
            (),
            float(self.reference["exposure_time"].sum()),
            {"units": "s", "long_name": "total time of one reference set of bands"},
        )
        ds.attrs = ds.attrs | self._attrs("raw/exposure_plan")
        ds["wavelength"].attrs["long_name"] = "centre wavelength of the filter band"
        return ds

    def _calibration_group(self, target: str) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        ne, ns, nw = self.calib_rgb_times.size, self.calib_spectral_times.size, self.wavelength.size
        rgb = self.lazy(
            f"{target}-rgb", (ne, n, n, 3), (ne, c, c, 3), np.uint16, self.calibration_rgb_block, target
        )
        spec = self.lazy(
            f"{target}-spectral",
            (nw, ns, n, n),
            (max(1, r.frames_per_chunk // ns), ns, c, c),
            np.uint16,
            self.calibration_spectral_block,
            target,
        )
        group = "raw/white_reference" if target == "white" else "raw/colour_checker"
        ds = xr.Dataset(
            {
                "rgb_counts": (
                    ("rgb_exposure", "y", "x", "channel"),
                    rgb,
                    self._counts_attrs(
                        r.rgb_bit_depth,
                        f"raw RGB counts of the RGB camera at {r.spectral_camera_theta:g} deg",
                    ),
                ),
                "spectral_counts": (
                    ("wavelength", "spectral_exposure", "y", "x"),
                    spec,
                    self._counts_attrs(r.spectral_bit_depth, "raw band counts of the spectral camera"),
                ),
            },
            coords={
                "wavelength": (
                    "wavelength",
                    self.wavelength,
                    {"units": "nm", "long_name": "centre wavelength of the filter band"},
                ),
                "channel": ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"}),
                "rgb_exposure_time": (
                    "rgb_exposure",
                    self.calib_rgb_times,
                    {"units": "s", "long_name": "exposure time of the RGB series"},
                ),
                "spectral_exposure_time": (
                    "spectral_exposure",
                    self.calib_spectral_times,
                    {"units": "s", "long_name": "exposure time of the spectral series"},
                ),
            },
            attrs=self._attrs(group)
            | {
                "illumination": "one LED at theta_i = 0 deg (Lambertian target)",
                "rgb_bit_depth": r.rgb_bit_depth,
                "spectral_bit_depth": r.spectral_bit_depth,
                "rgb_camera": self.paired_camera,
                "theta_o": r.spectral_camera_theta,
            },
        )
        ds["illuminant"] = (
            "wavelength",
            self.illuminant.values,
            {"units": "1", "long_name": "measured relative spectral radiance of the LEDs"},
        )
        if target == "white":
            ds["target_reflectance"] = (
                "wavelength",
                np.full(nw, 0.98),
                {"units": "1", "long_name": "certified reflectance of the white target"},
            )
        else:
            refl = self.chart.reflectances()
            ds["patch_reflectance"] = (
                ("patch", "wavelength"),
                refl.values,
                {"units": "1", "long_name": "published reflectance of the chart patches"},
            )
            ds = ds.assign_coords(
                patch=(
                    "patch",
                    refl["patch"].values,
                    {"units": "1", "long_name": "patch index (row-major, 4 x 6)"},
                ),
                patch_name=("patch", _strings(refl["patch_name"].values)),
            )
            ds["patch_index"] = (
                ("y", "x"),
                self.chart.patch_index(slice(0, n), slice(0, n)),
                {
                    "units": "1",
                    "long_name": "patch under each pixel of the "
                    "RGB image (-1: frame); the spectral image is shifted",
                },
            )
            ds.attrs["chart"] = self.chart.chart
        return ds

    def _registration_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        nr = r.n_rotations
        rgb = self.lazy(
            "reg-rgb",
            (nr, n, n, 3),
            (r.frames_per_chunk, c, c, 3),
            np.uint16,
            self.registration_rgb_block,
        )
        spec = self.lazy(
            "reg-spectral",
            (nr, n, n),
            (r.frames_per_chunk, c, c),
            np.uint16,
            self.registration_spectral_block,
        )
        return xr.Dataset(
            {
                "rgb_counts": (
                    ("rotation", "y", "x", "channel"),
                    rgb,
                    self._counts_attrs(
                        r.rgb_bit_depth, f"RGB camera at {r.spectral_camera_theta:g} deg"
                    ),
                ),
                "spectral_counts": (
                    ("rotation", "y", "x"),
                    spec,
                    self._counts_attrs(r.spectral_bit_depth, "spectral camera"),
                ),
            },
            coords={
                "rotation": (
                    "rotation",
                    np.arange(nr),
                    {"units": "1", "long_name": "rotation stage position index"},
                ),
                "rotation_angle": (
                    "rotation",
                    self.rotation_angle,
                    {"units": "degree", "long_name": "rotation of the sample"},
                ),
                "channel": ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"}),
                "rgb_exposure_time": (
                    (),
                    float(self.registration_rgb_time),
                    {"units": "s", "long_name": "exposure time of the RGB shots"},
                ),
                "spectral_exposure_time": (
                    (),
                    float(self.registration_spectral_time),
                    {"units": "s", "long_name": "exposure time of the spectral shots"},
                ),
                "spectral_wavelength": (
                    (),
                    float(self.wavelength[self.registration_band]),
                    {"units": "nm", "long_name": "filter band of the spectral shots"},
                ),
            },
            attrs=self._attrs("raw/registration")
            | {
                "illumination": "many LEDs on (diffuse dome)",
                "rgb_camera": self.paired_camera,
                "rgb_bit_depth": r.rgb_bit_depth,
                "spectral_bit_depth": r.spectral_bit_depth,
                "pairing": "spectral_counts at rotation r + 1 shows what rgb_counts at "
                "rotation r shows, up to the misregistration",
            },
        )

    def _truth_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        nw = self.wavelength.size
        rad = self.lazy(
            "truth",
            (len(self.images), nw, n, n),
            (max(1, r.frames_per_chunk // 4), nw, c, c),
            np.float32,
            self.truth_block,
        )
        coords = self._image_coords()
        coords["image"] = (
            "image",
            np.arange(len(self.images)),
            {"units": "1", "long_name": "image index (as raw/rgb)"},
        )
        coords["wavelength"] = (
            "wavelength",
            self.wavelength,
            {"units": "nm", "long_name": "wavelength"},
        )
        ds = xr.Dataset(
            {
                "radiance": (
                    ("image", "wavelength", "y", "x"),
                    rad,
                    {"units": "1", "long_name": "true spectral radiance (relative)"},
                )
            },
            coords=coords,
            attrs=self._attrs("truth/spectra") | {"materials": ", ".join(self.texture.material_names)},
        )
        tile = self.texture.evaluate(slice(0, n), slice(0, n)) if n <= 1024 else None
        if tile is not None:
            ds["material"] = (
                ("y", "x"),
                tile.material,
                {"units": "1", "long_name": "index of the dominant material"},
            )
        return ds

    def _camera_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        bits = max(r.rgb_bit_depth, r.spectral_bit_depth)
        codes = np.arange(2**bits)
        table = np.full((4, codes.size), np.nan)
        for k, ch in enumerate("RGB"):
            t = oecf_table(self.rgb_camera.responses[ch], bit_depth=r.rgb_bit_depth)
            table[k, : t.size] = t
        t = oecf_table(self.spectral_camera.response, bit_depth=r.spectral_bit_depth)
        table[3, : t.size] = t
        sensor = _strings(["R", "G", "B", "mono"])
        per = {
            "adc_offset": [r.rgb_adc_offset] * 3 + [r.spectral_adc_offset],
            "noise_sigma": [r.rgb_noise_sigma] * 3 + [r.spectral_noise_sigma],
            "bit_depth": [r.rgb_bit_depth] * 3 + [r.spectral_bit_depth],
        }
        offset = self.lazy("offset", (n, n), (c, c), np.float32, self.pattern_block, 0)
        dcur = self.lazy("dark-current", (n, n), (c, c), np.float32, self.pattern_block, 1)
        responses = {
            ch: {"model": s.model, **s.parameters} for ch, s in zip("RGB", r.rgb_responses, strict=True)
        }
        responses["mono"] = {"model": r.spectral_response.model, **r.spectral_response.parameters}
        return xr.Dataset(
            {
                "camera_matrix": self.rgb_camera.camera_matrix.drop_vars(
                    ["wavelength", "channel"]
                ).variable,
                "quantum_efficiency": (
                    "wavelength",
                    self.q,
                    {
                        "units": "s-1",
                        "long_name": "quantum efficiency Q of the spectral camera system per band",
                    },
                ),
                "illuminant": (
                    "wavelength",
                    self.illuminant.values,
                    {"units": "1", "long_name": "relative spectral radiance L of the LEDs"},
                ),
                "bandpass": (
                    ("band", "wavelength"),
                    self.bandpass,
                    {"units": "1", "long_name": "tunable filter bandpass weights"},
                ),
                "oecf": (
                    ("sensor", "code"),
                    table,
                    {
                        "units": "1",
                        "long_name": "true OECF tabulated per code: normalised "
                        "exposure x t Q whose noiseless, offset-free output is the code "
                        "(f in eq. 5; Robertson's I_m); NaN beyond the bit depth",
                    },
                ),
                "adc_offset": (
                    "sensor",
                    np.asarray(per["adc_offset"], float),
                    {"units": "DN", "long_name": "mean ADC offset Delta_ADC"},
                ),
                "noise_sigma": (
                    "sensor",
                    np.asarray(per["noise_sigma"], float),
                    {"units": "DN", "long_name": "standard deviation of N_sigma"},
                ),
                "bit_depth": (
                    "sensor",
                    np.asarray(per["bit_depth"], np.int64),
                    {"units": "1", "long_name": "ADC bit depth"},
                ),
                "spectral_adc_offset": (
                    ("y", "x"),
                    offset,
                    {"units": "DN", "long_name": "ADC offset of each spectral camera pixel"},
                ),
                "spectral_dark_current": (
                    ("y", "x"),
                    dcur,
                    {"units": "DN s-1", "long_name": "dark signal rate of each spectral camera pixel"},
                ),
                "misregistration": (
                    "axis",
                    np.asarray(r.misregistration, float),
                    {
                        "units": "px",
                        "long_name": "shift of the spectral image content "
                        "relative to the paired RGB image: spectral(p) = rgb(p - shift)",
                    },
                ),
            },
            coords={
                "channel": ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"}),
                "wavelength": (
                    "wavelength",
                    self.wavelength,
                    {"units": "nm", "long_name": "wavelength"},
                ),
                "band": (
                    "band",
                    self.wavelength,
                    {"units": "nm", "long_name": "centre wavelength of the filter band"},
                ),
                "sensor": ("sensor", sensor, {"long_name": "RGB channel or monochrome"}),
                "code": ("code", codes, {"units": "DN", "long_name": "code value"}),
                "axis": ("axis", _strings(["y", "x"]), {"long_name": "image axis"}),
            },
            attrs=self._attrs("truth/camera")
            | {
                "responses": json.dumps(responses),
                "noise": r.noise,
                "full_well": r.full_well,
                "bandpass_fwhm_nm": r.bandpass_fwhm,
            },
        )


def simulate_run(recipe: GantryRecipe) -> dict[str, xr.Dataset]:
    """Simulate a complete raw run of the gantry: ``{group: Dataset}``, dask-backed.

    Parameters
    ----------
    recipe
        Sizes, geometry, cameras, noise and plan; see :class:`GantryRecipe` and the named
        recipes in ``spectralize.nodes.simulation.recipes``.

    Returns
    -------
    dict of str to xarray.Dataset
        The groups of :data:`GROUPS`; variables are lazy (dask) except small tables.
        ``ds.load()`` or writing to zarr computes them chunk by chunk.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 4 (gantry) and 5 (simulation, eq. 5).
    """
    if not isinstance(recipe, GantryRecipe):
        raise SimulationParameterError(
            f"recipe must be a GantryRecipe; received {type(recipe).__name__}. Use "
            "spectralize.nodes.simulation.recipes.get_recipe(name) for a named one."
        )
    return Gantry(recipe).groups()
