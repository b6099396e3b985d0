"""The raw groups of a run store, built from a checked capture folder.

Each builder turns the rows of one kind (:class:`~spectralize.datasets.capture.Capture`) into
a lazy :class:`xarray.Dataset` in the run store's layout (``schemas/README.md``): ``raw/rgb``,
``raw/spectral``, ``raw/dark``, ``raw/white_reference``, ``raw/colour_checker``,
``raw/registration`` and ``raw/exposure_plan``. Dask reads one file (one RGB exposure series)
per chunk of about :data:`CHUNK_BYTES`, so memory is bounded by a chunk, not by the run; a
chunk's frames are decoded on every core and put in order (:mod:`.decode`).
A frame already in the store (same file, size and modification time) is copied from there
instead of decoded again (:class:`FrameSources`); a group's :func:`fingerprint` is made from
its coordinates, small variables, attributes and its files' versions.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (band shots paired with RGB images seen from the
same angles) and sec. 4, eq. 2 and 3 (exposure times and filter sizes of the exposure plan).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import uuid
from collections import defaultdict
from dataclasses import dataclass
from typing import Any

import dask.array as da
import numpy as np
import xarray as xr

from spectralize.datasets.capture import ANGLES, Capture, Row
from spectralize.datasets.capture.checks import borrowed_calibration, calibration_cameras, pair
from spectralize.datasets.capture.model import rounded
from spectralize.store import RunStore
from spectralize.store.fingerprint import STORE_LAYOUT
from spectralize.store.integrity import read_manifest

from .decode import FrameDecoder

__all__ = [
    "RAW_GROUPS",
    "INGEST_VERSION",
    "FILES_ATTR",
    "CHUNK_BYTES",
    "RawGroup",
    "FrameSources",
    "build_raw_groups",
    "fingerprint",
    "capture_files_of_chunk",
]

RAW_GROUPS: tuple[str, ...] = (
    "raw/rgb",
    "raw/spectral",
    "raw/dark",
    "raw/white_reference",
    "raw/colour_checker",
    "raw/registration",
    "raw/exposure_plan",
)
"""The groups ingest writes, in the order they are built (``raw/spectral`` needs ``raw/rgb``)."""

#: Bumped when the groups ingest writes change: every group is then rewritten.
INGEST_VERSION = "2"
FILES_ATTR = "spectralize_ingest_files"  # a record: per variable, [file, size, mtime_ns] per frame


@dataclass
class RawGroup:
    """One raw group to write: its dataset (frames lazy, from files or the store) and files."""

    name: str
    dataset: xr.Dataset
    files: dict[str, list[list[Any]]]  # variable -> [file, size, mtime_ns] per frame, C order
    resumable: str | None = None
    fingerprint: str = ""


class FrameSources:
    """Where each frame comes from: the store's previous version of the group, or its file.

    A previous version that fails the store's cheap check (or was marked damaged) is not
    copied from: its frames are read from their files again. The frames of a chunk are
    decoded by ``decoder`` (:class:`~.decode.FrameDecoder`: on every core; None: in the
    thread that computes the chunk).
    """

    def __init__(
        self, capture: Capture, store: RunStore, group: str, decoder: FrameDecoder | None = None
    ):
        self.capture = capture
        self.decoder = decoder or FrameDecoder(workers=1)
        self.read = 0
        self.copied = 0
        self.previous: dict[str, dict[tuple, tuple]] = {}
        if store.has(group) and not store.verify(group):
            manifest = read_manifest(store.manifest(group)) or {}
            checksums = {
                f"{group}/{rel}": crc for rel, (_, _, crc) in manifest.items() if crc is not None
            }
            for var, files in (store.record(group, FILES_ATTR) or {}).items():
                meta = json.loads((store.path / group / var / "zarr.json").read_text())
                frame = 3 if group == "raw/rgb" or var == "rgb_counts" else 2  # (y, x[, channel])
                grid = tuple(meta["shape"][: len(meta["shape"]) - frame])
                self.previous[var] = {
                    tuple(entry): (
                        str(store.path),
                        f"{group}/{var}",
                        np.unravel_index(k, grid),
                        checksums,
                    )
                    for k, entry in enumerate(files)
                }

    def frames(self, var: str, rows: list[Row], frame: tuple[int, ...]) -> tuple[Frames, list]:
        arrays, files = [], []
        for row in rows:
            stat = self.capture.stat(row)
            old = self.previous.get(var, {}).get(tuple(stat))
            file = str(self.capture.file(row))
            if old is not None:
                source = ("store", old[0], old[1], tuple(int(i) for i in old[2]), old[3], file)
                self.copied += 1
            else:  # its values are checked as it is decoded (its camera's bit depth)
                config = self.capture.config
                rgb = row.camera in config.rgb_cameras
                source = ("file", file, config.rgb_bit_depth if rgb else config.spectral_bit_depth)
                self.read += 1
            arrays.append(source)
            files.append(stat)
        return Frames(arrays, frame, self.decoder), files


@dataclass
class Frames:
    """Where each frame of a variable comes from (C order), the shape of one frame, and what
    decodes them."""

    sources: list[tuple]
    frame: tuple[int, ...]
    decoder: FrameDecoder


#: Target size of one dask chunk (and one resumable region): memory is bounded by a few.
CHUNK_BYTES = 64 * 2**20


def _grid(frames: Frames, shape: tuple[int, ...]) -> da.Array:
    """Frames (C order) stacked onto a grid of ``shape``, chunked to about :data:`CHUNK_BYTES`.

    The last grid dims are filled first: e.g. an RGB image's exposure series is one chunk
    (when it fits), and as many images as fit share it. One dask task per chunk, holding only
    the sources of its frames: the graph grows with the chunks, not with the frames.
    """
    frame = frames.frame
    budget = max(1, CHUNK_BYTES // max(1, int(np.prod(frame)) * 2))
    sizes = [0] * len(shape)
    for axis in reversed(range(len(shape))):
        sizes[axis] = int(min(shape[axis], max(1, budget)))
        budget //= max(1, shape[axis])
    chunks = da.core.normalize_chunks((*sizes, *frame), (*shape, *frame))
    name = f"ingest-frames-{uuid.uuid4().hex}"
    graph: dict[tuple, tuple] = {}
    starts = [np.cumsum((0, *c[:-1])) for c in chunks[: len(shape)]]
    for block in itertools.product(*(range(len(c)) for c in chunks[: len(shape)])):
        ranges = [
            range(int(starts[a][i]), int(starts[a][i]) + chunks[a][i]) for a, i in enumerate(block)
        ]
        positions = itertools.product(*ranges)
        picked = [frames.sources[int(np.ravel_multi_index(p, shape))] for p in positions]
        extent = tuple(len(r) for r in ranges)
        graph[(name, *block, *([0] * len(frame)))] = (
            _load_block,
            picked,
            frame,
            extent,
            frames.decoder,
        )
    return da.Array(graph, name, chunks, dtype=np.uint16)


def _load_block(
    sources: list[tuple], frame: tuple[int, ...], extent: tuple[int, ...], decoder: FrameDecoder
) -> np.ndarray:
    """The frames of one chunk, shape ``extent + frame``, decoded by ``decoder`` in order."""
    out = np.empty((len(sources), *frame), np.uint16)
    for k, data in enumerate(decoder.frames(sources, frame)):
        out[k] = data.reshape(frame)
    return out.reshape(*extent, *frame)


def _attrs_counts(bits: int, long_name: str) -> dict[str, Any]:
    return {"units": "DN", "long_name": long_name, "bit_depth": int(bits)}


def _source_attrs(capture: Capture, title: str) -> dict[str, Any]:
    return {
        "title": title,
        "source": f"capture folder {capture.path.name!r} ({capture.config.name}), "
        "ingested by spectralize.flows.ingest",
        "capture_folder": str(capture.path.absolute()),
    }


def _rgb_group(capture: Capture, sources: FrameSources) -> RawGroup:
    config = capture.config
    y, x = capture.frame_shape
    series: dict[tuple, list[Row]] = defaultdict(list)
    for row in capture.of("rgb"):
        series[(row.rotation, row.led, config.rgb_cameras.index(row.camera))].append(row)
    keys = sorted(series)
    ordered = [sorted(series[k], key=lambda r: r.exposure_time) for k in keys]
    n_img, n_exp = len(keys), len(ordered[0])
    arrays, files = sources.frames(
        "counts", [r for s in ordered for r in s], (y, x, len(config.channels))
    )
    counts = _grid(arrays, (n_img, n_exp))
    first = [s[0] for s in ordered]
    coords: dict[str, Any] = {
        "image": ("image", np.arange(n_img), {"units": "1", "long_name": "image label"}),
        "channel": ("channel", np.asarray(config.channels), {"long_name": "channel"}),
        "exposure_time": (
            ("image", "exposure"),
            np.array([[r.exposure_time for r in s] for s in ordered]),
            {"units": "s", "long_name": "exposure time"},
        ),
        "camera": (
            "image",
            np.array([k[2] for k in keys], np.int64),
            {"units": "1", "long_name": "RGB camera index (capture.toml rgb.cameras)"},
        ),
        "rotation": (
            "image",
            np.array([k[0] for k in keys], np.int64),
            {"units": "1", "long_name": "rotation stage position"},
        ),
        "led": (
            "image",
            np.array([k[1] for k in keys], np.int64),
            {"units": "1", "long_name": "index of the LED"},
        ),
        "led_power": (
            "image",
            np.array([_led_power(capture, k[1]) for k in keys]),
            {"units": "1", "long_name": "relative power of the LED (calibration/led_power.csv)"},
        ),
    }
    for i, name in enumerate(ANGLES):
        coords[name] = (
            "image",
            np.array([r.angles[i] for r in first]),
            {"units": "degree", "long_name": _ANGLE_NAMES[name]},
        )
    ds = xr.Dataset(
        {
            "counts": (
                ("image", "exposure", "y", "x", "channel"),
                counts,
                _attrs_counts(config.rgb_bit_depth, "raw RGB counts"),
            )
        },
        coords=coords,
        attrs=_source_attrs(capture, "LDR exposure series of the RGB cameras")
        | {
            "bit_depth": config.rgb_bit_depth,
            "camera": "rgb",
            "camera_names": list(config.rgb_cameras),
            "camera_models": [config.model_of(c) or "" for c in config.rgb_cameras],
            "black_level_dn": [config.black_level_dn.get(c, -1) for c in config.rgb_cameras],
            # only where capture.toml declares one (a capture without keeps its fingerprint)
            **(
                {"white_level_dn": [config.white_level_dn.get(c, -1) for c in config.rgb_cameras]}
                if config.white_level_dn
                else {}
            ),
            "led_power_from": "calibration/led_power.csv" if capture.led_power else "none (each LED 1)",
        },
    )
    return RawGroup("raw/rgb", ds, {"counts": files}, resumable="image")


_ANGLE_NAMES = {
    "theta_i": "polar angle of the light direction (sample frame)",
    "phi_i": "azimuth of the light direction (sample frame)",
    "theta_o": "polar angle of the view direction (sample frame)",
    "phi_o": "azimuth of the view direction (sample frame)",
}


def _filter_sizes(capture: Capture, wavelength: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Filter size per band: ``exposure_plan.csv``, else eq. 2 and 3 solved for ``s_i(t_i)``.

    With ``t_i = (t0 / (Q_i L_i))**omega`` and ``s_i = s0 / (Q_i L_i t_i)``:
    ``s_i = (s0 / t0) * t_i**(1 / omega - 1)``.
    """
    c = capture.config
    sizes = (c.s0 / c.t0) * np.asarray(times, dtype=float) ** (1.0 / c.omega - 1.0)
    if capture.plan_table is not None:
        table = {
            rounded(w): s for w, s in zip(capture.plan_table[0], capture.plan_table[2], strict=True)
        }
        sizes = np.array([table.get(rounded(w), s) for w, s in zip(wavelength, sizes, strict=True)])
    return sizes


