"""A sample capture folder, written from the simulator in the format a gantry's software writes.

:func:`write_capture_folder` renders a simulated run (a recipe of
:mod:`spectralize.nodes.simulation.recipes`) as what a real gantry leaves on disk: one image
file per exposure (16-bit PNG and TIFF, monochrome and RGB), ``manifest.csv``, ``capture.toml``
and the ``calibration/`` tables. ``spectralize ingest`` turns it into a run store; the format
is the contract of ``datasets/README.md`` ("Capture folders"). Deterministic: the same recipe
and seed give the same files, byte for byte. Nothing of it is kept in git.

File formats are mixed on purpose, so that a sample exercises every reader: RGB images and
the colour checker's band shots are PNG, everything else TIFF.

The simulator's ground truth is *not* written: a capture folder, like a real capture, has none.

Examples
--------
>>> from spectralize.datasets.capture.sample import write_capture_folder
>>> write_capture_folder("capture", recipe="tiny")  # doctest: +SKIP
PosixPath('capture')

References
----------
Fast Capture of Spectral Image Series, sec. 5 ("Simulated Data").
"""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe

from .model import CALIBRATION, CAPTURE_FORMAT, CONFIG, MANIFEST
from .write import write_config, write_manifest, write_png, write_table, write_tiff

__all__ = ["write_capture_folder"]

SPECTRAL_CAMERA = "mono"


def _image_row(name: str, kind: str, camera: str, coords: Any, **values: Any) -> dict[str, Any]:
    """A manifest row of an image of the gantry: rotation, LED and the four angles [degree]."""
    return {
        "file": name,
        "kind": kind,
        "camera": camera,
        "rotation": int(coords["rotation"]),
        "led": int(coords["led"]),
        **values,
        **{a: float(coords[a]) for a in ("theta_i", "phi_i", "theta_o", "phi_o")},
    }


