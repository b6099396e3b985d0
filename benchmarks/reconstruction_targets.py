"""The reconstruction's scorecard: every target on every row, beside the oracles and the
noise-free limit.

Run from the repository root::

    .venv/bin/python benchmarks/reconstruction_targets.py           # every scene x seeds 0, 1
    .venv/bin/python benchmarks/reconstruction_targets.py --quick   # one scene, seed 0, tiny

Rows: every hard scene x seed, as a single image (the hard suite's, 128^2) and as a set (the
hard suite's 20 x 48^2 set; dark-still-life is the held-out scene of every choice and is
reported apart). Per row, side by side:

- ``default``: what ``run btf`` runs: on a single image :data:`DEFAULT_METHOD`; on a set
  :data:`DEFAULT_METHOD` with the run's endmember library, learnt from the run of
  ``1 + --other-sets`` sets of ``reconstruction_run_library.py`` (the hard suite's set and
  sets of the same sample with their own noise and the lights turned). Solved here and
  compared with the stored row (``stored_default``) of ``reconstruction.json`` (single) or
  ``reconstruction_run_library.json`` (``default+run-library``, set);
- ``others``: every other preset of ``RECONSTRUCTION_METHODS`` and every baseline of
  ``BASELINE_METHODS`` (HySure and CNMF included) on the same captures, read from the hard
  suite's ``reconstruction.json``, except :data:`FRESH_PRESETS` (changed since that run),
  solved here; on a set also ``sparse-choice+run-library``, solved here. The default's own
  set models (``independent``, ``shared-texel``, and the default with the set's own library)
  are its variants, not rivals; the last is kept as ``default_own_library``. Where the stored
  JSON does not hold the row's size (``--quick``), :data:`QUICK_RIVALS` are solved instead;
- ``oracles``: ``present`` and ``nearest-3`` on the same inputs (the true endmembers weighted
  by the RGB alone, :func:`reconstruction_run_library.oracles`);
- ``noise_free``: the default on the same capture with noise-free band shots and the true HDR
  RGB (``C S``); on a set with the library learnt from the run's sets made noise-free alike:
  what the default reaches with perfect measurements. On a single image also the stored
  ``default_on_noise_free_bands`` (noise-free bands, the captured RGB) of the hard suite;
- ``targets``: each target of the issue, met or missed and by how much (ratio or points):
  set median <= 2x ``present``; set fraction under 0.03 >= 75 % (glossy, dark) or 40 %
  (woven, halftone); the default <= every other preset and baseline at the median and p95;
  set relit CIEDE2000 median <= 1.0 and p95 <= 3.0 under A and FL11; a set's images without
  band shots within 1.1x of those with them (median and p95);
- ``best_at``: per method, the rows and statistics (median, p95) where it is the best of all.

Per-pixel nRMSE as the hard suite measures it (:func:`reconstruction_hard.nrmse_per_pixel`).
The LAST line is one JSON object, also written to
``benchmarks/results/reconstruction_targets.json`` (``--output`` to choose).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from reconstruction_hard import RELIT_TARGET_LIGHTS, TARGETS, run_method, scene_illuminant  # noqa: E402
from reconstruction_run_library import oracles, pooled_library, run_sets  # noqa: E402

from spectralize.nodes.reconstruction import (  # noqa: E402
    BASELINE_METHODS,
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
)
from spectralize.nodes.reconstruction.endmember_library import DEFAULT_LIBRARY_SETS  # noqa: E402
from spectralize.nodes.simulation.scenes import SCENES, get_scene  # noqa: E402

RESULTS = HERE / "results"
OUTPUT = RESULTS / "reconstruction_targets.json"
HELD_OUT = "dark-still-life"
"""The scene kept out of every choice of the default."""
FRESH_PRESETS = ("sparse-choice",)
"""Presets whose code changed since the stored hard-suite run: solved here on every row."""
QUICK_RIVALS = ("wiener", "mixture-prior-pcg")
"""Rivals solved here where the stored JSON lacks the row's size (``--quick``)."""
RUN_LIBRARY_RIVAL = "sparse-choice+run-library"
"""The set rival solved with the run's library (``sparse-choice`` given ``endmembers``)."""
GLOSSY_DARK = ("glossy-mosaic", "dark-still-life")
"""The scenes of the 75 % target (the others: 40 %)."""


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def git(*args: str) -> str | None:
    """A git command's output in the repository, or ``None``."""
    try:
        out = subprocess.run(["git", *args], cwd=HERE, capture_output=True, text=True, check=True)
    except (OSError, subprocess.CalledProcessError):
        return None
    return out.stdout.strip()