def _spectral_group(capture: Capture, sources: FrameSources, image_of: dict[tuple, int]) -> RawGroup:
    config = capture.config
    y, x = capture.frame_shape
    rows = sorted(capture.of("spectral"), key=lambda r: (r.rotation, r.led, r.wavelength))
    arrays, files = sources.frames("counts", rows, (y, x))
    paired = [
        ((config.paired_camera, r.rotation, r.led), r)
        for r in capture.of("rgb")
        if r.camera == config.paired_camera
    ]
    pairs = [pair(r, paired, config.angle_tolerance) for r in rows]
    wavelength = np.array([r.wavelength for r in rows])
    times = np.array([r.exposure_time for r in rows])
    coords: dict[str, Any] = {
        "shot": ("shot", np.arange(len(rows)), {"units": "1", "long_name": "shot index"}),
        "wavelength": (
            "shot",
            wavelength,
            {"units": "nm", "long_name": "centre wavelength of the filter band"},
        ),
        "exposure_time": ("shot", times, {"units": "s", "long_name": "exposure time"}),
        "image": (
            "shot",
            np.array([image_of[(p[1], p[2], config.rgb_cameras.index(p[0]))] for p in pairs], np.int64),
            {"units": "1", "long_name": "label of the raw/rgb image this shot pairs with (same angles)"},
        ),
        "rotation": (
            "shot",
            np.array([r.rotation for r in rows], np.int64),
            {"units": "1", "long_name": "rotation stage position"},
        ),
        "led": (
            "shot",
            np.array([r.led for r in rows], np.int64),
            {"units": "1", "long_name": "index of the LED"},
        ),
        "led_power": (
            "shot",
            np.array([_led_power(capture, r.led) for r in rows]),
            {"units": "1", "long_name": "relative power of the shot's LED (calibration/led_power.csv)"},
        ),
        "image_led_power": (
            "shot",
            np.array([_led_power(capture, p[2]) for p in pairs]),
            {"units": "1", "long_name": "relative power of the LED of the RGB image it pairs with"},
        ),
        "filter_size": (
            "shot",
            _filter_sizes(capture, wavelength, times),
            {"units": "px", "long_name": "Gaussian filter size s_i (eq. 3)"},
        ),
    }
    for i, name in enumerate(ANGLES):
        coords[name] = (
            "shot",
            np.array([r.angles[i] for r in rows]),
            {"units": "degree", "long_name": _ANGLE_NAMES[name]},
        )
    ds = xr.Dataset(
        {
            "counts": (
                ("shot", "y", "x"),
                _grid(arrays, (len(rows),)),
                _attrs_counts(config.spectral_bit_depth, "raw band counts"),
            )
        },
        coords=coords,
        attrs=_source_attrs(capture, "band-filtered frames of the spectral camera")
        | {"bit_depth": config.spectral_bit_depth, "camera": config.spectral_camera},
    )
    return RawGroup("raw/spectral", ds, {"counts": files}, resumable="shot")


