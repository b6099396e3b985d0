"""The run's endmember library in the reconstruction benchmark: several sets of a scene ->
one library -> each set.

Run from the repository root::

    .venv/bin/python benchmarks/reconstruction_run_library.py            # 20 x 48^2 sets
    .venv/bin/python benchmarks/reconstruction_run_library.py --quick    # 20 x 32^2, seed 0

A run images one sample in many sets; the hard suite (``reconstruction_hard.py``) solves one
set alone, so its default learns the endmember library from that set's band shots. Here each
hard scene x seed is a run of ``1 + --other-sets`` sets of 20 images (default: the
``endmember_library`` node's ``sets``, 8): the hard suite's set (``get_scene(name, size,
seed, n_images=20)``, the same capture) and sets of the same sample (same layout) with their
own capture noise and every light turned by ``37 k`` degrees in azimuth (set ``k``). The
library is learnt from all of them pooled, as the ``endmember_library`` node learns it
(:func:`~spectralize.nodes.reconstruction.endmember_library.library_from_sample`), and the
hard suite's set is solved with it (``reconstruct(..., endmembers=...)``), beside the same
set solved with its own library (the hard suite's default row). Both with the scene's true
illuminant. With the run's library the default's set model ``"evidence-blend"`` weighs in
each texel's material choice by the band evidence; with the set's own it stops after the
pooled refit, and ``material-pooled+run-library`` is the default with that set model (the
default before the choice was weighed in). The same with ``"sparse-choice"`` (each texel's
materials chosen over its set, six candidates), with the set's own and the run's library,
and, mixed with ``material-pooled+run-library``: a blend of :data:`BLEND` x the choice, a
blend weighted per texel by which of the two fits the texel's band shots better
(:data:`BAND_WEIGHTS`), and the posterior blend of the default's set step with this
six-candidate choice (``evidence-blend``; its seconds are the two solves' and the blend's).
Per row: the per-pixel
nRMSE (median, p95, fraction < 0.03; images with and without band shots), relit CIEDE2000
under A, FL11 and D65 (median / p95), wall seconds; per library: the spectral angle of each
true endmember to the nearest learnt one (median over all materials, area-weighted median,
median over the dominant materials: at least 20 texels of fraction >= 0.9), as the
``material choice`` research reports it. The oracles ``present`` and ``nearest-3`` of the
set (true endmembers, RGB alone; see ``reconstruction_oracle.py``) are given for seed 0.

The LAST line is one JSON object, also written to
``benchmarks/results/reconstruction_run_library.json`` (``--output`` to choose).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import xarray as xr

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from reconstruction_hard import nrmse_per_pixel, relit_colour, scene_illuminant, statistics  # noqa: E402

import spectralize.nodes.simulation.scenes as scenes  # noqa: E402
from spectralize.nodes.reconstruction import DEFAULT_METHOD, reconstruct  # noqa: E402
from spectralize.nodes.reconstruction.endmember_library import (  # noqa: E402
    DEFAULT_LIBRARY_SETS,
    library_from_sample,
)
from spectralize.nodes.reconstruction.estimators.endmember_mixture import (  # noqa: E402
    Endmembers,
    chromaticity,
    rgb_abundances,
)
from spectralize.nodes.simulation.scenes.layout import box_average  # noqa: E402

RESULTS = HERE / "results" / "reconstruction_run_library.json"
CHOICE = "sparse-choice"
"""The method that chooses each texel's materials over its set, with a set's own and the
run's library."""
BLEND = 0.25
"""Weight of ``"sparse-choice"``'s spectra in the blend row (the rest the default's, both with
the run library): chosen on woven, halftone and glossy (the largest weight of 0.25, 0.5,
0.75 that lowered neither median nor p95 there), dark-still-life held out."""
BAND_WEIGHTS = (0.5, 0.1)
"""Weights of the choice in the band-weighted blend where its spectra fit the texel's band
shots better than the default's, and elsewhere (chosen as :data:`BLEND`)."""
POOLED = "material-pooled"
"""The default's set model before ``"evidence-blend"`` (its set step without the choice): the
blends below mix the choice with the default solved with it."""
ROWS = (
    "default",
    "default+run-library",
    f"{POOLED}+run-library",
    CHOICE,
    f"{CHOICE}+run-library",
    "blend+run-library",
    "band-weighted-blend+run-library",
    "evidence-blend+run-library",
)
"""The rows of each case: the default and ``"sparse-choice"``, each with the set's own
library and with the run's, and their blends with the run's (fixed, band-weighted, and
weighed per texel by the posterior of the band evidence,
:func:`~spectralize.nodes.reconstruction.estimators.evidence_blend.evidence_blend`)."""
TURN_DEG = 37.0
"""Azimuth by which set ``k``'s lights are turned (``k`` times)."""


