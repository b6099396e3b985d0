"""The schedule of a simulated run: which images and shots the gantry takes, and for how long.

From a :class:`~spectralize.nodes.simulation.recipes.GantryRecipe` and the spectral camera's
quantum efficiency ``Q`` and band illuminant ``L`` (which set the exposure times), this module
derives every frame of the run, eagerly (all small tables):

- the RGB images: one per (rotation, switched LED, RGB camera), with the BTF angles in the
  sample's frame;
- the band shots of the spectral camera: the exposure plan of eq. 2 and 3 gives each band's
  time ``t_i = (t0 / (Q_i L_i))**omega`` and filter size ``s_i = s0 / (Q_i L_i t_i)``; in
  sparse mode the bands of one set are spread over a set of LED positions, in dense mode
  every LED gets all bands;
- the calibration series (white target, ColorChecker), the registration shots and the
  exposure times that need dark frames.

Pairing (paper sec. 4, "Spectral Integration"): the spectral camera sits one rotation step
further in azimuth than the RGB camera at its polar angle, so the shot at rotation ``r + 1``
with LED ``l'`` (one step further round ``l``'s ring) sees the sample under the same view and
light directions, in the sample's frame, as that RGB camera at rotation ``r`` with LED ``l``.
Each shot records the RGB image it pairs with.

References
----------
Fast Capture of Spectral Image Series, sec. 4 and eq. 2, 3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import xarray as xr

from spectralize.nodes.simulation.camera_model import SimulationParameterError
from spectralize.nodes.simulation.exposure_plan import (
    exposure_plan,
    reference_exposure_plan,
    t0_for_total_time,
)
from spectralize.nodes.simulation.recipes import GantryRecipe, led_positions

__all__ = ["Images", "Shots", "RunSchedule"]


@dataclass(frozen=True, eq=False)
class Images:
    """The RGB images of a run: one row per image, BTF angles [deg] in the sample's frame."""

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
class Shots:
    """The band shots of the spectral camera: one row per shot, angles [deg] as :class:`Images`.

    ``band`` indexes the wavelength grid, ``image`` the RGB image the shot pairs with and
    ``led_set`` the set of LED positions its set of bands is spread over.
    """

    band: np.ndarray
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


class RunSchedule:
    """Every frame of one simulated run and its exposure time, computed on construction.

    Parameters
    ----------
    recipe
        The run.
    wavelength
        Centre wavelengths of the filter bands [nm].
    quantum_efficiency
        ``Q_i`` of the spectral camera per band.
    band_illuminant
        ``L_i``: the illuminant seen through each band.

    Raises
    ------
    SimulationParameterError
        If the recipe gives the spectral camera nothing to shoot.

    Notes
    -----
    All times are quantised to the shutter step ``recipe.exposure_resolution``; the dark
    frames cover every time the spectral camera uses (bands, calibration, registration).
    """

    def __init__(
        self,
        recipe: GantryRecipe,
        *,
        wavelength: np.ndarray,
        quantum_efficiency: np.ndarray,
        band_illuminant: np.ndarray,
    ) -> None:
        r = self.recipe = recipe
        self.wavelength = wavelength
        self.q = quantum_efficiency
        self.band_illuminant = band_illuminant
        self.led_theta, self.led_phi = led_positions()
        self.leds = np.arange(self.led_theta.size) if r.leds is None else np.asarray(r.leds)
        self.cameras = np.asarray(r.rgb_camera_thetas, dtype=np.float64)
        self.paired_camera = int(np.flatnonzero(np.isclose(self.cameras, r.spectral_camera_theta))[0])
        self.rotation_angle = np.arange(r.n_rotations) * r.rotation_step
        self.images = self._image_table()
        self.plan = self._plan()
        self.band_time = self.quantise(self.plan["exposure_time"].values)
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
        self.registration_spectral_time = self.quantise(
            0.5 * r.reference_exposure / (self.q[reg_band] * self.band_illuminant[reg_band])
        )
        self.registration_rgb_time = self.quantise(0.5 * r.rgb_saturation_time)
        self.dark_times = np.unique(
            np.concatenate(
                [
                    self.band_time[np.unique(self.shots.band)],
                    self.calib_spectral_times,
                    [self.registration_spectral_time],
                ]
            )
        )

    def quantise(self, t: np.ndarray | float) -> np.ndarray:
        """Times [s] rounded to the shutter step, at least one step."""
        res = self.recipe.exposure_resolution
        return np.maximum(np.round(np.asarray(t, dtype=np.float64) / res), 1) * res

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

    def _image_table(self) -> Images:
        r = self.recipe
        rot, led, cam = np.meshgrid(
            np.arange(r.n_rotations), self.leds, np.arange(self.cameras.size), indexing="ij"
        )
        rot, led, cam = rot.ravel(), led.ravel(), cam.ravel()
        rho = self.rotation_angle[rot]
        return Images(
            camera=cam,
            rotation=rot,
            led=led,
            theta_i=self.led_theta[led],
            phi_i=(self.led_phi[led] - rho) % 360.0,
            theta_o=self.cameras[cam],
            phi_o=(0.0 - rho) % 360.0,
        )

    def _plan(self) -> xr.Dataset:
        """The exposure plan of eq. 2, 3, with ``t0`` from the recipe or its total time."""
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
        """Rotations with band shots: all on a full circle, else all but the first."""
        r = self.recipe
        full = math.isclose(r.n_rotations * r.rotation_step, 360.0)
        return list(range(r.n_rotations)) if full else list(range(1, r.n_rotations))

    def _shot_table(self) -> Shots:
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
        return Shots(
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
        Unequal ratios make the response identifiable from the series (Robertson).
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
        return np.unique(self.quantise(np.asarray(times)))

    def _calibration_spectral_times(self) -> np.ndarray:
        r = self.recipe
        t_ref = self.reference["exposure_time"].values
        lo, hi = t_ref.min() / r.calibration_exposure_span, t_ref.max()
        return self._irregular_series(lo, hi, cover=False)

    def _calibration_rgb_times(self) -> np.ndarray:
        r = self.recipe
        lo, hi = r.rgb_exposure_times[0] / 4.0, r.rgb_exposure_times[-1] * 4.0
        return self._irregular_series(lo, hi, cover=True)