def _dark_group(capture: Capture, sources: FrameSources) -> RawGroup:
    config = capture.config
    y, x = capture.frame_shape
    by_time: dict[float, list[Row]] = defaultdict(list)
    for row in capture.of("dark"):
        by_time[rounded(row.exposure_time)].append(row)
    times = sorted(by_time)
    ordered = [sorted(by_time[t], key=lambda r: r.file) for t in times]
    arrays, files = sources.frames("frames", [r for s in ordered for r in s], (y, x))
    frames = _grid(arrays, (len(times), len(ordered[0])))
    ds = xr.Dataset(
        {
            "frames": (
                ("exposure_time", "frame", "y", "x"),
                frames,
                _attrs_counts(
                    config.spectral_bit_depth, "raw dark frames of the spectral camera (closed shutter)"
                ),
            )
        },
        coords={
            "exposure_time": (
                "exposure_time",
                np.array([s[0].exposure_time for s in ordered]),
                {"units": "s", "long_name": "exposure time"},
            )
        },
        attrs=_source_attrs(capture, "dark frames of the spectral camera")
        | {"camera": config.spectral_camera, "bit_depth": config.spectral_bit_depth},
    )
    return RawGroup("raw/dark", ds, {"frames": files}, resumable="exposure_time")


def _target_group(capture: Capture, sources: FrameSources, kind: str) -> RawGroup:
    config = capture.config
    y, x = capture.frame_shape
    cameras = calibration_cameras(capture.rows, config)
    per_camera = [sorted(capture.of(kind, c), key=lambda r: r.exposure_time) for c in cameras]
    rgb_rows = [r for series in per_camera for r in series]
    band_rows = capture.of(kind, config.spectral_camera)
    times = sorted({rounded(r.exposure_time) for r in band_rows})
    grid = {(rounded(r.wavelength), rounded(r.exposure_time)): r for r in band_rows}
    ordered = [grid[(rounded(w), t)] for w in capture.bands for t in times]
    rgb_arrays, rgb_files = sources.frames("rgb_counts", rgb_rows, (y, x, len(config.channels)))
    band_arrays, band_files = sources.frames("spectral_counts", ordered, (y, x))
    ds = xr.Dataset(
        {
            "rgb_counts": (
                ("camera", "rgb_exposure", "y", "x", "channel"),
                _grid(rgb_arrays, (len(cameras), len(per_camera[0]))),
                _attrs_counts(config.rgb_bit_depth, "raw RGB counts of each RGB camera"),
            ),
            "spectral_counts": (
                ("wavelength", "spectral_exposure", "y", "x"),
                _grid(band_arrays, (capture.bands.size, len(times))),
                _attrs_counts(config.spectral_bit_depth, "raw band counts of the spectral camera"),
            ),
            "illuminant": (
                "wavelength",
                capture.illuminant,
                {
                    "units": "1",
                    "long_name": "measured relative spectral radiance of the LEDs (illuminant.csv)",
                },
            ),
        },
        coords={
            "wavelength": (
                "wavelength",
                capture.bands,
                {"units": "nm", "long_name": "centre wavelength of the filter band"},
            ),
            "channel": ("channel", np.asarray(config.channels), {"long_name": "channel"}),
            "camera": (
                "camera",
                np.array([config.rgb_cameras.index(c) for c in cameras], np.int64),
                {"units": "1", "long_name": "RGB camera index (capture.toml rgb.cameras)"},
            ),
            "camera_name": ("camera", np.asarray(cameras), {"long_name": "RGB camera name"}),
            "rgb_exposure_time": (
                ("camera", "rgb_exposure"),
                np.array([[r.exposure_time for r in series] for series in per_camera]),
                {"units": "s", "long_name": "exposure time of the RGB series"},
            ),
            "spectral_exposure_time": (
                "spectral_exposure",
                np.array([grid[(rounded(capture.bands[0]), t)].exposure_time for t in times]),
                {"units": "s", "long_name": "exposure time of the band series"},
            ),
        },
        attrs=_source_attrs(capture, f"{kind.replace('_', ' ')} under the LEDs")
        | {
            "rgb_bit_depth": config.rgb_bit_depth,
            "spectral_bit_depth": config.spectral_bit_depth,
            "rgb_camera": config.rgb_cameras.index(config.paired_camera),
        }
        | _camera_attrs(capture, cameras),
    )
    if kind == "white_reference":
        ds["target_reflectance"] = (
            "wavelength",
            np.clip(capture.white_reflectance, 0.0, 1.0),
            {
                "units": "1",
                "long_name": "certified reflectance of the white target (white_reference.csv)",
            },
        )
    else:
        names, reflectance, chart = capture.patches
        ds["patch_reflectance"] = (
            ("patch", "wavelength"),
            np.clip(reflectance, 0.0, 1.0),
            {"units": "1", "long_name": "published reflectance of the chart patches"},
        )
        ds = ds.assign_coords(
            patch=("patch", np.arange(len(names)), {"units": "1", "long_name": "patch index"}),
            patch_name=("patch", np.asarray(names)),
        )
        ds["patch_index"] = (
            ("y", "x"),
            capture.patch_index,
            {"units": "1", "long_name": "patch under each pixel of the paired RGB camera (-1: frame)"},
        )
        ds["rgb_patch_index"] = (
            ("camera", "y", "x"),
            np.stack([capture.rgb_patch_index[c] for c in cameras]),
            {"units": "1", "long_name": "patch under each pixel of each RGB camera (-1: frame)"},
        )
        ds.attrs["chart"] = chart
    return RawGroup(f"raw/{kind}", ds, {"rgb_counts": rgb_files, "spectral_counts": band_files})