@contextlib.contextmanager
def lights_turned(k: int):
    """:func:`~spectralize.nodes.simulation.scenes.set_geometry` with every light turned by
    ``TURN_DEG * k`` degrees in azimuth, while in the block."""
    original = scenes.set_geometry

    def turned(n_images: int, images_with_bands: int) -> list[dict]:
        return [
            {**g, "phi_i": (g["phi_i"] + TURN_DEG * k) % 360.0}
            for g in original(n_images, images_with_bands)
        ]

    scenes.set_geometry = turned
    try:
        yield
    finally:
        scenes.set_geometry = original


def run_sets(name: str, seed: int, size: int, others: int) -> list:
    """The hard suite's set of ``seed`` and ``others`` more sets of the same sample."""
    sets = [scenes.get_scene(name, size=size, seed=seed, n_images=20)]
    for k in range(1, others + 1):
        with lights_turned(k):
            sets.append(scenes.get_scene(name, size=size, seed=1000 * (seed + 1) + k, n_images=20))
    return sets


def pooled_library(sets: list) -> Endmembers:
    """The library learnt from every set's images and band shots, pooled (images renumbered)."""
    rgbs, shots = [], []
    offset = 0
    for capture in sets:
        n = capture.rgb.sizes["image"]
        rgb = capture.rgb.drop_vars(["theta_i", "phi_i", "theta_o", "phi_o"], errors="ignore")
        rgbs.append(rgb.assign_coords(image=np.arange(offset, offset + n)))
        shots.append(capture.bands.assign_coords(image=("shot", capture.bands["image"].values + offset)))
        offset += n
    rgb = xr.concat(rgbs, "image")
    bands = xr.concat(shots, "shot")
    learnt, _ = library_from_sample(rgb, bands, sets[0].camera_matrix)
    return learnt


def true_endmembers(capture) -> tuple[np.ndarray, np.ndarray]:
    """The scene's true endmembers (reflectance x LED) ``(J, w)`` and each texel's material
    fractions ``(texels, J)``."""
    layout = capture.layout
    led = scene_illuminant(capture)
    fractions = np.stack(
        [
            box_average((layout.label == j).astype(float), layout.supersample).ravel()
            for j in range(layout.reflectance.shape[0])
        ]
    ).T
    return layout.reflectance * led[None], fractions


def library_angles(atoms: np.ndarray, capture) -> dict:
    """Angles [degree] of each true endmember to the nearest learnt one (highlight left out)."""
    true, fractions = true_endmembers(capture)
    a = atoms[:-1] / np.maximum(np.linalg.norm(atoms[:-1], axis=1, keepdims=True), 1e-300)
    t = true / np.maximum(np.linalg.norm(true, axis=1, keepdims=True), 1e-300)
    angle = np.degrees(np.arccos(np.clip(t @ a.T, -1.0, 1.0))).min(axis=1)
    area = fractions.sum(axis=0)
    order = np.argsort(angle)
    weighted = angle[order][np.searchsorted(np.cumsum(area[order]) / area.sum(), 0.5)]
    label = np.where(fractions.max(axis=1) >= 0.9, fractions.argmax(axis=1), -1)
    dominant = np.bincount(label[label >= 0], minlength=true.shape[0]) >= 20
    return {
        "all_median": round(float(np.median(angle)), 2),
        "area_weighted_median": round(float(weighted), 2),
        "dominant_median": round(float(np.median(angle[dominant])), 2) if dominant.any() else None,
        "materials": int(true.shape[0]),
        "dominant_materials": int(dominant.sum()),
    }


def solve(
    capture, endmembers: Endmembers | None, method: str = DEFAULT_METHOD, **given
) -> tuple[dict, xr.DataArray]:
    """``method`` on ``capture`` (its own library, or ``endmembers``; ``given`` options):
    scores and seconds, and the spectra."""
    options = {**given} if endmembers is None else {"endmembers": endmembers, **given}
    wall = time.perf_counter()
    spectra = reconstruct(
        capture.rgb,
        capture.bands,
        capture.camera_matrix,
        method=method,
        illuminant=scene_illuminant(capture),
        **options,
    )
    return scores(spectra, capture, time.perf_counter() - wall), spectra


def scores(spectra: xr.DataArray, capture, wall: float) -> dict:
    """nRMSE statistics (all images, with and without band shots), relit colour, seconds."""
    e = nrmse_per_pixel(spectra.values, capture.truth.values)
    have = capture.images_with_bands
    lack = np.setdiff1d(np.arange(e.shape[0]), have)
    relit, _ = relit_colour(spectra, capture)
    return {
        **statistics(e),
        "with_bands": statistics(e[have]),
        "without_bands": statistics(e[lack]),
        "relit_de2000": relit,
        "wall_s": round(wall, 3),
    }


