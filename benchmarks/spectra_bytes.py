"""Benchmark of the bytes a reconstructed cube takes in a run store: lossless vs its precision.

Run from the repository root::

    .venv/bin/python benchmarks/spectra_bytes.py [--size 256] [--images 4]

Real reconstructed radiance, not random numbers: per scene, a set of ``--images`` images of
``--size``^2 px is simulated and reconstructed with the default method (eq. 1), and its cube
is written to a run store twice, side by side in one process, the way
``reconstruct_image_sets`` writes ``spectra`` (tiles of ``DISK_TILE`` px, resumable along
``image``, packed into shards):

``before``  the contract without a precision: float32 with zarr's default zstd, as every
            store was written before the cube declared one;
``after``   the ``spectra`` contract: values rounded to ``SPECTRA_PRECISION`` mantissa bits,
            Blosc zstd on bit planes (``spectralize.store.precision``).

and a third time with the alternative contract ``per_spectrum_peak``: the values of each
pixel's spectrum rounded to one quantum, ``2 ** -(keepbits + 1)`` of the spectrum's peak
(``Precision(keepbits, along="wavelength")``, a scale to integers per spectrum: a band far
below its pixel's peak keeps fewer bits), with the same codecs; its largest error is
reported relative to the stored peak, and its store checked against that contract.

Scenes: ``texture`` and ``voronoi`` of ``benchmarks/reconstruction_scene.py`` (the codec was
chosen on these) and, held out of that choice, the hard scenes of
``spectralize.nodes.simulation.scenes``, reported apart. Per scene and side: bytes of the
``radiance`` array per Mpx-image (the whole group beside it), write and read seconds; for
``after`` also the largest relative error of a stored value against the computed one (finite,
non-zero values), that over the stated bound, and whether ``validate(deep=True)`` passes.
The LAST line is one JSON object, also written to ``benchmarks/results/spectra_bytes.json``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "spectra_bytes.json"
sys.path.insert(0, str(HERE))

from reconstruction_scene import simulate_capture  # noqa: E402

from spectralize.nodes.reconstruction import reconstruct  # noqa: E402
from spectralize.nodes.reconstruction.set_reconstruction import DISK_TILE  # noqa: E402
from spectralize.nodes.simulation.scenes import SCENES, get_scene  # noqa: E402
from spectralize.schemas import GroupSchema, Precision, validate_dataset  # noqa: E402
from spectralize.schemas.run import SPECTRA, SPECTRA_PRECISION  # noqa: E402
from spectralize.store import RunStore  # noqa: E402
from spectralize.store.precision import precision_problems  # noqa: E402

CHOICE_SCENES = ("texture", "voronoi")
LOSSLESS = dataclasses.replace(
    SPECTRA, variables=tuple(dataclasses.replace(s, precision=None) for s in SPECTRA.variables)
)
PEAK_PRECISION = Precision(SPECTRA_PRECISION.keepbits, along="wavelength")
PEAK = dataclasses.replace(
    SPECTRA,
    variables=tuple(dataclasses.replace(s, precision=PEAK_PRECISION) for s in SPECTRA.variables),
)


def log(message: str) -> None:
    print(message, flush=True)


def reconstructed_cube(scene: str, size: int, images: int, seed: int) -> xr.Dataset:
    """The reconstructed cube of a simulated set, as the ``spectra`` group holds it."""
    if scene in CHOICE_SCENES:
        capture = simulate_capture(size, n_images=images, scene=scene, seed=seed)
        rgb, bands, camera = capture.rgb, capture.bands, capture.camera_matrix
    else:
        hard = get_scene(scene, size=size, seed=seed, n_images=images)
        rgb, bands, camera = hard.rgb, hard.bands, hard.camera_matrix
    spectra = reconstruct(rgb, bands, camera)
    values = np.asarray(spectra.transpose("image", "wavelength", "y", "x").values, dtype=np.float32)
    n = values.shape[0]
    per_image = {name: ("image", np.zeros(n, int)) for name in ("camera", "rotation", "led")}
    angles = {
        name: ("image", np.zeros(n), {"units": "degree"})
        for name in ("theta_i", "phi_i", "theta_o", "phi_o")
    }
    return xr.Dataset(
        {"radiance": (("image", "wavelength", "y", "x"), values, SPECTRA.spec("radiance").attrs)},
        coords={
            "wavelength": (
                "wavelength",
                np.asarray(spectra["wavelength"].values, float),
                {"units": "nm"},
            ),
            **per_image,
            **angles,
        },
    )


def write_side(store: RunStore, cube: xr.Dataset, schema: GroupSchema) -> dict:
    """Write ``cube`` as the node writes ``spectra``; its bytes, times and what it stored."""
    tiles = {"y": min(DISK_TILE, cube.sizes["y"]), "x": min(DISK_TILE, cube.sizes["x"])}
    start = time.perf_counter()
    store.write(
        "spectra",
        cube.chunk({"image": 1}),
        schema=schema,
        fingerprint="fp",
        chunks=tiles,
        resumable_along="image",
    )
    write_s = time.perf_counter() - start
    start = time.perf_counter()
    stored = store.read("spectra")["radiance"].values
    read_s = time.perf_counter() - start
    root = store.path / "spectra"
    array_bytes = sum(p.stat().st_size for p in (root / "radiance").rglob("*") if p.is_file())
    mpx_images = cube.sizes["image"] * cube.sizes["y"] * cube.sizes["x"] / 1e6
    codecs = json.loads((root / "radiance" / "zarr.json").read_text())["codecs"]
    inner = codecs[0]["configuration"]["codecs"] if codecs[0]["name"] == "sharding_indexed" else codecs
    return {
        "radiance_bytes_per_mpx_image": round(array_bytes / mpx_images),
        "group_bytes_per_mpx_image": round(store.size_on_disk("spectra") / mpx_images),
        "of_raw_float32": round(array_bytes / cube["radiance"].nbytes, 4),
        "codecs": [c["name"] for c in inner],
        "write_s": round(write_s, 3),
        "read_s": round(read_s, 3),
        "stored": stored,
    }


def scene_row(scene: str, size: int, images: int, seed: int, work: Path) -> dict:
    start = time.perf_counter()
    cube = reconstructed_cube(scene, size, images, seed)
    solve_s = time.perf_counter() - start
    computed = cube["radiance"].values
    row: dict = {"scene": scene, "size": size, "images": images, "solve_s": round(solve_s, 2)}
    finite = np.isfinite(computed)
    nonzero = finite & (computed != 0)
    for side, schema in (("before", LOSSLESS), ("after", SPECTRA), ("per_spectrum_peak", PEAK)):
        store = RunStore.create(work / f"{scene}-{side}.zarr")
        result = write_side(store, cube, schema)
        stored = result.pop("stored")
        error = np.abs(stored[nonzero].astype(np.float64) - computed[nonzero]) / np.abs(
            computed[nonzero]
        )
        result["max_relative_error"] = float(error.max()) if error.size else 0.0
        result["identical"] = bool(np.array_equal(stored, computed, equal_nan=True))
        if side == "after":
            result["within_bound"] = result["max_relative_error"] <= SPECTRA_PRECISION.relative_bound
            result["validate_deep_problems"] = len(store.validate(deep=True))
        if side == "per_spectrum_peak":
            peak = np.abs(np.where(finite, stored, 0)).max(axis=1, keepdims=True)
            of_peak = np.where(finite, np.abs(stored.astype(np.float64) - computed), 0) / np.where(
                peak > 0, peak, 1
            )
            result["max_error_of_stored_peak"] = float(of_peak.max())
            result["within_bound"] = result["max_error_of_stored_peak"] <= PEAK_PRECISION.relative_bound
            raw = store.read("spectra", friendly=False)
            result["validate_deep_problems"] = len(
                validate_dataset(raw, PEAK)
                + precision_problems(store.path / "spectra", raw, PEAK, "spectra", deep=True)
            )
        row[side] = result
    for side in ("after", "per_spectrum_peak"):
        row[side]["ratio"] = round(
            row[side]["radiance_bytes_per_mpx_image"] / row["before"]["radiance_bytes_per_mpx_image"],
            4,
        )
    row["ratio"] = row["after"]["ratio"]
    before, after = row["before"], row["after"]
    log(
        f"{scene:16s} {images}x{size}^2: "
        f"before {before['radiance_bytes_per_mpx_image'] / 1e6:.2f} MB/Mpx-image "
        f"({before['of_raw_float32']:.3f} of raw), "
        f"after {after['radiance_bytes_per_mpx_image'] / 1e6:.2f} MB/Mpx-image: "
        f"ratio {row['ratio']:.3f}; max relative error {after['max_relative_error']:.3e} "
        f"(bound {SPECTRA_PRECISION.relative_bound:.3e}); "
        f"write {before['write_s']:.2f} -> {after['write_s']:.2f} s, "
        f"read {before['read_s']:.2f} -> {after['read_s']:.2f} s; per spectrum peak: ratio "
        f"{row['per_spectrum_peak']['ratio']:.3f}"
    )
    return row


def summary(rows: list[dict]) -> dict:
    before = sum(r["before"]["radiance_bytes_per_mpx_image"] for r in rows)
    after = sum(r["after"]["radiance_bytes_per_mpx_image"] for r in rows)
    return {
        "scenes": [r["scene"] for r in rows],
        "bytes_per_mpx_image_before": round(before / len(rows)),
        "bytes_per_mpx_image_after": round(after / len(rows)),
        "ratio_mean": round(after / before, 4),
        "ratio_worst": max(r["ratio"] for r in rows),
        "max_relative_error": max(r["after"]["max_relative_error"] for r in rows),
        "all_within_bound": all(r["after"]["within_bound"] for r in rows),
        "all_validate": all(r["after"]["validate_deep_problems"] == 0 for r in rows),
        "per_spectrum_peak_ratio_mean": round(
            sum(r["per_spectrum_peak"]["radiance_bytes_per_mpx_image"] for r in rows) / before, 4
        ),
        "per_spectrum_peak_ratio_worst": max(r["per_spectrum_peak"]["ratio"] for r in rows),
        "per_spectrum_peak_all_within_bound": all(r["per_spectrum_peak"]["within_bound"] for r in rows),
        "per_spectrum_peak_all_validate": all(
            r["per_spectrum_peak"]["validate_deep_problems"] == 0 for r in rows
        ),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256)
    parser.add_argument("--images", type=int, default=4)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for scene in (*CHOICE_SCENES, *SCENES):
            rows.append(scene_row(scene, args.size, args.images, args.seed, Path(tmp)))
    choice = [r for r in rows if r["scene"] in CHOICE_SCENES]
    held_out = [r for r in rows if r["scene"] not in CHOICE_SCENES]
    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE
    ).stdout.strip()
    result = {
        "benchmark": "spectra_bytes",
        "command": " ".join(["benchmarks/spectra_bytes.py", *sys.argv[1:]]),
        "commit": head,
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cpu_count": os.cpu_count(), "python": sys.version.split()[0]},
        "load_average": round(os.getloadavg()[0], 2),
        "keepbits": SPECTRA_PRECISION.keepbits,
        "relative_bound": SPECTRA_PRECISION.relative_bound,
        "per_spectrum_peak_bound": PEAK_PRECISION.relative_bound,
        "target_ratio": 0.4,
        "choice": summary(choice),
        "held_out": summary(held_out),
        "scenes": rows,
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