def _camera_attrs(capture: Capture, cameras: list[str]) -> dict[str, Any]:
    """Every RGB camera's name and sensor model, and which cameras borrow a calibration
    (``{borrower: lender}`` as JSON text, so the attrs stay netCDF-writable)."""
    config = capture.config
    return {
        "camera_names": list(config.rgb_cameras),
        "camera_models": [config.model_of(c) or "" for c in config.rgb_cameras],
        "calibration_borrowed": json.dumps(borrowed_calibration(config, cameras), sort_keys=True),
    }


def _led_power(capture: Capture, led: int) -> float:
    return 1.0 if capture.led_power is None else float(capture.led_power[led])


def _registration_group(capture: Capture, sources: FrameSources) -> RawGroup:
    config = capture.config
    y, x = capture.frame_shape
    rgb_rows = sorted(capture.of("registration", config.paired_camera), key=lambda r: r.rotation)
    mono_rows = sorted(capture.of("registration", config.spectral_camera), key=lambda r: r.rotation)
    rgb_arrays, rgb_files = sources.frames("rgb_counts", rgb_rows, (y, x, len(config.channels)))
    mono_arrays, mono_files = sources.frames("spectral_counts", mono_rows, (y, x))
    rotation = np.array([r.rotation for r in rgb_rows], np.int64)
    ds = xr.Dataset(
        {
            "rgb_counts": (
                ("rotation", "y", "x", "channel"),
                _grid(rgb_arrays, (len(rgb_rows),)),
                _attrs_counts(config.rgb_bit_depth, f"RGB camera {config.paired_camera}"),
            ),
            "spectral_counts": (
                ("rotation", "y", "x"),
                _grid(mono_arrays, (len(mono_rows),)),
                _attrs_counts(config.spectral_bit_depth, "spectral camera"),
            ),
        },
        coords={
            "rotation": ("rotation", rotation, {"units": "1", "long_name": "rotation stage position"}),
            "rotation_angle": (
                "rotation",
                (rotation * config.rotation_step) % 360.0,
                {"units": "degree", "long_name": "rotation of the sample"},
            ),
            "channel": ("channel", np.asarray(config.channels), {"long_name": "channel"}),
            "rgb_exposure_time": (
                (),
                float(rgb_rows[0].exposure_time),
                {"units": "s", "long_name": "exposure time of the RGB shots"},
            ),
            "spectral_exposure_time": (
                (),
                float(mono_rows[0].exposure_time),
                {"units": "s", "long_name": "exposure time of the spectral shots"},
            ),
            "spectral_wavelength": (
                (),
                float(mono_rows[0].wavelength),
                {"units": "nm", "long_name": "filter band of the spectral shots"},
            ),
        },
        attrs=_source_attrs(capture, "long-exposure registration shots per rotation")
        | {
            "rgb_camera": config.rgb_cameras.index(config.paired_camera),
            "rgb_bit_depth": config.rgb_bit_depth,
            "spectral_bit_depth": config.spectral_bit_depth,
        },
    )
    return RawGroup("raw/registration", ds, {"rgb_counts": rgb_files, "spectral_counts": mono_files})