def noise_free(capture):
    """``capture`` with noise-free band shots (the truth at each shot's band and image) and
    the true HDR RGB (``C S`` of the truth)."""
    truth = capture.truth.values.astype(np.float64)
    c = capture.camera_matrix.values.astype(np.float64)
    rgb = np.einsum("cw,mwyx->myxc", c, truth)
    band = np.searchsorted(
        capture.camera_matrix["wavelength"].values, capture.bands["wavelength"].values
    )
    shots = truth[capture.bands["image"].values, band]
    return dataclasses.replace(
        capture,
        rgb=capture.rgb.copy(data=rgb.astype(capture.rgb.dtype)),
        bands=capture.bands.copy(data=shots.astype(capture.bands.dtype)),
    )


def load(name: str) -> dict:
    path = RESULTS / f"{name}.json"
    return json.loads(path.read_text()) if path.exists() else {}


def stored_case(stored: dict, scene: str, seed: int, n_images: int, size: int) -> dict | None:
    """The hard suite's case of the row, if its JSON holds it at this size."""
    for case in stored.get("cases", []):
        if (case["scene"], case["seed"], case["n_images"], case["size"]) == (
            scene,
            seed,
            n_images,
            size,
        ):
            return case
    return None


def stored_rivals(case: dict | None) -> dict:
    """Every other preset and baseline of a stored hard-suite case (not the default, its set
    variants or :data:`FRESH_PRESETS`)."""
    if case is None:
        return {}
    wanted = set(RECONSTRUCTION_METHODS) | set(BASELINE_METHODS)
    return {
        m: row
        for m, row in case["methods"].items()
        if m in wanted and m != DEFAULT_METHOD and m not in FRESH_PRESETS
    }


def brief(row: dict) -> dict:
    """The figures of a method's row the scorecard keeps."""
    keys = ("median", "p95", "p99", "fraction_under_0.03", "wall_s", "relit_de2000")
    out = {k: row[k] for k in keys if k in row}
    for part in ("with_bands", "without_bands"):
        if part in row:
            out[part] = row[part]
    return out


def fresh_rivals(capture, illuminant, methods, rivals: dict, what: str) -> None:
    """Solve ``methods`` on ``capture`` into ``rivals``."""
    for method in methods:
        rivals[method] = brief(run_method(capture, method, illuminant))
        log(f"{what} {method:20s} {rivals[method]['median']:.4f} / {rivals[method]['p95']:.4f}")


def single_row(scene: str, seed: int, size: int, hard: dict) -> dict:
    """Default, rivals, oracles and noise-free limit of a single image."""
    capture = get_scene(scene, size=size, seed=seed, n_images=1)
    what = f"{scene:16s} seed {seed} single {size}^2"
    default = brief(run_method(capture, DEFAULT_METHOD))
    log(f"{what} default {default['median']:.4f} / {default['p95']:.4f}")
    case = stored_case(hard, scene, seed, 1, size)
    rivals = stored_rivals(case)
    fresh_rivals(
        capture, None, FRESH_PRESETS if rivals else (*FRESH_PRESETS, *QUICK_RIVALS), rivals, what
    )
    row = {
        "scene": scene,
        "seed": seed,
        "mode": "single",
        "size": size,
        "held_out": scene == HELD_OUT,
        "default": default,
        "stored_default": brief(case["methods"][DEFAULT_METHOD]) if case else None,
        "others": rivals,
        "oracles": oracles(capture),
        "noise_free": brief(run_method(noise_free(capture), DEFAULT_METHOD)),
        "noise_free_bands_only_stored": brief(case["default_on_noise_free_bands"])
        if case and "default_on_noise_free_bands" in case
        else None,
    }
    log(f"{what} oracles {row['oracles']}, noise-free {row['noise_free']['median']:.4f}")
    return row


def set_row(scene: str, seed: int, size: int, other_sets: int, hard: dict, run_library: dict) -> dict:
    """Default with the run's library, rivals, oracles and noise-free limit of a set."""
    what = f"{scene:16s} seed {seed} set 20x{size}^2"
    sets = run_sets(scene, seed, size, other_sets)
    capture, illuminant = sets[0], scene_illuminant(sets[0])
    library = pooled_library(sets)
    default = brief(run_method(capture, DEFAULT_METHOD, illuminant, endmembers=library))
    log(f"{what} default+run-library {default['median']:.4f} / {default['p95']:.4f}")
    case = stored_case(hard, scene, seed, 20, size)
    rivals = stored_rivals(case)
    fresh = FRESH_PRESETS if rivals else (*FRESH_PRESETS, *QUICK_RIVALS)
    fresh_rivals(capture, illuminant, fresh, rivals, what)
    rivals[RUN_LIBRARY_RIVAL] = brief(
        run_method(capture, "sparse-choice", illuminant, endmembers=library)
    )
    stored_run = next(
        (
            c["methods"]["default+run-library"]
            for c in run_library.get("cases", [])
            if (c["scene"], c["seed"], c["size"]) == (scene, seed, size)
            and run_library.get("sets_pooled") == len(sets)
        ),
        None,
    )
    clean_sets = [noise_free(s) for s in sets]
    clean_library = pooled_library(clean_sets)
    row = {
        "scene": scene,
        "seed": seed,
        "mode": "set",
        "size": f"20 x {size}^2",
        "sets_pooled": len(sets),
        "held_out": scene == HELD_OUT,
        "default": default,
        "stored_default": brief(stored_run) if stored_run else None,
        "default_own_library": brief(case["methods"][DEFAULT_METHOD]) if case else None,
        "others": rivals,
        "oracles": oracles(capture),
        "noise_free": brief(
            run_method(clean_sets[0], DEFAULT_METHOD, illuminant, endmembers=clean_library)
        ),
    }
    log(f"{what} oracles {row['oracles']}, noise-free {row['noise_free']['median']:.4f}")
    return row