def write_capture_folder(
    path: str | os.PathLike[str],
    *,
    recipe: str = "tiny",
    seed: int = 0,
    overrides: dict[str, Any] | None = None,
    chart_by_name: bool = False,
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write a simulated run as a capture folder (image files, manifest, calibration tables).

    Parameters
    ----------
    path
        Folder to write; created. Existing files of the same names are replaced.
    recipe, seed, overrides
        The simulated run (:func:`~spectralize.nodes.simulation.recipes.get_recipe`).
    chart_by_name
        Name the colour checker in ``capture.toml`` (a colour-science chart) instead of
        writing ``calibration/colour_checker.csv``.
    progress
        Called with a short message per group written.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    root = Path(path)
    run = get_recipe(recipe, seed=seed, **(overrides or {}))
    groups = simulate_run(run)
    say = progress or (lambda message: None)
    rgb = groups["raw/rgb"]
    cameras = [f"rgb{float(theta):g}" for theta in _camera_thetas(rgb)]
    paired = cameras[int(groups["raw/white_reference"].attrs["rgb_camera"])]
    for folder in ("rgb", "spectral", "dark", "white_reference", "colour_checker", "registration"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    (root / CALIBRATION).mkdir(parents=True, exist_ok=True)

    rows = _write_rgb_series(root, rgb, cameras)
    say(f"raw/rgb: {rgb.sizes['image']} images x {rgb.sizes['exposure']} exposures")
    spectral = groups["raw/spectral"]
    rows += _write_band_shots(root, spectral)
    say(f"raw/spectral: {spectral.sizes['shot']} band shots")
    dark = groups["raw/dark"]
    rows += _write_dark_frames(root, dark)
    say(f"raw/dark: {dark.sizes['exposure_time']} times x {dark.sizes['frame']} frames")
    # calibration targets: RGB series as TIFF (white) / PNG (checker), band series the other way
    for kind, rgb_writer, band_writer in (
        ("white_reference", (write_tiff, "tif"), (write_tiff, "tif")),
        ("colour_checker", (write_tiff, "tif"), (write_png, "png")),
    ):
        rows += _write_target_series(root, groups[f"raw/{kind}"], kind, cameras, rgb_writer, band_writer)
        say(f"raw/{kind}: RGB and band exposure series")
    registration = groups["raw/registration"]
    rows += _write_registration(root, registration, paired)
    say(f"raw/registration: {registration.sizes['rotation']} rotations")

    write_manifest(root / MANIFEST, rows)
    _write_calibration(root / CALIBRATION, groups, chart_by_name=chart_by_name)
    _write_config(
        root / CONFIG,
        groups,
        cameras,
        paired,
        recipe=recipe,
        seed=seed,
        rotation_step=float(run.rotation_step),
        chart_by_name=chart_by_name,
    )
    say(f"wrote {len(rows)} frames to {root}")
    return root


def _write_rgb_series(root: Path, rgb: xr.Dataset, cameras: list[str]) -> list[dict[str, Any]]:
    """The RGB exposure series (``raw/rgb``): one PNG per image and exposure; their rows.

    The simulated counts are lazy and rendered a chunk of images at a time: read chunk by
    chunk (never one image at a time, which renders its whole chunk again for every image),
    with the per-image coordinates read once as plain arrays.
    """
    rows: list[dict[str, Any]] = []
    counts = rgb["counts"]
    per_image = {
        name: np.asarray(rgb[name].values)
        for name in ("camera", "rotation", "led", "theta_i", "phi_i", "theta_o", "phi_o")
    }
    exposure_times = np.asarray(rgb["exposure_time"].transpose("image", "exposure").values, dtype=float)
    for start, stop in _image_blocks(counts):
        block = np.asarray(counts.isel(image=slice(start, stop)).values)
        for image in range(start, stop):
            c = {name: values[image] for name, values in per_image.items()}
            cam = cameras[int(c["camera"])]
            series = block[image - start]
            for e in range(rgb.sizes["exposure"]):
                name = f"rgb/{cam}_rot{int(c['rotation']):02d}_led{int(c['led']):03d}_exp{e}.png"
                write_png(root / name, series[e])
                rows.append(
                    _image_row(name, "rgb", cam, c, exposure_time_s=float(exposure_times[image, e]))
                )
    return rows


def _write_band_shots(root: Path, spectral: xr.Dataset) -> list[dict[str, Any]]:
    """The band shots of the spectral camera (``raw/spectral``): one TIFF each; their rows."""
    rows: list[dict[str, Any]] = []
    shots = spectral["counts"].values
    per_shot = {
        name: np.asarray(spectral[name].values)
        for name in (
            "rotation",
            "led",
            "wavelength",
            "exposure_time",
            "theta_i",
            "phi_i",
            "theta_o",
            "phi_o",
        )
    }
    for shot in range(spectral.sizes["shot"]):
        c = {name: values[shot] for name, values in per_shot.items()}
        wl = float(c["wavelength"])
        name = f"spectral/rot{int(c['rotation']):02d}_led{int(c['led']):03d}_{wl:g}nm.tif"
        write_tiff(root / name, shots[shot])
        rows.append(
            _image_row(
                name,
                "spectral",
                SPECTRAL_CAMERA,
                c,
                exposure_time_s=float(c["exposure_time"]),
                wavelength_nm=wl,
            )
        )
    return rows


def _write_dark_frames(root: Path, dark: xr.Dataset) -> list[dict[str, Any]]:
    """The spectral camera's dark frames (``raw/dark``): one TIFF each; their rows."""
    rows: list[dict[str, Any]] = []
    frames = dark["frames"].values
    for k, t in enumerate(dark["exposure_time"].values):
        for f in range(dark.sizes["frame"]):
            name = f"dark/t{k:02d}_frame{f:03d}.tif"
            write_tiff(root / name, frames[k, f])
            rows.append(
                {"file": name, "kind": "dark", "camera": SPECTRAL_CAMERA, "exposure_time_s": float(t)}
            )
    return rows


def _write_target_series(
    root: Path,
    ds: xr.Dataset,
    kind: str,
    cameras: list[str],
    rgb_writer: tuple[Callable[[Path, np.ndarray], None], str],
    band_writer: tuple[Callable[[Path, np.ndarray], None], str],
) -> list[dict[str, Any]]:
    """A calibration target's exposure series (``raw/white_reference``, ``raw/colour_checker``).

    Every RGB camera photographs the target (an RGB series each), the spectral camera a band
    series per wavelength; ``rgb_writer`` and ``band_writer`` are ``(writer, suffix)``.
    """
    rows: list[dict[str, Any]] = []
    rgb_counts = ds["rgb_counts"].values
    for k, index in enumerate(ds["camera"].values):  # every RGB camera photographs it
        cam = cameras[int(index)]
        for e, t in enumerate(ds["rgb_exposure_time"].values[k]):
            name = f"{kind}/{cam}_rgb_exp{e:02d}.{rgb_writer[1]}"
            rgb_writer[0](root / name, rgb_counts[k, e])
            rows.append({"file": name, "kind": kind, "camera": cam, "exposure_time_s": float(t)})
    band_counts = ds["spectral_counts"].values
    for w, wl in enumerate(ds["wavelength"].values):
        for e, t in enumerate(ds["spectral_exposure_time"].values):
            name = f"{kind}/band_{float(wl):g}nm_exp{e:02d}.{band_writer[1]}"
            band_writer[0](root / name, band_counts[w, e])
            rows.append(
                {
                    "file": name,
                    "kind": kind,
                    "camera": SPECTRAL_CAMERA,
                    "exposure_time_s": float(t),
                    "wavelength_nm": float(wl),
                }
            )
    return rows


def _write_registration(root: Path, reg: xr.Dataset, paired: str) -> list[dict[str, Any]]:
    """The registration shots (``raw/registration``): one long exposure per rotation and camera."""
    rows: list[dict[str, Any]] = []
    reg_rgb, reg_spectral = reg["rgb_counts"].values, reg["spectral_counts"].values
    for r, rotation in enumerate(reg["rotation"].values):
        name = f"registration/rgb_rot{int(rotation):02d}.png"
        write_png(root / name, reg_rgb[r])
        rows.append(
            {
                "file": name,
                "kind": "registration",
                "camera": paired,
                "rotation": int(rotation),
                "exposure_time_s": float(reg["rgb_exposure_time"]),
            }
        )
        name = f"registration/mono_rot{int(rotation):02d}.tif"
        write_tiff(root / name, reg_spectral[r])
        rows.append(
            {
                "file": name,
                "kind": "registration",
                "camera": SPECTRAL_CAMERA,
                "rotation": int(rotation),
                "exposure_time_s": float(reg["spectral_exposure_time"]),
                "wavelength_nm": float(reg["spectral_wavelength"]),
            }
        )
    return rows


def _write_config(
    path: Path,
    groups: dict[str, xr.Dataset],
    cameras: list[str],
    paired: str,
    *,
    recipe: str,
    seed: int,
    rotation_step: float,
    chart_by_name: bool,
) -> None:
    """``capture.toml``: the cameras, the exposure plan (eq. 2, 3), the chart and the source."""
    rgb, spectral = groups["raw/rgb"], groups["raw/spectral"]
    plan = groups["raw/exposure_plan"]
    checker = groups["raw/colour_checker"]
    config = {
        "format": CAPTURE_FORMAT,
        "version": 1,
        "name": f"simulated {recipe} run (seed {seed})",
        "rotation_step_deg": rotation_step,
    }
    sections = {
        "rgb": {
            "cameras": cameras,
            "bit_depth": int(rgb.attrs["bit_depth"]),
            "paired_camera": paired,
            "models": {c: "Nikon 5100 (NPL)" for c in cameras},  # the simulator's one sensor model
        },
        "spectral": {"camera": SPECTRAL_CAMERA, "bit_depth": int(spectral.attrs["bit_depth"])},
        "exposure_plan": {k: float(plan.attrs[k]) for k in ("t0", "s0", "omega")},
        # the simulated cameras' frames of the chart are one rectified view: one label image
        "colour_checker": {
            "patch_index": "calibration/colour_checker_patches.png",
            "shared_patch_index": True,
        }
        | ({"chart": str(checker.attrs["chart"])} if chart_by_name else {}),
        "source": {
            "simulator": "spectralize.datasets.capture.sample",
            "recipe": recipe,
            "seed": int(seed),
        },
    }
    write_config(
        path,
        config,
        sections,
        comments=(
            "Capture folder written by spectralize.datasets.capture.sample (simulated gantry run).",
            "Format: datasets/README.md, 'Capture folders'.",
        ),
    )


def _image_blocks(counts: xr.DataArray) -> list[tuple[int, int]]:
    """``(start, stop)`` of the image chunks of lazy counts (one block if in memory)."""
    chunks = counts.chunks
    sizes = dict(zip(counts.dims, chunks, strict=True))["image"] if chunks else (counts.sizes["image"],)
    stops = np.cumsum(sizes).tolist()
    return list(zip([0, *stops[:-1]], stops, strict=True))


def _camera_thetas(rgb: xr.Dataset) -> list[float]:
    """Polar angle of each RGB camera index (from the images it took)."""
    camera = np.asarray(rgb["camera"].values)
    theta = np.asarray(rgb["theta_o"].values)
    return [float(theta[camera == c][0]) for c in range(int(camera.max()) + 1)]


def _write_calibration(folder: Path, groups: dict[str, xr.Dataset], *, chart_by_name: bool) -> None:
    white = groups["raw/white_reference"]
    checker = groups["raw/colour_checker"]
    plan = groups["raw/exposure_plan"]
    wavelength = np.asarray(white["wavelength"].values, dtype=float)
    write_table(
        folder / "illuminant.csv",
        ("wavelength_nm", "value"),
        zip(wavelength, np.asarray(white["illuminant"].values, dtype=float), strict=True),
    )
    write_table(
        folder / "white_reference.csv",
        ("wavelength_nm", "reflectance"),
        zip(wavelength, np.asarray(white["target_reflectance"].values, dtype=float), strict=True),
    )
    if not chart_by_name:
        reflectance = np.asarray(checker["patch_reflectance"].values, dtype=float)
        names = [str(n) for n in checker["patch_name"].values]
        write_table(
            folder / "colour_checker.csv",
            ("patch", "wavelength_nm", "reflectance"),
            (
                (name, wl, reflectance[p, w])
                for p, name in enumerate(names)
                for w, wl in enumerate(wavelength)
            ),
        )
    # patch k (1-based, in the order of colour_checker.csv / the chart) under each RGB pixel, 0: frame
    write_png(folder / "colour_checker_patches.png", np.asarray(checker["patch_index"].values) + 1)
    write_table(
        folder / "exposure_plan.csv",
        ("wavelength_nm", "exposure_time_s", "filter_size_px"),
        zip(
            np.asarray(plan["wavelength"].values, dtype=float),
            np.asarray(plan["exposure_time_quantised"].values, dtype=float),
            np.asarray(plan["filter_size"].values, dtype=float),
            strict=True,
        ),
    )


def main(argv: list[str] | None = None) -> int:
    """``python -m spectralize.datasets.capture.sample OUT [--recipe tiny] [--seed 0]``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog="python -m spectralize.datasets.capture.sample",
        description="Write a sample capture folder (simulated gantry run) in the documented format.",
    )
    parser.add_argument("out", help="folder to write")
    parser.add_argument("--recipe", default="tiny", help="tiny (default) or demo")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--chart-by-name", action="store_true", help="name the chart in capture.toml")
    args = parser.parse_args(argv)
    write_capture_folder(
        args.out, recipe=args.recipe, seed=args.seed, chart_by_name=args.chart_by_name, progress=print
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