def _plan_group(capture: Capture, rgb: xr.Dataset, spectral: xr.Dataset) -> RawGroup:
    c = capture.config
    if capture.plan_table is not None:
        wavelength, times, sizes = (np.asarray(v, dtype=float) for v in capture.plan_table)
        order = np.argsort(wavelength)
        wavelength, times, sizes = wavelength[order], times[order], sizes[order]
    else:
        shots = spectral[["exposure_time"]].to_dataframe().groupby(spectral["wavelength"].values).first()
        wavelength = np.asarray(shots.index, dtype=float)
        times = np.asarray(shots["exposure_time"], dtype=float)
        sizes = _filter_sizes(capture, wavelength, times)
    ds = xr.Dataset(
        {
            "exposure_time": ("wavelength", times, {"units": "s", "long_name": "exposure time (eq. 2)"}),
            "filter_size": (
                "wavelength",
                sizes,
                {"units": "px", "long_name": "filter size s_i (eq. 3)"},
            ),
            "filter_sigma": ("wavelength", sizes / 5.0, {"units": "px", "long_name": "s_i / 5"}),
            "spectral_capture_time": (
                (),
                float(spectral["exposure_time"].sum()),
                {"units": "s", "long_name": "total spectral exposure"},
            ),
            "rgb_capture_time": (
                (),
                float(rgb["exposure_time"].sum()),
                {"units": "s", "long_name": "total RGB exposure"},
            ),
        },
        coords={
            "wavelength": (
                "wavelength",
                wavelength,
                {"units": "nm", "long_name": "centre wavelength of the filter band"},
            )
        },
        attrs=_source_attrs(capture, "the exposure plan (eq. 2, 3) the band shots followed")
        | {
            "t0": c.t0,
            "s0": c.s0,
            "omega": c.omega,
            "filter_sizes_from": "calibration/exposure_plan.csv"
            if capture.plan_table is not None
            else "eq. 2 and 3 with t0, s0, omega of capture.toml",
        },
    )
    return RawGroup("raw/exposure_plan", ds, {})