def band_weights(capture, chosen: np.ndarray, default: np.ndarray) -> xr.DataArray:
    """Per texel the weight of the choice in the band-weighted blend: ``BAND_WEIGHTS[0]``
    where the choice's spectra fit the texel's band shots (all of the set's, chi^2 with each
    shot's noise) better than the default's, ``BAND_WEIGHTS[1]`` elsewhere; ``(y, x)``."""
    from spectralize.nodes.reconstruction import inputs_from_xarray
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import band_noise_sigma

    inputs = inputs_from_xarray(capture.rgb, capture.bands, capture.camera_matrix)
    sigma = band_noise_sigma(inputs)
    misfit = np.zeros((2, inputs.height, inputs.width))
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image, strict=True)):
        shot = inputs.band_data[i].astype(np.float64)
        for k, cube in enumerate((chosen, default)):
            misfit[k] += (cube[m, b] - shot) ** 2 / sigma[i] ** 2
    weight = np.where(misfit[0] < misfit[1], *BAND_WEIGHTS)
    return xr.DataArray(weight, dims=("y", "x"))


def posterior_blend(capture, chosen: xr.DataArray, default: xr.DataArray, wall: float) -> dict:
    """Scores of the evidence blend of the choice's and the default's spectra (both with the
    run's library), and the share of texels the choice holds more than half of."""
    from spectralize.nodes.reconstruction import inputs_from_xarray
    from spectralize.nodes.reconstruction.estimators.evidence_blend import evidence_blend

    started = time.perf_counter()
    inputs = inputs_from_xarray(capture.rgb, capture.bands, capture.camera_matrix)
    order = ("wavelength", "image", "y", "x")
    cube, pi = evidence_blend(inputs, default.transpose(*order).values, chosen.transpose(*order).values)
    spectra = default.transpose("image", "wavelength", "y", "x").copy(data=np.moveaxis(cube, 0, 1))
    row = scores(spectra, capture, wall + time.perf_counter() - started)
    row["choice_weight_mean"] = round(float(np.mean(1.0 - pi)), 4)
    row["choice_majority_fraction"] = round(float(np.mean(pi < 0.5)), 4)
    return row


def oracles(capture) -> dict:
    """``present`` and ``nearest-3`` of the set: mixtures of the true endmembers and the LED
    weighted by each image's RGB alone (exact NNLS), projected onto ``C S = R``."""
    from scipy.optimize import nnls

    from spectralize.nodes.reconstruction.baselines.projection import project_onto_rgb

    true, fractions = true_endmembers(capture)
    atoms = np.vstack([true, scene_illuminant(capture)[None]])
    c = capture.camera_matrix.values.astype(np.float64)
    projected = atoms @ c.T
    n_material = true.shape[0]
    rgb = np.moveaxis(capture.rgb.values.astype(np.float64), -1, 1)  # (image, 3, y, x)
    n_image, _, h, w = rgb.shape
    pixels = rgb.reshape(n_image, 3, -1).transpose(0, 2, 1)  # (image, texel, 3)
    present = np.empty((n_image, h * w, atoms.shape[1]))
    for p in range(h * w):
        use = np.append(np.flatnonzero(fractions[p] > 0), n_material)
        for m in range(n_image):
            weights, _ = nnls(projected[use].T, pixels[m, p])
            present[m, p] = weights @ atoms[use]
    flat = pixels.reshape(-1, 3)
    scale = np.abs(flat.mean(axis=0))
    _, chroma = chromaticity(flat, scale)
    _, centres = chromaticity(projected[:n_material], scale=scale)
    endmembers = Endmembers(atoms, centres, scale)
    near = endmembers.candidates(chroma, 3)
    weights = rgb_abundances(endmembers, near, c, flat)
    nearest = np.einsum("pk,pkw->pw", weights, atoms[near]).reshape(n_image, h * w, -1)
    out = {}
    for key, spectra in (("present", present), ("nearest-3", nearest)):
        cube = np.ascontiguousarray(np.moveaxis(spectra.reshape(n_image, h, w, -1), -1, 0))
        project_onto_rgb(cube, c, rgb.transpose(1, 0, 2, 3), overwrite=True)
        out[key] = statistics(nrmse_per_pixel(np.moveaxis(cube, 0, 1), capture.truth.values))
    return out


