"""The physics of the simulated gantry: what each camera sees and the counts it records.

One :class:`Renderer` per recipe holds the scene (the spectral texture of
:mod:`~spectralize.nodes.simulation.ground_truth`, a white target, a ColorChecker chart and
the LED illuminant) and both cameras of
:mod:`~spectralize.nodes.simulation.camera_model`.  A raw counts array of any group is
described by one :class:`Capture` (which camera, which scene, which frames, how long each
is exposed) and rendered chunk by chunk by :meth:`Renderer.counts`:

1. the irradiance ``x`` of each channel (RGB: ``C L``-weighted reflectance) or band (spectral
   camera: bandpass ``B L``-weighted reflectance) on the chunk, with the sample's shading and
   its specular lobe in the illuminant's colour, or the calibration target lit from 0 deg, or
   the diffuse dome of the registration shots, or nothing (dark frames);
2. eq. 5, ``I = floor(f^-1(x t Q) + Delta_ADC + N_sigma)``, with the spectral camera's
   per-pixel offset and dark current (a fixed pattern) in ``Delta_ADC``.

The spectral camera sees the content shifted by the recipe's ``misregistration``.  Noise is
drawn per frame and per fixed ``noise_tile`` from ``numpy.random.SeedSequence(seed,
spawn_key=(stream, *frame, [channel], tile_y, tile_x))``, so a chunk's values do not depend on
chunking or scheduling, and each capture has its own stream (:data:`STREAMS`).

References
----------
Fast Capture of Spectral Image Series, sec. 4 and 5 (eq. 5).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np

from spectralize.nodes.simulation.camera_model import (
    RGBCamera,
    SimulationParameterError,
    SpectralCamera,
    camera_sensitivities,
    capture_with_generator,
    gaussian_bandpass,
    spectral_quantum_efficiency,
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
from spectralize.nodes.simulation.recipes import GantryRecipe
from spectralize.nodes.simulation.schedule import Images, Shots

__all__ = ["STREAMS", "PATTERN_STREAM", "Capture", "Renderer"]

Sensor = Literal["rgb", "spectral"]
Scene = Literal["sample", "white", "colour_checker", "dome", "dark"]

#: Noise stream of each (scene, sensor) capture: ``spawn_key[0]`` of its seed sequence.
#: Never reuse an id for another purpose: the values of a run depend on them.
STREAMS: dict[tuple[Scene, Sensor], int] = {
    ("sample", "rgb"): 1,
    ("sample", "spectral"): 2,
    ("dark", "spectral"): 3,
    ("white", "rgb"): 5,
    ("white", "spectral"): 6,
    ("colour_checker", "rgb"): 7,
    ("colour_checker", "spectral"): 8,
    ("dome", "rgb"): 9,
    ("dome", "spectral"): 10,
}
#: Noise stream of the spectral camera's fixed pattern (offset and dark current).
PATTERN_STREAM = 4


@dataclass(frozen=True, eq=False)
class Capture:
    """What one raw counts array shows, frame by frame: everything :meth:`Renderer.counts` needs.

    A counts array has frame axes, then ``y, x`` and, for the RGB camera, ``channel``.  The
    scene is fixed along every frame axis but the first (the later axes are exposures or
    repeated frames), so the renderer computes one irradiance per first-axis frame.

    Attributes
    ----------
    sensor
        ``"rgb"`` (channels R, G, B) or ``"spectral"`` (one band per frame).
    scene
        ``"sample"``: the texture under one LED, at the angles of ``light``; ``"white"`` or
        ``"colour_checker"``: a calibration target lit from 0 deg; ``"dome"``: the texture
        under many LEDs (registration shots); ``"dark"``: closed shutter.
    exposure_time
        ``t`` [s] of every frame, shape of the frame axes (a broadcast view is fine).
    band
        Spectral camera: band index of each first-axis frame; ``None`` for the RGB camera and
        dark frames (``Q = 1``).
    light
        ``"sample"`` only: the images or shots whose BTF angles light the first-axis frames.
    """

    sensor: Sensor
    scene: Scene
    exposure_time: np.ndarray
    band: np.ndarray | None = None
    light: Images | Shots | None = None

    @property
    def stream(self) -> int:
        """Noise stream id of this capture (:data:`STREAMS`)."""
        return STREAMS[(self.scene, self.sensor)]


@dataclass(frozen=True, eq=False)
class _Optics:
    """How one camera sees the scene: channel weights, illuminant per channel, content shift."""

    weights: np.ndarray  # (channel or band, wavelength): sensitivity x illuminant, float32
    white: np.ndarray  # (channel or band,): the illuminant seen through each (specular term)
    shift: tuple[float, float]  # (dy, dx) px of the image content


class Renderer:
    """The scene and cameras of one recipe; renders chunks of radiance and raw counts.

    Parameters
    ----------
    recipe
        The run: spectra, texture, cameras, noise and ``misregistration``.

    Notes
    -----
    The RGB camera matrix is scaled so that a white diffuse target at normal incidence
    saturates at ``recipe.rgb_saturation_time``.  Chunks must be aligned to ``noise_tile``.
    """

    def __init__(self, recipe: GantryRecipe) -> None:
        self.recipe = r = recipe
        self._pattern_cache: dict = {}  # per-tile fixed pattern (cleared when pickled)
        self.wavelength = wavelength_grid(r.wavelength_start, r.wavelength_stop, r.wavelength_step)
        self.illuminant = illuminant_spd(self.wavelength, name=r.illuminant)
        self.texture: SpectralTexture = spectral_texture(
            r.size, wavelength=self.wavelength, seed=r.seed, n_materials=r.n_materials
        )
        self.chart = ColourCheckerChart(r.size, self.wavelength)
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
        self.band_illuminant = self.bandpass @ ell  # L_i seen through band i
        self.q = self.spectral_camera.quantum_efficiency.values
        rgb_weights = (cm.values * ell[None, :]).astype(np.float32)  # (3, n)
        self.optics = {
            "rgb": _Optics(rgb_weights, rgb_weights.sum(axis=1), (0.0, 0.0)),
            "spectral": _Optics(
                (self.bandpass * ell[None, :]).astype(np.float32),  # (n, n)
                self.band_illuminant,
                r.misregistration,
            ),
        }

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_pattern_cache"] = {}
        return state

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
        q: float,
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
        """Fixed pattern of the spectral camera: (ADC offset [DN], dark current [DN/s]).

        Drawn per whole noise tile (clipped to the image), so it does not depend on chunking.
        """
        r = self.recipe
        key = (rows.start, rows.stop, cols.start, cols.stop)
        hit = self._pattern_cache.get(key)
        if hit is not None:
            return hit
        h, w = rows.stop - rows.start, cols.stop - cols.start
        off = np.empty((h, w))
        dc = np.empty((h, w))
        for ty, tx, ry, rx in self._tiles(rows, cols):
            g = self.rng(PATTERN_STREAM, ty, tx)
            t = r.noise_tile
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

    def pattern(self, which: int, rows: slice, cols: slice) -> np.ndarray:
        """One chunk of the fixed pattern: ``which`` 0 the offset [DN], 1 the dark current [DN/s]."""
        return self.dark_pattern(rows, cols)[which].astype(np.float32)

    # -- the scene ---------------------------------------------------------------------
    def _diffuse(self, sensor: Sensor, rows: slice, cols: slice) -> np.ndarray:
        """Texture reflectance seen through each channel or band (cached per chunk)."""
        optics = self.optics[sensor]
        key = (sensor, rows.start, rows.stop, cols.start, cols.stop)
        hit = self.texture._cache.get(key)
        if hit is None:
            tile = self.texture.evaluate(rows, cols, shift=optics.shift)
            hit = self.texture.remember(
                key, np.tensordot(optics.weights, self.texture.diffuse_reflectance(tile), 1)
            )
        return hit

    def _shade(self, rows: slice, cols: slice, ti, pi, to, po, shift=(0.0, 0.0)):
        """Diffuse and specular factors (d, s) of the texture lit from (ti, pi), seen from (to, po)."""
        tile = self.texture.evaluate(rows, cols, shift=shift)
        return shading(
            tile.normal,
            direction(ti, pi),
            direction(to, po),
            specular_albedo=tile.specular_albedo,
            shininess=tile.shininess,
        )

    def _target_reflectance(self, target: str, rows: slice, cols: slice, shift) -> np.ndarray:
        """Reflectance (wavelength, h, w) of the white target (0.98) or the ColorChecker."""
        if target == "white":
            return np.full(
                (self.wavelength.size, rows.stop - rows.start, cols.stop - cols.start),
                0.98,
                dtype=np.float32,
            )
        return self.chart.diffuse_reflectance(self.chart.patch_index(rows, cols, shift=shift))

    def _dome(self, rows: slice, cols: slice, shift) -> np.ndarray:
        """Diffuse-dome (many LEDs on) shading factor (1 + n_z) / 2."""
        return 0.5 * (1.0 + self.texture.evaluate(rows, cols, shift=shift).normal[2])

    def irradiance(
        self, capture: Capture, frames: slice, rows: slice, cols: slice
    ) -> Iterator[np.ndarray]:
        """Noiseless irradiance ``x`` of each first-axis frame in ``frames`` on a chunk.

        Yields (channel, h, w) for the RGB camera, (h, w) of the frame's band for the spectral
        camera: the reflectance weighted by the channel's or band's sensitivity and the
        illuminant, times the shading, plus the specular lobe in the illuminant's colour.
        """
        optics = self.optics[capture.sensor]
        n = frames.stop - frames.start

        def channels(i: int):
            return slice(None) if capture.band is None else int(capture.band[i])

        if capture.scene == "dark":
            yield from itertools.repeat(np.zeros((rows.stop - rows.start, cols.stop - cols.start)), n)
        elif capture.scene == "sample":
            diffuse, lit = self._diffuse(capture.sensor, rows, cols), capture.light
            for i in range(frames.start, frames.stop):
                d, s = self._shade(
                    rows, cols, lit.theta_i[i], lit.phi_i[i], lit.theta_o[i], lit.phi_o[i], optics.shift
                )
                c = channels(i)
                yield diffuse[c] * d + np.asarray(optics.white[c])[..., None, None] * s
        elif capture.scene == "dome":
            diffuse, dome = (
                self._diffuse(capture.sensor, rows, cols),
                self._dome(rows, cols, optics.shift),
            )
            for i in range(frames.start, frames.stop):
                yield diffuse[channels(i)] * dome
        else:
            refl = self._target_reflectance(capture.scene, rows, cols, optics.shift)
            x = np.tensordot(optics.weights, refl, 1)
            for i in range(frames.start, frames.stop):
                yield x[channels(i)]

    # -- chunks ------------------------------------------------------------------------
    def counts(self, capture: Capture, *slices: slice) -> np.ndarray:
        """One chunk of raw counts [DN] (uint16) of ``capture`` (eq. 5): the block renderer.

        Parameters
        ----------
        capture
            What the counts array shows.
        *slices
            Absolute index ranges of the chunk: the frame axes, then ``y``, ``x`` and, for
            the RGB camera, ``channel``.

        Returns
        -------
        numpy.ndarray
            Counts of shape ``(*frames, h, w)`` or ``(*frames, h, w, channel)``.
        """
        rgb = capture.sensor == "rgb"
        *frames, rows, cols = slices[:-1] if rgb else slices
        self._check_tiles(rows, cols)
        if rgb:
            cam = self.rgb_camera
            responses = [cam.responses["RGB"[ch]] for ch in range(slices[-1].start, slices[-1].stop)]
            off, dc = cam.adc_offset, 0.0
        else:
            cam = self.spectral_camera
            responses = [cam.response]
            off, dc = self.dark_pattern(rows, cols)
        later = list(itertools.product(*(range(s.start, s.stop) for s in frames[1:])))
        out = np.empty(tuple(s.stop - s.start for s in slices), dtype=np.uint16)
        frame_x = zip(
            range(frames[0].start, frames[0].stop),
            self.irradiance(capture, frames[0], rows, cols),
            strict=True,
        )
        for i, x in frame_x:
            q = 1.0 if capture.band is None else float(self.q[int(capture.band[i])])
            for index in ((i, *rest) for rest in later):
                local = tuple(k - s.start for k, s in zip(index, frames, strict=True))
                t = capture.exposure_time[index]
                for c, response in enumerate(responses):
                    ch = slices[-1].start + c if rgb else None
                    out[(*local, ..., c) if rgb else local] = self._capture(
                        x[ch] if rgb else x,
                        rows,
                        cols,
                        (capture.stream, *index, ch) if rgb else (capture.stream, *index),
                        t=t,
                        response=response,
                        q=q,
                        offset=off + dc * t,
                        sigma=cam.noise_sigma,
                        bits=cam.bit_depth,
                    )
        return out

    def radiance(self, light: Images, images: slice, wl: slice, rows: slice, cols: slice) -> np.ndarray:
        """One chunk (image, wavelength, h, w) float32 of the true spectral radiance of RGB images.

        ``L (rho d + s)``: the illuminant times the diffuse reflectance shaded, plus the
        specular lobe, at each image's BTF angles (no misregistration: the RGB frame).
        """
        tile = self.texture.evaluate(rows, cols)
        ell = self.illuminant.values.astype(np.float32)[:, None, None]
        rho = self.texture.diffuse_reflectance(tile)
        out = []
        for i in range(images.start, images.stop):
            d, s = self._shade(
                rows, cols, light.theta_i[i], light.phi_i[i], light.theta_o[i], light.phi_o[i]
            )
            out.append((ell * (rho * d + s))[wl])
        return np.stack(out)