def fingerprint(group: RawGroup) -> str:
    """Of the group's description: coords, small variables, attrs and its files' versions."""
    ds = group.dataset
    payload = {
        "ingest": INGEST_VERSION,
        "layout": STORE_LAYOUT,  # a store of another layout is ingested again
        "group": group.name,
        "attrs": {k: v for k, v in ds.attrs.items() if k != "capture_folder"},
        "coords": {k: np.asarray(v.values).tolist() for k, v in ds.coords.items()},
        "small": {k: np.asarray(v.values).tolist() for k, v in ds.data_vars.items() if v.chunks is None},
        "files": group.files,
    }
    text = json.dumps(payload, sort_keys=True, default=str)
    return "ingest:" + hashlib.sha256(text.encode()).hexdigest()


def build_raw_groups(
    capture: Capture, store: RunStore, decoder: FrameDecoder | None = None
) -> list[tuple[RawGroup, FrameSources]]:
    """Every raw group of :data:`RAW_GROUPS`, lazy, with its fingerprint and where its frames come from.

    Parameters
    ----------
    capture
        A checked capture folder (:func:`~spectralize.datasets.capture.read_capture`).
    store
        The run store: frames of files it holds already (same size and modification time)
        are copied from it.
    decoder
        What decodes a chunk's frames when the groups are computed (:class:`~.decode.FrameDecoder`
        on every core, open while they are; None: one thread).
    """
    groups: list[tuple[RawGroup, FrameSources]] = []
    for name in RAW_GROUPS:
        sources = FrameSources(capture, store, name, decoder)
        if name == "raw/rgb":
            group = _rgb_group(capture, sources)
            rgb = group.dataset
            image_of = {
                (int(r), int(led), int(cam)): int(i)
                for i, r, led, cam in zip(
                    rgb["image"].values,
                    rgb["rotation"].values,
                    rgb["led"].values,
                    rgb["camera"].values,
                    strict=True,
                )
            }
        elif name == "raw/spectral":
            group = _spectral_group(capture, sources, image_of)
            spectral = group.dataset
        elif name == "raw/dark":
            group = _dark_group(capture, sources)
        elif name in ("raw/white_reference", "raw/colour_checker"):
            group = _target_group(capture, sources, name.split("/")[1])
        elif name == "raw/registration":
            group = _registration_group(capture, sources)
        else:
            group = _plan_group(capture, rgb, spectral)
        group.fingerprint = fingerprint(group)
        groups.append((group, sources))
    return groups