def run_case(name: str, seed: int, size: int, others: int, with_oracles: bool) -> dict:
    sets = run_sets(name, seed, size, others)
    capture = sets[0]
    own, _ = solve(capture, None)
    from spectralize.nodes.reconstruction import inputs_from_xarray
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import set_endmembers

    own_library = set_endmembers(inputs_from_xarray(capture.rgb, capture.bands, capture.camera_matrix))
    wall = time.perf_counter()
    library = pooled_library(sets)
    library_s = time.perf_counter() - wall
    run, _ = solve(capture, library)
    pooled, run_spectra = solve(capture, library, set_model=POOLED)
    rows = {"default": own, "default+run-library": run, f"{POOLED}+run-library": pooled}
    rows[CHOICE], _ = solve(capture, None, CHOICE)
    rows[f"{CHOICE}+run-library"], chosen = solve(capture, library, CHOICE)
    blend = BLEND * chosen + (1.0 - BLEND) * run_spectra
    wall = rows[f"{POOLED}+run-library"]["wall_s"] + rows[f"{CHOICE}+run-library"]["wall_s"]
    rows["blend+run-library"] = scores(blend, capture, wall)
    weight = band_weights(capture, chosen.values, run_spectra.values)
    mixed = (weight * chosen + (1.0 - weight) * run_spectra).transpose(*chosen.dims)
    rows["band-weighted-blend+run-library"] = scores(mixed, capture, wall)
    rows["evidence-blend+run-library"] = posterior_blend(capture, chosen, run_spectra, wall)
    case = {
        "scene": name,
        "seed": seed,
        "size": size,
        "sets_pooled": len(sets),
        "library_s": round(library_s, 3),
        "angles": {
            "own": library_angles(own_library.atoms, capture),
            "run": library_angles(library.atoms, capture),
        },
        "methods": rows,
    }
    if with_oracles:
        case["oracles"] = oracles(capture)
    angles = case["angles"]
    print(
        f"[{time.strftime('%H:%M:%S')}] {name:16s} seed {seed}: "
        f"own {own['median']:.4f}/{own['p95']:.3f}/{own['fraction_under_0.03']:.3f}, "
        f"run library {run['median']:.4f}/{run['p95']:.3f}/{run['fraction_under_0.03']:.3f}; "
        f"sparse-choice {rows[CHOICE]['median']:.4f}/{rows[CHOICE]['p95']:.3f}, with the run "
        f"library {rows[CHOICE + '+run-library']['median']:.4f}/"
        f"{rows[CHOICE + '+run-library']['p95']:.3f}; "
        f"angles own {angles['own']}, run {angles['run']}",
        flush=True,
    )
    return case


def summarise(cases: list[dict]) -> dict:
    """Per scene, the worse seed of each row and the ratio run library / own library."""
    out = {}
    for name in dict.fromkeys(c["scene"] for c in cases):
        chosen = [c for c in cases if c["scene"] == name]
        rows = {}
        for method in ROWS:
            rows[method] = {
                "median": max(c["methods"][method]["median"] for c in chosen),
                "p95": max(c["methods"][method]["p95"] for c in chosen),
                "fraction_under_0.03": min(c["methods"][method]["fraction_under_0.03"] for c in chosen),
                "relit_de2000": {
                    light: {
                        k: max(c["methods"][method]["relit_de2000"][light][k] for c in chosen)
                        for k in ("median", "p95")
                    }
                    for light in chosen[0]["methods"][method]["relit_de2000"]
                },
            }
        ratios = {
            method: {
                k: round(max(c["methods"][method][k] / c["methods"]["default"][k] for c in chosen), 3)
                for k in ("median", "p95")
            }
            for method in ROWS[1:]
        }
        out[name] = {
            **rows,
            "run_vs_own_max_ratio": ratios["default+run-library"],
            "vs_default_max_ratio": ratios,
        }
    return out


def commit() -> str | None:
    """The repository's HEAD commit (short), if there is one."""
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True, check=True
        )
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip() or None


def main() -> None:
    from spectralize.nodes.simulation.scenes import SCENES

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="20 x 32^2 sets, seed 0")
    parser.add_argument("--size", type=int, default=None)
    parser.add_argument(
        "--other-sets",
        type=int,
        default=DEFAULT_LIBRARY_SETS - 1,
        help="sets pooled besides the solved one (default: the node's, less the solved set)",
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=None)
    parser.add_argument("--output", type=Path, default=RESULTS, help="where the JSON goes")
    args = parser.parse_args()
    size = args.size or (32 if args.quick else 48)
    seeds = tuple(args.seeds or ((0,) if args.quick else (0, 1)))
    started = time.perf_counter()
    cases = [
        run_case(name, seed, size, args.other_sets, with_oracles=seed == seeds[0])
        for name in SCENES
        for seed in seeds
    ]
    report = {
        "benchmark": "the run's endmember library: several sets of a scene -> library -> each set",
        "size": f"20 x {size}^2",
        "seeds": list(seeds),
        "sets_pooled": 1 + args.other_sets,
        "turn_deg": TURN_DEG,
        "summary": summarise(cases),
        "cases": cases,
        "total_seconds": round(time.perf_counter() - started, 1),
        "commit": commit(),
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count()},
    }
    args.output.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