def ratio(a: float, b: float) -> float:
    return round(a / b, 3) if b else float("inf")


def best_rivals(row: dict) -> dict:
    """The best other preset and the best baseline at the median and at p95: the method, its
    value and the default's over it."""
    groups = {
        "preset": [m for m in row["others"] if m not in BASELINE_METHODS],
        "baseline": [m for m in row["others"] if m in BASELINE_METHODS],
    }
    out: dict = {}
    for group, methods in groups.items():
        for key in ("median", "p95"):
            if not methods:
                continue
            best = min(methods, key=lambda m, key=key: row["others"][m][key])
            value = row["others"][best][key]
            out.setdefault(group, {})[key] = {
                "method": best,
                "value": value,
                "default_over": ratio(row["default"][key], value),
            }
    return out


def limits(row: dict) -> dict:
    """The information-limit reading of the median: the default, the noise-free limit and
    ``nearest-3`` over the ``present`` oracle, and the default over the noise-free limit
    (what the measurements' noise costs)."""
    present = row["oracles"]["present"]["median"]
    default, clean = row["default"]["median"], row["noise_free"]["median"]
    return {
        "default_over_present": ratio(default, present),
        "noise_free_over_present": ratio(clean, present),
        "nearest3_over_present": ratio(row["oracles"]["nearest-3"]["median"], present),
        "default_over_noise_free": ratio(default, clean),
    }


def targets(row: dict) -> dict:
    """Each target of the row: met, and by how much (ratio to the bound, or points)."""
    default, out = row["default"], {}
    beaten = {
        f"{method} ({key})": ratio(default[key], other[key])
        for method, other in row["others"].items()
        for key in ("median", "p95")
        if other[key] * TARGETS["default_vs_every_other_method_max_ratio"] < default[key]
    }
    out["le_every_other_method"] = {"met": not beaten, "beaten_by_default_over_other": beaten}
    if row["mode"] != "set":
        return out
    present = row["oracles"]["present"]["median"]
    out["median_le_2x_present"] = {
        "met": default["median"] <= 2.0 * present,
        "default_over_present": ratio(default["median"], present),
        "noise_free_over_present": ratio(row["noise_free"]["median"], present),
        "nearest3_over_present": ratio(row["oracles"]["nearest-3"]["median"], present),
    }
    wanted = TARGETS[
        "set_fraction_under_0.03_min_glossy_dark"
        if row["scene"] in GLOSSY_DARK
        else "set_fraction_under_0.03_min_woven_halftone"
    ]
    fraction = default["fraction_under_0.03"]
    out["fraction_under_0.03"] = {
        "met": fraction >= wanted,
        "target": wanted,
        "default": fraction,
        "points_short": round(100 * max(wanted - fraction, 0.0), 1),
        "noise_free": row["noise_free"]["fraction_under_0.03"],
        "present": row["oracles"]["present"]["fraction_under_0.03"],
    }
    for key in ("median", "p95"):
        bound = TARGETS[f"set_relit_de2000_{key}_max_A_FL11"]
        values = {light: default["relit_de2000"][light][key] for light in RELIT_TARGET_LIGHTS}
        out[f"relit_A_FL11_{key}_le_{bound}"] = {
            "met": all(v <= bound for v in values.values()),
            "default": values,
            "noise_free": {
                light: row["noise_free"]["relit_de2000"][light][key] for light in RELIT_TARGET_LIGHTS
            },
            "worst_over_bound": ratio(max(values.values()), bound),
        }
    without = {
        k: ratio(default["without_bands"][k], default["with_bands"][k]) for k in ("median", "p95")
    }
    out["without_within_1.1x_of_with"] = {
        "met": all(v <= TARGETS["without_vs_with_bands_max_ratio"] for v in without.values()),
        "without_over_with": without,
    }
    return out