def capture_files_of_chunk(store: RunStore, key: str) -> list[str]:
    """The capture files whose frames the chunk ``key`` of a raw group holds, in frame order.

    ``key`` is a store key such as ``raw/rgb/counts/c/0/1/0/0/0`` (what a
    :class:`~spectralize.store.ChecksumError` names); the files come from the group's record
    ``spectralize_ingest_files`` (one ``[file, size, mtime_ns]`` per frame, C order). An empty
    list for keys that are not chunks of a frame variable written by ingest.
    """
    parts = key.strip("/").split("/")
    if len(parts) < 5 or parts[3] != "c" or "/".join(parts[:2]) not in RAW_GROUPS:
        return []
    group, var = "/".join(parts[:2]), parts[2]
    try:
        files = (store.record(group, FILES_ATTR) or {}).get(var) or []
        meta = json.loads((store.path / group / var / "zarr.json").read_text())
        shape, chunk = meta["shape"], meta["chunk_grid"]["configuration"]["chunk_shape"]
        index = [int(i) for i in parts[4:]]
    except (OSError, ValueError, KeyError, TypeError):
        return []
    frame = 3 if group == "raw/rgb" or var == "rgb_counts" else 2  # (y, x[, channel])
    grid = shape[: len(shape) - frame]
    ranges = [range(i * c, min((i + 1) * c, n)) for i, c, n in zip(index, chunk, grid, strict=False)]
    out = []
    for position in itertools.product(*ranges):
        k = int(np.ravel_multi_index(position, grid)) if grid else 0
        if k < len(files):
            out.append(str(files[k][0]))
    return out
