"""Assembly of a simulated gantry run: the run's groups from its recipe, schedule and renderer.

Geometry (paper sec. 4, "RGB Measurement Setup" and "Spectral Integration"):

- RGB cameras on an arc at azimuth 0 deg, polar angles 0..75 deg from the sample normal;
- LEDs on the hemisphere in rings of 24 (15 deg apart) plus a small top ring (198 in all);
- the sample on a rotation stage, rotated in 15 deg steps;
- the spectral camera (monochrome + tunable filter) at 45 deg with a 15 deg azimuth offset
  from the RGB camera at 45 deg, so each band shot pairs with one RGB image (see
  :mod:`~spectralize.nodes.simulation.schedule`); a small known misregistration (a sub-pixel
  shift) separates the two.

Images are rectified to the sample plane (as a BTF pipeline does after detecting the
sample holder), so all images share pixel coordinates except the spectral camera's shift.
What the run contains is the :class:`~spectralize.nodes.simulation.recipes.GantryRecipe`;
which frames it takes and for how long (eq. 2, 3) is the
:class:`~spectralize.nodes.simulation.schedule.RunSchedule`; the counts of every frame
(eq. 5) and the true radiance come from the
:class:`~spectralize.nodes.simulation.rendering.Renderer`.  This module puts them together
into ``{group: xarray.Dataset}`` with dask-backed variables: each counts variable is one
:class:`~spectralize.nodes.simulation.rendering.Capture` rendered chunk by chunk, so nothing is
computed until a chunk is asked for, and even the paper-scale run (2048 x 2048 px, 11
cameras, 198 LEDs, 24 rotations) has bounded memory.

The groups are :data:`GROUPS`; their contracts (dims, coords, units) are those of
:mod:`spectralize.schemas.run`, and their layout is documented in ``datasets/README.md``.

References
----------
Fast Capture of Spectral Image Series, sec. 4 and 5 (eq. 2, 3, 5).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from functools import cached_property

import dask.array as da
import numpy as np
import xarray as xr
from dask.array.core import normalize_chunks

from spectralize.nodes.simulation.camera_model import SimulationParameterError, oecf_table
from spectralize.nodes.simulation.recipes import GantryRecipe
from spectralize.nodes.simulation.rendering import Capture, Renderer
from spectralize.nodes.simulation.schedule import Images, RunSchedule

__all__ = ["GROUPS", "Gantry", "simulate_run"]

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


def _strings(values) -> np.ndarray:
    """Fixed-width unicode strings: they read back as ``<U`` (the contract's ``kind:U``).

    Object strings would be stored without zarr's UnstableSpecificationWarning but read
    back as numpy ``StringDType`` (kind ``T``), which the contract does not accept yet.
    """
    return np.array([str(v) for v in values], dtype=str)


class Gantry:
    """The simulated gantry of one recipe: its schedule, its renderer and the run's groups.

    Parameters
    ----------
    recipe
        The run.

    Attributes
    ----------
    recipe : GantryRecipe
    renderer : Renderer
        Scene and cameras; renders chunks of counts and radiance.
    schedule : RunSchedule
        Images, shots and exposure times.

    Notes
    -----
    :meth:`groups` returns the lazy run; its dask graphs call :meth:`Renderer.counts`,
    :meth:`Renderer.radiance` and :meth:`Renderer.pattern` with absolute index slices, and
    are named after the recipe's fingerprint, so equal recipes give equal keys.
    """

    def __init__(self, recipe: GantryRecipe) -> None:
        self.recipe = recipe
        self.renderer = Renderer(recipe)
        self.schedule = RunSchedule(
            recipe,
            wavelength=self.renderer.wavelength,
            quantum_efficiency=self.renderer.q,
            band_illuminant=self.renderer.band_illuminant,
        )

    # -- lazy arrays -------------------------------------------------------------------
    @cached_property
    def spatial_chunk(self) -> int:
        """Chunk size along ``y`` and ``x`` [px]: the recipe's, else the size up to 512 px."""
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

    def counts(
        self, kind: str, shape: tuple[int, ...], chunks: tuple[int, ...], capture: Capture
    ) -> da.Array:
        """Lazy uint16 counts of one capture, rendered chunk by chunk (eq. 5)."""
        return self.lazy(kind, shape, chunks, np.uint16, self.renderer.counts, capture)

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
            "source": "spectralize.nodes.simulation (simulated capture, paper eq. 2, 3, 5)",
            "recipe_fingerprint": r.fingerprint(),
        }

    @staticmethod
    def _counts_attrs(bits: int, long_name: str) -> dict:
        return {"units": "DN", "long_name": long_name, "bit_depth": int(bits)}

    def _image_coords(self, dim: str = "image", im: Images | None = None) -> dict:
        im = self.schedule.images if im is None else im
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
        n_img, n_exp = len(self.schedule.images), len(r.rgb_exposure_times)
        times = np.broadcast_to(np.asarray(r.rgb_exposure_times), (n_img, n_exp))
        counts = self.counts(
            "rgb",
            (n_img, n_exp, n, n, 3),
            (r.frames_per_chunk, n_exp, c, c, 3),
            Capture("rgb", "sample", times, light=self.schedule.images),
        )
        coords = self._image_coords()
        coords["image"] = ("image", np.arange(n_img), {"units": "1", "long_name": "image index"})
        coords["channel"] = ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"})
        coords["exposure_time"] = (
            ("image", "exposure"),
            times.copy(),
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
        sh = self.schedule.shots
        shots = Capture("spectral", "sample", self.schedule.band_time[sh.band], band=sh.band, light=sh)
        counts = self.counts("spectral", (len(sh), n, n), (r.frames_per_chunk, c, c), shots)
        im = Images(
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
                    self.renderer.wavelength[sh.band],
                    {"units": "nm", "long_name": "centre wavelength of the filter band"},
                ),
                "exposure_time": (
                    "shot",
                    self.schedule.band_time[sh.band],
                    {"units": "s", "long_name": "exposure time (eq. 2, quantised)"},
                ),
                "filter_size": (
                    "shot",
                    self.schedule.plan["filter_size"].values[sh.band],
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
        nt = self.schedule.dark_times.size
        times = np.broadcast_to(self.schedule.dark_times[:, None], (nt, r.n_dark_frames))
        frames = self.counts(
            "dark",
            (nt, r.n_dark_frames, n, n),
            (1, r.frames_per_chunk, c, c),
            Capture("spectral", "dark", times),
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
                    self.schedule.dark_times,
                    {"units": "s", "long_name": "exposure time"},
                )
            },
            attrs=self._attrs("raw/dark") | {"camera": "spectral", "bit_depth": r.spectral_bit_depth},
        )

    def _plan_group(self) -> xr.Dataset:
        ds = self.schedule.plan.copy()
        ds["exposure_time_quantised"] = (
            "wavelength",
            self.schedule.band_time,
            {"units": "s", "long_name": "exposure time used (quantised to the shutter step)"},
        )
        ds["band_illuminant"] = (
            "wavelength",
            self.renderer.band_illuminant,
            {"units": "1", "long_name": "illuminant seen through each filter band"},
        )
        ds["reference_exposure_time"] = (
            "wavelength",
            self.schedule.reference["exposure_time"].values,
            {"units": "s", "long_name": "long-exposure reference plan (omega = 1)"},
        )
        ds["reference_capture_time"] = (
            (),
            float(self.schedule.reference["exposure_time"].sum()),
            {"units": "s", "long_name": "total time of one reference set of bands"},
        )
        ds.attrs = ds.attrs | self._attrs("raw/exposure_plan")
        ds["wavelength"].attrs["long_name"] = "centre wavelength of the filter band"
        return ds

    def _calibration_group(self, target: str) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        ne, ns, nw = (
            self.schedule.calib_rgb_times.size,
            self.schedule.calib_spectral_times.size,
            self.renderer.wavelength.size,
        )
        rgb = self.counts(
            f"{target}-rgb",
            (ne, n, n, 3),
            (ne, c, c, 3),
            Capture("rgb", target, self.schedule.calib_rgb_times),
        )
        spec = self.counts(
            f"{target}-spectral",
            (nw, ns, n, n),
            (max(1, r.frames_per_chunk // ns), ns, c, c),
            Capture(
                "spectral",
                target,
                np.broadcast_to(self.schedule.calib_spectral_times[None, :], (nw, ns)),
                band=np.arange(nw),
            ),
        )
        group = "raw/white_reference" if target == "white" else "raw/colour_checker"
        # every RGB camera photographs the flat Lambertian target lit at normal incidence: the
        # cameras are of one model, so each sees the paired camera's frames (one noise draw)
        n_camera = len(r.rgb_camera_thetas)
        rgb = da.broadcast_to(rgb[None], (n_camera, *rgb.shape), chunks=((1,) * n_camera, *rgb.chunks))
        ds = xr.Dataset(
            {
                "rgb_counts": (
                    ("camera", "rgb_exposure", "y", "x", "channel"),
                    rgb,
                    self._counts_attrs(r.rgb_bit_depth, "raw RGB counts of each RGB camera"),
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
                    self.renderer.wavelength,
                    {"units": "nm", "long_name": "centre wavelength of the filter band"},
                ),
                "channel": ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"}),
                "camera": (
                    "camera",
                    np.arange(n_camera, dtype=np.int64),
                    {"units": "1", "long_name": "RGB camera index"},
                ),
                "rgb_exposure_time": (
                    ("camera", "rgb_exposure"),
                    np.broadcast_to(self.schedule.calib_rgb_times, (n_camera, ne)).copy(),
                    {"units": "s", "long_name": "exposure time of the RGB series"},
                ),
                "spectral_exposure_time": (
                    "spectral_exposure",
                    self.schedule.calib_spectral_times,
                    {"units": "s", "long_name": "exposure time of the spectral series"},
                ),
            },
            attrs=self._attrs(group)
            | {
                "illumination": "one LED at theta_i = 0 deg (Lambertian target)",
                "rgb_bit_depth": r.rgb_bit_depth,
                "spectral_bit_depth": r.spectral_bit_depth,
                "rgb_camera": self.schedule.paired_camera,
                "theta_o": r.spectral_camera_theta,
            },
        )
        ds["illuminant"] = (
            "wavelength",
            self.renderer.illuminant.values,
            {"units": "1", "long_name": "measured relative spectral radiance of the LEDs"},
        )
        if target == "white":
            ds["target_reflectance"] = (
                "wavelength",
                np.full(nw, 0.98),
                {"units": "1", "long_name": "certified reflectance of the white target"},
            )
        else:
            ds = self._with_chart(ds, n, n_camera)
        return ds

    def _with_chart(self, ds: xr.Dataset, n: int, n_camera: int) -> xr.Dataset:
        """The colour checker's published reflectances and the patch under each pixel.

        Every RGB camera sees the chart in one rectified view: its patch label image is the
        paired camera's (``rgb_patch_index``, one per camera).
        """
        refl = self.renderer.chart.reflectances()
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
        labels = self.renderer.chart.patch_index(slice(0, n), slice(0, n))
        ds["patch_index"] = (
            ("y", "x"),
            labels,
            {
                "units": "1",
                "long_name": "patch under each pixel of the "
                "RGB image (-1: frame); the spectral image is shifted",
            },
        )
        ds["rgb_patch_index"] = (
            ("camera", "y", "x"),
            np.broadcast_to(np.asarray(labels), (n_camera, n, n)).copy(),
            {"units": "1", "long_name": "patch under each pixel of each RGB camera (-1: frame)"},
        )
        ds.attrs["chart"] = self.renderer.chart.chart
        return ds

    def _registration_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        nr = r.n_rotations
        sched = self.schedule
        rgb = self.counts(
            "reg-rgb",
            (nr, n, n, 3),
            (r.frames_per_chunk, c, c, 3),
            Capture("rgb", "dome", np.full(nr, float(sched.registration_rgb_time))),
        )
        spec = self.counts(
            "reg-spectral",
            (nr, n, n),
            (r.frames_per_chunk, c, c),
            Capture(
                "spectral",
                "dome",
                np.full(nr, float(sched.registration_spectral_time)),
                band=np.full(nr, sched.registration_band),
            ),
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
                    self.schedule.rotation_angle,
                    {"units": "degree", "long_name": "rotation of the sample"},
                ),
                "channel": ("channel", _strings(["R", "G", "B"]), {"long_name": "channel"}),
                "rgb_exposure_time": (
                    (),
                    float(self.schedule.registration_rgb_time),
                    {"units": "s", "long_name": "exposure time of the RGB shots"},
                ),
                "spectral_exposure_time": (
                    (),
                    float(self.schedule.registration_spectral_time),
                    {"units": "s", "long_name": "exposure time of the spectral shots"},
                ),
                "spectral_wavelength": (
                    (),
                    float(self.renderer.wavelength[self.schedule.registration_band]),
                    {"units": "nm", "long_name": "filter band of the spectral shots"},
                ),
            },
            attrs=self._attrs("raw/registration")
            | {
                "illumination": "many LEDs on (diffuse dome)",
                "rgb_camera": self.schedule.paired_camera,
                "rgb_bit_depth": r.rgb_bit_depth,
                "spectral_bit_depth": r.spectral_bit_depth,
                "pairing": "spectral_counts at rotation r + 1 shows what rgb_counts at "
                "rotation r shows, up to the misregistration",
            },
        )

    def _truth_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        nw = self.renderer.wavelength.size
        rad = self.lazy(
            "truth",
            (len(self.schedule.images), nw, n, n),
            (max(1, r.frames_per_chunk // 4), nw, c, c),
            np.float32,
            self.renderer.radiance,
            self.schedule.images,
        )
        coords = self._image_coords()
        coords["image"] = (
            "image",
            np.arange(len(self.schedule.images)),
            {"units": "1", "long_name": "image index (as raw/rgb)"},
        )
        coords["wavelength"] = (
            "wavelength",
            self.renderer.wavelength,
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
            attrs=self._attrs("truth/spectra")
            | {"materials": ", ".join(self.renderer.texture.material_names)},
        )
        tile = self.renderer.texture.evaluate(slice(0, n), slice(0, n)) if n <= 1024 else None
        if tile is not None:
            ds["material"] = (
                ("y", "x"),
                tile.material,
                {"units": "1", "long_name": "index of the dominant material"},
            )
        return ds

    def _true_oecf(self) -> tuple[np.ndarray, np.ndarray]:
        """The true OECFs tabulated per code: ``codes`` and a (sensor, code) table.

        Rows R, G, B (the RGB camera's responses) and mono (the spectral camera's), over the
        codes of the larger bit depth; NaN beyond a sensor's own bit depth.
        """
        r = self.recipe
        bits = max(r.rgb_bit_depth, r.spectral_bit_depth)
        codes = np.arange(2**bits)
        table = np.full((4, codes.size), np.nan)
        for k, ch in enumerate("RGB"):
            t = oecf_table(self.renderer.rgb_camera.responses[ch], bit_depth=r.rgb_bit_depth)
            table[k, : t.size] = t
        t = oecf_table(self.renderer.spectral_camera.response, bit_depth=r.spectral_bit_depth)
        table[3, : t.size] = t
        return codes, table

    def _camera_group(self) -> xr.Dataset:
        r = self.recipe
        n, c = self._yx()
        codes, table = self._true_oecf()
        sensor = _strings(["R", "G", "B", "mono"])
        per = {
            "adc_offset": [r.rgb_adc_offset] * 3 + [r.spectral_adc_offset],
            "noise_sigma": [r.rgb_noise_sigma] * 3 + [r.spectral_noise_sigma],
            "bit_depth": [r.rgb_bit_depth] * 3 + [r.spectral_bit_depth],
        }
        offset = self.lazy("offset", (n, n), (c, c), np.float32, self.renderer.pattern, 0)
        dcur = self.lazy("dark-current", (n, n), (c, c), np.float32, self.renderer.pattern, 1)
        responses = {
            ch: {"model": s.model, **s.parameters} for ch, s in zip("RGB", r.rgb_responses, strict=True)
        }
        responses["mono"] = {"model": r.spectral_response.model, **r.spectral_response.parameters}
        return xr.Dataset(
            {
                "camera_matrix": self.renderer.rgb_camera.camera_matrix.drop_vars(
                    ["wavelength", "channel"]
                ).variable,
                "quantum_efficiency": (
                    "wavelength",
                    self.renderer.q,
                    {
                        "units": "s-1",
                        "long_name": "quantum efficiency Q of the spectral camera system per band",
                    },
                ),
                "illuminant": (
                    "wavelength",
                    self.renderer.illuminant.values,
                    {"units": "1", "long_name": "relative spectral radiance L of the LEDs"},
                ),
                "bandpass": (
                    ("band", "wavelength"),
                    self.renderer.bandpass,
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
                    self.renderer.wavelength,
                    {"units": "nm", "long_name": "wavelength"},
                ),
                "band": (
                    "band",
                    self.renderer.wavelength,
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