def best_at(rows: list[dict]) -> dict:
    """Per method, the rows (``mode scene seed: statistic``) where it is the best of all."""
    out: dict[str, list[str]] = {}
    for row in rows:
        methods = {"default": row["default"], **row["others"]}
        for key in ("median", "p95"):
            best = min(methods, key=lambda m, key=key: methods[m][key])
            out.setdefault(best, []).append(f"{row['mode']} {row['scene']} {row['seed']}: {key}")
    presets = [m for m in RECONSTRUCTION_METHODS if m != DEFAULT_METHOD] + [RUN_LIBRARY_RIVAL]
    return {
        "best": out,
        "presets_best_nowhere": [m for m in presets if m not in out],
    }


def summary(rows: list[dict]) -> dict:
    """Per target, the rows where it is missed (held-out scene marked)."""
    missed: dict[str, list[str]] = {}
    for row in rows:
        for name, target in row["targets"].items():
            if not target["met"]:
                mark = " (held out)" if row["held_out"] else ""
                missed.setdefault(name, []).append(f"{row['mode']} {row['scene']} {row['seed']}{mark}")
    checked = {name for row in rows for name in row["targets"]}
    stored = [row for row in rows if row.get("stored_default")]
    return {
        "met_on_every_row": sorted(checked - set(missed)),
        "missed_on": missed,
        "rows": len(rows),
        # the default solved here against the stored JSON's row (same capture and library)
        "default_as_stored": {
            "rows_compared": len(stored),
            "differ": [
                f"{row['mode']} {row['scene']} {row['seed']}: "
                f"{row['default'][k]} vs stored {row['stored_default'][k]} ({k})"
                for row in stored
                for k in ("median", "p95")
                if row["default"][k] != row["stored_default"][k]
            ],
        },
    }


def run(
    scenes: list[str], seeds: tuple[int, ...], single_size: int, set_size: int, other_sets: int
) -> dict:
    hard, run_library = load("reconstruction"), load("reconstruction_run_library")
    rows = []
    for scene in scenes:
        for seed in seeds:
            rows.append(single_row(scene, seed, single_size, hard))
            rows.append(set_row(scene, seed, set_size, other_sets, hard, run_library))
    return {
        "benchmark": "the reconstruction's scorecard: every target on every row, beside the "
        "oracles and the noise-free limit",
        "default_method": DEFAULT_METHOD,
        "sizes": {"single": single_size, "set": f"20 x {set_size}^2"},
        "seeds": list(seeds),
        "scenes": scenes,
        "held_out": HELD_OUT,
        "sets_pooled": 1 + other_sets,
        "targets": TARGETS,
        "fresh_presets": list(FRESH_PRESETS),
        "stored_from": {
            "reconstruction": git(
                "log", "-1", "--format=%h", "--", str(RESULTS / "reconstruction.json")
            ),
            "reconstruction_run_library": run_library.get("commit"),
        },
        "rows": rows,
    }


def score(report: dict) -> dict:
    """The scorecard of the rows' figures: per row the best rivals, the limits and the
    targets; the summary and where each method is best."""
    for row in report["rows"]:
        row["best_rivals"] = best_rivals(row)
        row["limits"] = limits(row)
        row["targets"] = targets(row)
    report["summary"] = summary(report["rows"])
    report["best_at"] = best_at(report["rows"])
    return report


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="woven-fabric, seed 0, 24^2 and 20 x 16^2")
    parser.add_argument("--seeds", type=int, nargs="+", default=None)
    parser.add_argument("--scenes", nargs="+", default=None, choices=list(SCENES))
    parser.add_argument("--other-sets", type=int, default=None)
    parser.add_argument("--output", type=Path, default=OUTPUT, help="where the JSON goes")
    parser.add_argument(
        "--rescore",
        type=Path,
        default=None,
        help="score the rows of this JSON again (no solve) and write it to --output",
    )
    args = parser.parse_args(argv)
    if args.rescore is not None:
        report = score(json.loads(args.rescore.read_text()))
        args.output.write_text(json.dumps(report, indent=1) + "\n")
        print(json.dumps(report))
        return report
    started = time.perf_counter()
    report = run(
        args.scenes or (["woven-fabric"] if args.quick else list(SCENES)),
        tuple(args.seeds or ((0,) if args.quick else (0, 1))),
        24 if args.quick else 128,
        16 if args.quick else 48,
        args.other_sets
        if args.other_sets is not None
        else (1 if args.quick else DEFAULT_LIBRARY_SETS - 1),
    )
    report = score(report) | {
        "quick": args.quick,
        "total_seconds": round(time.perf_counter() - started, 1),
        "commit": git("rev-parse", "--short", "HEAD"),
        "working_tree_changes": git(
            "status", "--porcelain", "--untracked-files=no", "--", str(HERE.parent / "nodes")
        ),
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"python": platform.python_version(), "cpu_count": os.cpu_count()},
    }
    args.output.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report))
    return report


if __name__ == "__main__":
    main()
