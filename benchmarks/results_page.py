"""Writes ``docs/benchmarks.md`` from the benchmarks' JSON in ``benchmarks/results/``.

Run from the repository root after a benchmark has written its JSON::

    .venv/bin/python benchmarks/results_page.py            # rewrite docs/benchmarks.md
    .venv/bin/python benchmarks/results_page.py --check    # exit 1 if the page is stale

Every figure on the page comes from a JSON file; what a JSON cannot say (why a target is
missed, what was tried) is written by hand in ``docs/benchmarks_notes.md``, one ``## <name>``
section per benchmark, and placed under that benchmark's tables. A test
(``tests/benchmarks/test_results_page.py``) keeps the committed page equal to this script's
output, so the page never goes stale. Standard library only: nothing is run or imported.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
NOTES = ROOT / "docs" / "benchmarks_notes.md"
PAGE = ROOT / "docs" / "benchmarks.md"

Json = dict[str, Any]


# --- formatting ----------------------------------------------------------------------------


def num(value: Any, digits: int = 3) -> str:
    """A figure as the page prints it: ``digits`` significant digits, ``-`` for none."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if abs(value) >= 10 ** (digits - 1):
            return f"{value:.0f}"
        return f"{value:.{digits}g}"
    return str(value)


def pct(value: float | None) -> str:
    """A fraction as a percentage with one decimal."""
    return "-" if value is None else f"{num(100 * value)} %"


def pair(stats: Json | None, first: str = "median", second: str = "p95") -> str:
    """``median / p95`` of a statistics record."""
    if not stats:
        return "-"
    return f"{num(stats.get(first))} / {num(stats.get(second))}"


def table(headers: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A markdown table; cells that are not strings go through :func:`num`."""
    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    for row in rows:
        lines.append("| " + " | ".join(c if isinstance(c, str) else num(c) for c in row) + " |")
    return "\n".join(lines)


def verdict(value: Any) -> str:
    """A target's outcome: ``met``/``not met``, per key where the JSON has several."""
    if isinstance(value, dict):
        return ", ".join(f"{key}: {verdict(v)}" for key, v in value.items())
    return "met" if value else "not met"


def provenance(data: Json, name: str) -> str:
    """Which commit and date the JSON records, and on what machine."""
    parts = []
    if data.get("commit"):
        parts.append(f"commit `{data['commit']}`")
    if data.get("date"):
        parts.append(data["date"])
    machine = data.get("machine") or {}
    cores = machine.get("cpu_count") or data.get("cpu_count") or data.get("cores_measured")
    if cores:
        parts.append(f"{cores} cores")
    if machine.get("python"):
        parts.append(f"Python {machine['python']}")
    recorded = ", ".join(parts) if parts else "no commit or date recorded"
    return f"JSON: `benchmarks/results/{name}.json` ({recorded})."


# --- one section per JSON ------------------------------------------------------------------


def reconstruction(data: Json) -> list[str]:
    targets = data["targets"]
    out = [
        f"Every hard scene x seeds {data['seeds']} x every method, on the same captures: single "
        f"images {data['sizes']['single']}^2 with all 32 band shots, and sets of "
        f"{data['sizes']['set']} (half the images with band shots). Per-pixel nRMSE (RMSE over "
        "bands / the image's mean truth, paper Fig. 5); each cell is the worse of the seeds: "
        f"median / p95. Default method: `{data['default_method']}`.",
    ]
    for mode, title in (("single", "Single images"), ("set", "Sets")):
        scenes = data["summary"][mode]
        names = list(scenes)
        methods = list(next(iter(scenes.values()))["solvers"])
        rows = [[f"`{m}`"] + [pair(scenes[s]["solvers"].get(m)) for s in names] for m in methods]
        rows.append(
            ["best baseline"]
            + [
                f"{num(scenes[s]['best_baseline_median']['value'])} "
                f"({scenes[s]['best_baseline_median']['method']}) / "
                f"{num(scenes[s]['best_baseline_p95']['value'])} "
                f"({scenes[s]['best_baseline_p95']['method']})"
                for s in names
            ]
        )
        rows.append(
            ["default: pixels < 0.03"]
            + [pct(scenes[s]["default"]["fraction_under_0.03"]) for s in names]
        )
        rows.append(
            ["default vs best baseline (median, p95)"]
            + [
                f"{num(scenes[s]['median_gain_vs_best_baseline'])}x, "
                f"{num(scenes[s]['p95_gain_vs_best_baseline'])}x"
                for s in names
            ]
        )
        if mode == "set":
            rows.append(
                ["default with / without band shots (median)"]
                + [
                    f"{num(scenes[s]['default_with_bands']['median'])} / "
                    f"{num(scenes[s]['default_without_bands']['median'])}"
                    for s in names
                ]
            )
        out += [f"**{title}** (median / p95 nRMSE)", table(["method"] + names, rows)]
    for mode, title in (("single", "Single images"), ("set", "Sets")):
        out += relit_colour(data, mode, title)
    target_rows = []
    for mode in ("single", "set"):
        for scene, summary in data["summary"][mode].items():
            met = [k for k, v in summary["targets"].items() if v]
            missed = [k for k, v in summary["targets"].items() if not v]
            target_rows.append([f"{scene}, {mode}", ", ".join(met) or "-", ", ".join(missed) or "-"])
    out += [
        "**Targets** (" + ", ".join(f"`{k}` {num(v)}" for k, v in targets.items()) + ")",
        table(["case", "met", "not met"], target_rows),
    ]
    rank = {}
    for case in data["cases"]:
        value = case["methods"][data["default_method"]].get("confidence_rank_correlation")
        mode = "single" if case["n_images"] == 1 else "set"
        rank.setdefault(mode, []).append(value)
    if rank:
        out.append(
            "Confidence of the default (Spearman rank correlation with its per-pixel error, over "
            "scenes and seeds): "
            + "; ".join(f"{mode} {num(min(v))} to {num(max(v))}" for mode, v in rank.items())
            + ". Every case's figures for every method, baselines included, are in the JSON "
            "(`cases`)."
        )
    if data.get("note_paper_cg_sets"):
        out.append(f"Note from the JSON: {data['note_paper_cg_sets']}.")
    return out


def relit_colour(data: Json, mode: str, title: str) -> list[str]:
    """The relit CIEDE2000 of every method per scene (worse seed), if the JSON has it."""
    scenes = data["summary"][mode]
    if not all("relit_de2000" in row for row in scenes.values()):
        return []
    names = list(scenes)
    methods = list(next(iter(scenes.values()))["relit_de2000"])
    lights = list(next(iter(next(iter(scenes.values()))["relit_de2000"].values())))

    def cell(scene: str, method: str) -> str:
        relit = scenes[scene]["relit_de2000"].get(method)
        return "-" if relit is None else ", ".join(pair(relit[light]) for light in lights)

    rows = [[f"`{m}`"] + [cell(s, m) for s in names] for m in methods]
    default = data["default_method"]
    rows.append(
        ["default: pixels left out (near black)"]
        + [
            ", ".join(pct(scenes[s]["relit_de2000"][default][light]["excluded"]) for light in lights)
            for s in names
        ]
    )
    return [
        f"**{title}: colour under other lights** (CIEDE2000 of the spectra relit under "
        + ", ".join(lights)
        + ", in that order, against the truth relit alike; median / p95, worse seed)",
        table(["method"] + names, rows),
    ]


def reconstruction_run_library(data: Json) -> list[str]:
    cases = {(c["scene"], c["seed"]): c for c in data["cases"]}
    first = data["seeds"][0]

    def angles(a: Json) -> str:
        return f"{num(a['all_median'])} / {num(a['area_weighted_median'])} / {num(a['dominant_median'])}"

    def relit(row: Json, light: str) -> str:
        colour = row["relit_de2000"][light]
        return f"{num(colour['median'], 2)} / {num(colour['p95'], 2)}"

    library_rows = []
    rows = []
    for scene, v in data["summary"].items():
        case = cases[(scene, first)]
        oracle = case.get("oracles") or {}
        library_rows.append(
            [
                scene,
                angles(case["angles"]["own"]),
                angles(case["angles"]["run"]),
                pair(oracle.get("present")),
                pair(oracle.get("nearest-3")),
            ]
        )
        ratios = v.get("vs_default_max_ratio", {"default+run-library": v["run_vs_own_max_ratio"]})
        for method in (m for m in v if isinstance(v[m], dict) and "relit_de2000" in v[m]):
            ratio = ratios.get(method)
            rows.append(
                [
                    scene,
                    f"`{method}`",
                    f"{pair(v[method])} ({pct(v[method]['fraction_under_0.03'])})",
                    f"{num(ratio['median'])} / {num(ratio['p95'])}" if ratio else "-",
                    *(relit(v[method], light) for light in ("A", "FL11", "D65")),
                ]
            )
    return [
        f"Sets of {data['size']}, seeds {', '.join(map(str, data['seeds']))}: each scene x seed "
        f"is a run of {data['sets_pooled']} sets (the hard suite's set and sets of the same "
        f"sample with their own noise and the lights turned by {num(data['turn_deg'])} degrees "
        "per set); the run library is learnt from all of them pooled (as the `endmember_library` "
        "node learns it) and the hard suite's set is solved with it, beside the same set with "
        "its own library. Angles [degree] (seed "
        f"{first}): each true endmember to the nearest learnt one, median over all materials / "
        "area-weighted / dominant materials. Oracles: the true endmembers weighted by the RGB "
        "alone, with each pixel's own materials (`present`) or the three nearest in "
        "chromaticity (`nearest-3`).",
        table(
            ["scene", "angles: own library", "angles: run library", "present", "nearest-3"],
            library_rows,
        ),
        "nRMSE median / p95 (pixels < 0.03) and relit CIEDE2000 median / p95, the worse seed; "
        "the ratio is the row's over the default's (own library), the larger of the seeds.",
        table(
            ["scene", "row", "median / p95", "vs default", "A", "FL11", "D65"],
            rows,
        ),
    ]


def reconstruction_targets(data: Json) -> list[str]:
    def row_name(row: Json) -> str:
        held = " (held out)" if row["held_out"] else ""
        return f"{row['mode']} {row['scene']}{held} {row['seed']}"

    def rival(best: Json, group: str) -> str:
        cells = best.get(group) or {}
        return " / ".join(
            f"{num(cells[k]['value'])} `{cells[k]['method']}` ({num(cells[k]['default_over'])}x)"
            for k in ("median", "p95")
            if k in cells
        )

    def missed(row: Json) -> str:
        names = [name for name, target in row["targets"].items() if not target["met"]]
        return ", ".join(names) or "none"

    score_rows = []
    set_rows = []
    for row in data["rows"]:
        default, oracle, clean = row["default"], row["oracles"], row["noise_free"]
        score_rows.append(
            [
                row_name(row),
                f"{pair(default)} ({pct(default['fraction_under_0.03'])})",
                rival(row["best_rivals"], "preset"),
                rival(row["best_rivals"], "baseline"),
                pair(oracle["present"]),
                pair(oracle["nearest-3"]),
                f"{pair(clean)} ({pct(clean['fraction_under_0.03'])})",
                missed(row),
            ]
        )
        if row["mode"] != "set":
            continue
        t, lim = row["targets"], row["limits"]
        relit = [
            " / ".join(
                f"{num(t[f'relit_A_FL11_{k}_le_{b}']['default'][light], 2)}"
                for k, b in (("median", 1.0), ("p95", 3.0))
            )
            + " ("
            + " / ".join(
                f"{num(t[f'relit_A_FL11_{k}_le_{b}']['noise_free'][light], 2)}"
                for k, b in (("median", 1.0), ("p95", 3.0))
            )
            + ")"
            for light in ("A", "FL11")
        ]
        fraction = t["fraction_under_0.03"]
        set_rows.append(
            [
                row_name(row),
                f"{num(lim['default_over_present'])} ({num(lim['noise_free_over_present'])}, "
                f"{num(lim['nearest3_over_present'])})",
                num(lim["default_over_noise_free"]),
                f"{pct(fraction['default'])} of {pct(fraction['target'])} "
                f"({pct(fraction['noise_free'])}, {pct(fraction['present'])})",
                *relit,
                " / ".join(
                    num(v) for v in t["without_within_1.1x_of_with"]["without_over_with"].values()
                ),
            ]
        )
    best = data["best_at"]
    nowhere = ", ".join(f"`{m}`" for m in best["presets_best_nowhere"]) or "none"
    best_rows = [[f"`{m}`", "; ".join(where)] for m, where in best["best"].items()]
    summary = data["summary"]
    same = summary.get("default_as_stored") or {}
    differ = "; ".join(same.get("differ", [])) or "none differ"
    return [
        f"Every hard scene x seeds {', '.join(map(str, data['seeds']))} as a single image "
        f"({data['sizes']['single']}^2) and a set ({data['sizes']['set']}; the default with the "
        f"library of a run of {data['sets_pooled']} sets, as `run btf` runs it). Rivals: every "
        "other preset and baseline on the same captures (stored rows of `reconstruction.json`, "
        "presets changed since solved again). Oracles on the same inputs: the true endmembers "
        "weighted by the RGB alone, each pixel's own (`present`) or the three nearest in "
        "chromaticity (`nearest-3`). Noise-free: the default on the same capture with noise-free "
        "band shots and the true HDR RGB (on a set, its run's library learnt from noise-free "
        "sets too): what the default reaches with perfect measurements. nRMSE median / p95 "
        "(pixels < 0.03); a rival's ratio is the default's over it (> 1: the default loses).",
        table(
            [
                "row",
                "default",
                "best other preset: median / p95",
                "best baseline: median / p95",
                "present",
                "nearest-3",
                "noise-free",
                "targets missed",
            ],
            score_rows,
        ),
        "Set targets: median over `present` (noise-free over `present`, `nearest-3` over "
        "`present`); the default over its noise-free limit; pixels < 0.03 against the target "
        "(noise-free, `present`); relit CIEDE2000 median / p95 under A and FL11 (noise-free); "
        "images without band shots over those with them, median / p95.",
        table(
            [
                "set row",
                "median / present",
                "default / noise-free",
                "< 0.03",
                "A",
                "FL11",
                "without / with",
            ],
            set_rows,
        ),
        f"The default solved here against the stored JSON's row on {same.get('rows_compared', 0)} "
        f"rows: {differ}. "
        f"Targets met on every row: {', '.join(summary['met_on_every_row']) or 'none'}. "
        f"Presets best on no row and statistic: {nowhere}. Where each method is best (of all, "
        "at the median or p95):",
        table(["method", "best on"], best_rows),
    ]


def reconstruction_legacy(data: Json) -> list[str]:
    comparison = data["comparison"]
    scene = comparison["scene"]
    methods = sorted(comparison["methods"].items(), key=lambda item: item[1]["median"])
    out = [
        f"The earlier single scene: one simulated {scene['size']}^2 x 32 capture at the paper's "
        "exposure plan (3 DN band noise, specular highlights), every method on the same data. "
        f"Default method: `{data['default_method']}`.",
        table(
            [
                "method",
                "kind",
                "median",
                "p95",
                "p99",
                "pixels < 0.03",
                "wall s",
                "iterations",
                "traced MB",
            ],
            (
                [
                    f"`{name}`",
                    m.get("kind", "-"),
                    m["median"],
                    m["p95"],
                    m["p99"],
                    pct(m["fraction_under_0.03"]),
                    m["wall_s"],
                    m.get("iterations") or "-",
                    m.get("peak_traced_mb"),
                ]
                for name, m in methods
            ),
        ),
    ]
    noise_free = comparison.get("default_on_noise_free_bands")
    if noise_free:
        out.append(f"The default on noise-free band shots: median {num(noise_free['median'])}.")
    timing = comparison.get("time_to_equal_accuracy")
    if timing:
        out.append(
            "Time to the paper CG's final median nRMSE: default "
            f"{num(timing['default_seconds_to_target'])} s, paper CG "
            f"{num(timing['paper_cg_seconds_to_target'])} s "
            f"({num(timing['speedup_time_to_equal_accuracy'])}x)."
        )
    out += [
        "**Scaling** (fresh processes, default method)",
        table(
            ["size", "images", "median", "wall s", "iterations", "peak RSS MB"],
            (
                [
                    f"{s['size']}^2",
                    s["n_images"],
                    s["median"],
                    s["wall_s"],
                    s["iterations"],
                    s["peak_rss_mb"],
                ]
                for s in data["scaling"]
            ),
        ),
    ]
    ablation = comparison.get("ablation")
    if ablation:
        steps = [(k, v) for k, v in ablation.items() if isinstance(v, dict)]
        out += [
            f"**Ablation of eq. 1's solver** ({ablation['size']}^2, time to median nRMSE "
            f"{num(ablation['target_median_nrmse'])})",
            table(
                ["step", "s to target", "iterations to target", "final median"],
                (
                    [k, v["seconds_to_target"], v["iterations_to_target"], v["final_median_nrmse"]]
                    for k, v in steps
                ),
            ),
        ]
    sensitivity = comparison.get("weight_sensitivity")
    if sensitivity:
        rows = [
            [k, v["median"], v["p95"], pct(v["fraction_under_0.03"])]
            for k, v in sensitivity.items()
            if isinstance(v, dict)
        ]
        out += [
            f"**Weight sensitivity of eq. 1** ({sensitivity['size']}^2)",
            table(["weights", "median", "p95", "pixels < 0.03"], rows),
        ]
    return out


def reconstruction_oracle(data: Json) -> list[str]:
    return [
        f"What the hard scenes allow ({data['size']}^2, seed 0): each scene's truth rebuilt as a "
        "non-negative mixture of its *true* endmembers, weighted by the noisy RGB alone. "
        "`present`: each pixel mixes the materials it truly holds (an oracle); `nearest-3`: the "
        "three endmembers nearest in chromaticity, as the endmember-mixture estimator chooses.",
        table(
            [
                "scene",
                "materials",
                "per pixel (median)",
                "present: median / p95",
                "nearest-3: median / p95",
            ],
            (
                [
                    s,
                    v["materials"],
                    v["materials_per_pixel_median"],
                    pair(v["present"]),
                    pair(v["nearest-3"]),
                ]
                for s, v in data["scenes"].items()
            ),
        ),
    ]


def calibration(data: Json) -> list[str]:
    setup = data["setup"]
    rows = []
    for name, m in data["methods"].items():
        error = m.get("response_error") or {}
        hdr = m.get("hdr_error") or {}

        def med_max(part: str, error: Json = error) -> str:
            e = error.get(part)
            return "-" if not e else f"{pct(e['median'])} / {pct(e['max'])}"

        rows.append(
            [
                f"`{name}`",
                med_max("whole_range"),
                med_max("lowest_5pct"),
                med_max("upper_95pct"),
                pct(hdr.get("median")) if hdr else "-",
                m.get("calibrate_seconds"),
            ]
        )
    out = [
        f"Radiometric calibration at the noise floor: one simulated camera ({setup['pixels']} px, "
        f"{setup['bit_depth']} bit, read noise {num(setup['read_noise_dn'])} DN, "
        f"{setup['true_oecf']}), an RGB exposure series and a low-SNR series with "
        f"{setup['dark_frames']} dark frames; OpenCV and colour-hdri get the series shifted to "
        "8 bit (all they accept). Response error `|s f / f_true - 1|` with one scale per method.",
        table(
            [
                "method",
                "response error, whole range: median / max",
                "lowest 5 %",
                "upper 95 %",
                "HDR median error",
                "calibrate s",
            ],
            rows,
        ),
    ]
    snr = data["methods"].get("spectralize_low_snr_extension", {}).get("at_snr_le_1")
    if snr:
        levels = list(snr["extension"])
        out += [
            "**Response error near the dark level** (DN above dark)",
            table(
                ["method"] + [level.replace("_dn", " DN") for level in levels],
                [[k] + [pct(v[level]) for level in levels] for k, v in snr.items()],
            ),
        ]
    race = data["methods"].get("opencv_robertson", {}).get("race")
    if race:
        out += [
            f"**Race** ({race.get('note', '')}, seconds)",
            table(
                ["run", "best", "median"],
                ([k, v["min"], v["median"]] for k, v in race.items() if isinstance(v, dict)),
            ),
        ]
    out += [
        "**Targets**",
        table(["target", "met"], ([k, verdict(v)] for k, v in data["targets_met"].items())),
    ]
    return out


def btf_flow(data: Json) -> list[str]:
    recipe = data["recipe"]
    iterations = data["iterations"]
    warm = list(iterations["warm_start"].values())
    cold = list(iterations["cold_start"].values())
    throughput = data["throughput"]
    out = [
        f"The whole `btf` flow as one Prefect run on the `{recipe['recipe']}` recipe "
        f"({data['images']} images of {data['image_size'][0]} x {data['image_size'][1]} px, "
        f"{data['sets']} image sets), simulation included.",
        table(
            ["measure", "value"],
            [
                ["flow wall time", f"{num(data['flow_seconds'])} s"],
                ["processing per image", f"{num(data['processing_seconds_per_image'])} s"],
                [
                    "iterations per set, warm start / cold",
                    f"{min(warm)}-{max(warm)} / {min(cold)}-{max(cold)}",
                ],
                ["iterations saved by the warm start", pct(iterations["mean_saved_fraction"])],
                [
                    "all sets, 1 / 2 dask workers",
                    f"{num(throughput['1_workers']['seconds'])} s / "
                    f"{num(throughput['2_workers']['seconds'])} s "
                    f"({num(data['speedup_2_vs_1_workers'])}x)",
                ],
                ["peak memory of the process", f"{num(data['peak_rss_mb'])} MB"],
            ],
        ),
        "**Node wall times** (s)",
        table(["node", "s"], ([f"`{k}`", v] for k, v in data["node_seconds"].items())),
        "**Accuracy against the truth** (paper Fig. 7)",
        table(
            ["images", "median nRMSE", "p95", "pixels < 0.03"],
            (
                [k.replace("_", " "), v["median_nrmse"], v["p95_nrmse"], pct(v["fraction_under_0.03"])]
                for k, v in data["accuracy"].items()
            ),
        ),
    ]
    return out


def paper_scale(data: Json) -> list[str]:
    summary = data["summary"]
    untiled = data["untiled"]
    today = data["today"]
    sizes = data["sizes"]
    first = next(iter(sizes.values()))
    out = [
        f"{data['set']} of the `{data['scene']}` hard scene, method `{first['method']}`, solved tile "
        f"by tile ({first['tile']} px cores, {first['halo']} px halo), two tiles at a time on "
        f"{first['threads']} threads; inputs above 512^2 are the 512^2 capture mirrored up and read "
        f"per tile from memory-mapped files; {first['tiles_solved']} interior tiles solved per size, "
        "the set's time extrapolated.",
        table(
            ["size", "s per Mpx-image", "peak RSS GB", "iterations per tile", "set s (extrapolated)"],
            (
                [
                    f"{k}^2",
                    v["seconds_per_mpx_image"],
                    v["peak_rss_gb"],
                    "-".join(str(i) for i in sorted(set(v["iterations"]))),
                    v["set_seconds_extrapolated"],
                ]
                for k, v in sizes.items()
            ),
        ),
        f"**Side by side on one 20 x {untiled['size']}^2 set** (same inputs, one run)",
        table(
            ["solve", "wall s", "s per Mpx-image", "median / p95 nRMSE"],
            [
                [
                    "the solver before the paper-scale work, whole set",
                    today["wall_s"],
                    summary["today_seconds_per_mpx_image"],
                    pair(today),
                ],
                [
                    "the default, whole set",
                    untiled["untiled_s"],
                    summary["untiled_seconds_per_mpx_image"],
                    pair(untiled["accuracy"]["untiled"]),
                ],
                [
                    f"the default, tiled ({untiled['tile']} px cores)",
                    untiled["tiled_s"],
                    summary["tiled_seconds_per_mpx_image_small"],
                    pair(untiled["accuracy"]["tiled"]),
                ],
            ],
        ),
        table(
            ["measure", "value"],
            [
                [
                    "tiled / untiled nRMSE (median, p95)",
                    f"{num(summary['tiled_vs_untiled_nrmse_ratio']['median'], 4)}, "
                    f"{num(summary['tiled_vs_untiled_nrmse_ratio']['p95'], 4)}",
                ],
                [
                    "error near tile borders / tile interiors (tiled, untiled)",
                    f"{num(untiled['seam_median_border_vs_interior'])}, "
                    f"{num(untiled['untiled_median_border_vs_interior'])}",
                ],
                ["speed-up over the earlier solver (tiled)", f"{num(summary['speedup_vs_today'])}x"],
                [
                    "dask workers: wall s",
                    ", ".join(
                        f"{d['workers']}: {num(d['wall_s'])} s ({d['sets']} sets, {d['tiles']} tiles)"
                        for d in data["dask"]
                    ),
                ],
                ["2 workers vs 1", f"{num(summary['dask_speedup_2_workers'])}x"],
                [
                    "full run on 100 cores, extrapolated",
                    f"{num(summary['full_run_hours_at_100_cores'])} h",
                ],
            ],
        ),
        "**Targets**",
        table(["target", "met"], ([k, verdict(v)] for k, v in summary["targets"].items())),
    ]
    return out


def paper_scale_2048_rerun(data: Json) -> list[str]:
    rows = [
        [
            f"`{name}`",
            v["seconds_per_mpx_image"],
            v["peak_rss_gb"],
            "-".join(str(i) for i in sorted(set(v["iterations"]))),
        ]
        for name, v in data.items()
        if isinstance(v, dict)
    ]
    return [
        "The 2048^2 throughput row of `paper_scale.py` for one method at a time "
        "(`benchmarks/paper_scale_default.py --method NAME`), merged by method.",
        table(["method", "s per Mpx-image", "peak RSS GB", "iterations per tile"], rows),
        f"Note from the JSON: {data['note']}",
    ]


def paper_scale_throughput(data: Json) -> list[str]:
    rows = []
    for key in ("before", "after"):
        v = data[key]
        accuracy = v.get("accuracy_128", {})
        rows.append(
            [
                v["commit"],
                v["seconds_per_mpx_image"],
                "/".join(str(s) for s in v["seconds_per_tile"]),
                v["peak_rss_gb"],
                "-".join(str(i) for i in sorted(set(v["iterations"]))),
                v.get("endmembers_s", "-"),
                f"{num(accuracy.get('median'), 4)} / {num(accuracy.get('p95'), 4)}",
            ]
        )
    return (
        [
            f"The 2048^2 throughput case of `paper_scale.py` ({data['method']}, {data['scene']}, "
            f"{data['set']}; 2 interior 256 px tiles on 2 threads), before and after in one run; "
            f"accuracy: the 128^2 set solved whole. Speed-up {data['speedup']}x.",
            table(
                [
                    "code",
                    "s per Mpx-image",
                    "s per tile",
                    "peak RSS GB",
                    "iterations per tile",
                    "endmembers s",
                    "128^2 nRMSE median / p95",
                ],
                rows,
            ),
            f"Note from the JSON: {data['note']}",
        ]
        + _throughput_profile(data.get("profile_256"))
        + _mixture_tile(data.get("mixture_tile"))
    )


def _mixture_tile(case: Json | None) -> list[str]:
    if not case:
        return []
    before, after = case["before"], case["after"]
    rows = [
        ["mixture (timed, unprofiled)", num(before["mixture_s"]), num(after["mixture_s"])],
        ["whole tile (solve_tile)", num(before["tile_s"]), num(after["tile_s"])],
        ["iterations", before["iterations"], after["iterations"]],
    ]
    for section in before["sections_s"]:
        depth = (len(section) - len(section.lstrip())) // 2  # sub-sections indented
        name = "&nbsp;&nbsp;" * depth + section.strip()
        rows.append([name, num(before["sections_s"][section]), num(after["sections_s"].get(section))])
    for key in ("median", "p95"):
        rows.append(
            [
                f"128^2 nRMSE {key}",
                num(before["accuracy_128"][key], 5),
                num(after["accuracy_128"][key], 5),
            ]
        )
    return [
        f"**The endmember mixture on one tile** ({case['set']}; before `{case['baseline_commit']}`, "
        f"after `{case['commit']}`, one run; mixture {case['mixture_speedup']}x, tile "
        f"{case['tile_speedup']}x; the sections are cProfile's cumulative seconds of a second, "
        "profiled call). Note from the JSON: " + case["note"],
        table(["seconds", "before", "after"], rows),
    ] + _mixture_throughput(case.get("throughput_2048"))


def _mixture_throughput(run: Json | None) -> list[str]:
    if not run:
        return []
    rows = [
        [
            run[key]["commit"],
            run[key]["seconds_per_mpx_image"],
            "/".join(str(s) for s in run[key]["seconds_per_tile"]),
            run[key]["peak_rss_gb"],
            "{} / {}".format(*(num(run[key]["accuracy_128"].get(q), 4) for q in ("median", "p95"))),
        ]
        for key in ("before", "after")
    ]
    return [
        f"The same change at 2048^2 (as above: 2 interior 256 px tiles on 2 threads), before and "
        f"after in one run: {run['speedup']}x. Note from the JSON: {run['note']}",
        table(
            ["code", "s per Mpx-image", "s per tile", "peak RSS GB", "128^2 nRMSE median / p95"], rows
        ),
    ]


def _throughput_profile(profile: Json | None) -> list[str]:
    if not profile:
        return []
    rows = [[r["section"], num(r["before_s"]), num(r["after_s"])] for r in profile["sections"]]
    out = [
        f"**Where a tile's time goes** ({profile['note']})",
        table(["section", "before s", "after s"], rows),
    ]
    before, after = profile["before"], profile["after"]
    if "stage_peak_rss_gb" in after:  # the resident set each stage had reached (kept heap)
        stages = dict.fromkeys([*before.get("stage_peak_rss_gb", {}), *after["stage_peak_rss_gb"]])
        out += [
            f"**Where a tile's peak forms**: the resident set (GB) a stage had reached; peak "
            f"{num(before['peak_rss_gb'])} -> {num(after['peak_rss_gb'])} GB, formed in "
            f"{before.get('peak_stage', '-')} -> {after['peak_stage']}.",
            table(
                ["stage", "before GB", "after GB"],
                (
                    [
                        stage,
                        num(before.get("stage_peak_rss_gb", {}).get(stage)),
                        num(after["stage_peak_rss_gb"].get(stage)),
                    ]
                    for stage in stages
                ),
            ),
        ]
    return out


def node_table(seconds: dict[str, float], peaks: dict[str, float] | None) -> str:
    """Per node its seconds and, where the run recorded them, the process's peak resident set
    while it ran (flows/memory.py)."""
    if not peaks:
        return table(["node", "s"], ([f"`{k}`", v] for k, v in seconds.items()))
    return table(
        ["node", "s", "peak resident GB"], ([f"`{k}`", v, peaks.get(k, "")] for k, v in seconds.items())
    )


def paper_slice(data: Json) -> list[str]:
    return [
        f"The paper recipe at {data['size']}^2 through every node of the `btf` flow (a real Prefect "
        f"run on a zarr store on disk): {data['images']} images, {data['images_with_bands']} with "
        f"the band shots of one sweep, {data['sets']} set, {data['dark_frames_per_exposure']} dark "
        "frames per exposure time, in one fresh process.",
        table(
            ["measure", "value"],
            [
                ["wall time, all nodes", f"{num(data['wall_s'])} s"],
                ["after the simulation", f"{num(data['processing_s'])} s"],
                ["processing per Mpx-image", f"{num(data['processing_seconds_per_mpx_image'])} s"],
                ["peak resident set", f"{num(data['peak_rss_gb'])} GB"],
                ["store on disk", f"{num(data['store_gb'])} GB"],
                ["full run on 100 cores, extrapolated", f"{num(data['full_run_hours_at_100_cores'])} h"],
            ],
        ),
        node_table(data["node_seconds"], data.get("node_peak_rss_gb")),
        table(
            ["images", "median / p95 nRMSE"],
            ([k.replace("_", " "), pair(v)] for k, v in data["accuracy"].items()),
        ),
    ]


def cli(data: Json) -> list[str]:
    labels = {
        "python_start_s": "`python -c pass` (the interpreter alone)",
        "help_s": "`spectralize --help`",
        "version_s": "`spectralize --version`",
        "nodes_s": "`spectralize nodes` (cached listing)",
        "nodes_uncached_s": "`spectralize nodes --refresh` (loads every node)",
    }
    return [
        f"Median wall time of {data['repeat']} fresh processes per command; target under "
        f"{num(data['target_s'])} s for `--help`, `--version` and `nodes` (met: {num(data['met'])}).",
        table(["command", "s"], ([label, data[key]] for key, label in labels.items() if key in data)),
    ]


def calibration_camera_matrix(data: Json) -> list[str]:
    """C of physical shape: each fitting method on each camera, over illuminants and charts."""
    setup = data["setup"]
    rows = [
        [
            f"`{name}`" + (" (held out)" if entry.get("held_out") else ""),
            " / ".join(pct(v) for v in entry["c_error_mean_rgb"]),
            " / ".join(pct(v) for v in entry["c_error_max_rgb"]),
            pct(entry["share_of_cases_all_channels_within_5pct"]),
            f"{pct(entry['chart_loo_mean'])} / {pct(entry['chart_loo_max'])}",
        ]
        for name, entry in data["summary"].items()
    ]
    return [
        "The camera matrix C fitted from a chart's patch RGB (noise "
        f"{pct(setup['patch_rgb_noise'])}, the white reference as one more patch) under "
        f"{', '.join(setup['illuminants'])} with {', '.join(setup['charts'])}, {setup['seeds']} noise "
        f"draws; settings chosen on {', '.join(setup['cameras_tuned_on'])}; "
        f"{', '.join(setup['cameras_held_out'])} held out. C error: {setup['c_error']}; chart: "
        f"{setup['chart_loo']}.",
        table(
            [
                "method / camera",
                "C error mean R / G / B",
                "C error max R / G / B",
                "cases all within 5 %",
                "chart leave-one-out mean / max",
            ],
            rows,
        ),
    ]


def calibration_oracle(data: Json) -> list[str]:
    """Calibrated chain against the oracle (the writer's truth injected) per foreign lab."""
    out = [
        "The foreign gantries' captures (tests/support) through ingest and `run btf`, then the "
        "reconstruction twice in one process: on the calibrated groups and on the writer's truth "
        f"injected ({data['setup']['oracle']}). nRMSE per pixel `|S - T| / |T|` against the "
        "writer's radiance of each image (median / p95, share below 0.03), per RGB camera, with and "
        f"without band shots. {data['setup']['held_out']}.",
    ]
    for lab, result in data["labs"].items():
        rows = [
            [
                key,
                pair(value["calibrated"]),
                pct(value["calibrated"]["share_below_0.03"]),
                pair(value["oracle"]),
                f"{num(value['ratio_median'])} / {num(value['ratio_p95'])}",
                pair(value["calibrated"], "shape_median", "shape_p95"),
            ]
            for key, value in result["spectra"].items()
        ]
        ablation = result.get("ablation", {})
        if ablation:
            rows = [row + [pair(ablation[variant].get(row[0])) for variant in ablation] for row in rows]
        out += [
            f"**{lab}** (paired camera {result['paired_camera']})",
            table(
                [
                    "images",
                    "calibrated nRMSE",
                    "< 0.03",
                    "oracle nRMSE",
                    "calibrated / oracle",
                    "calibrated shape error",
                    *(f"{variant} injected" for variant in ablation),
                ],
                rows,
            ),
            table(
                ["camera", "model", "C from", "C error R / G / B", "chart mean / max"],
                [
                    [
                        name,
                        entry["model"],
                        entry.get("c_source", "-"),
                        " / ".join(pct(v) for v in entry.get("c_error", [])) or "-",
                        f"{pct(entry.get('chart_cross_check_mean'))} / "
                        f"{pct(entry.get('chart_cross_check_max'))}",
                    ]
                    for name, entry in result["calibration"].items()
                ],
            ),
            "Band radiance against the oracle's: largest band bias "
            f"{pct(result['band_radiance']['max_abs_band_bias'])}; LED scale spread "
            f"{pct(result['band_radiance']['led_scale_spread'])} with the LED power table, "
            f"{pct(result['band_radiance_without_led_table']['led_scale_spread'])} without. "
            + (
                "Second camera model over the paired model (without bands, median / p95): "
                + ", ".join(
                    f"{name} {num(v['median'])} / {num(v['p95'])}"
                    for name, v in result["second_model_over_paired_model"].items()
                )
                + "".join(
                    f"; oracle {name} {num(v['median'])} / {num(v['p95'])}"
                    for name, v in result.get("second_model_over_paired_model_oracle", {}).items()
                )
                + "".join(
                    f"; with one C and the 3 x 3 map ({variant}) {name} {num(v['median'])} / "
                    f"{num(v['p95'])}"
                    for variant, ratios in result.get("second_model_over_paired_model_one_c", {}).items()
                    for name, v in ratios.items()
                )
                + "."
                if result.get("second_model_over_paired_model")
                else ""
            )
            + "".join(
                f" The 3 x 3 map of {name} onto the paired camera (true C) on the scene's spectra: "
                f"{pct(v['median'])} / {pct(v['p95'])} (median / p95)."
                for name, v in result.get("map_error_on_scene", {}).items()
            )
            + _flat_field_line(result.get("flat_field")),
        ]
    for kind, what in (("falloff", "lens falloff"), ("white_level", "an undeclared white level")):
        split = data.get(f"{kind}_against_clean_split", {})
        for lab, ratios in data.get(f"{kind}_against_clean", {}).items():
            out += [_twin_table(lab, what, ratios, split.get(lab, {}))]
    return out


def _twin_table(lab: str, what: str, ratios: dict, split: dict) -> str:
    """A twin capture against its clean twin: the calibrated ratio and, where the benchmark
    split it, the capture's own part (oracle over oracle) and the calibration's part."""
    header = ["images", "median", "p95"]
    if split:
        header += ["oracle twin / clean (median / p95)", "calibration's part (median / p95)"]
    rows = []
    for key, v in ratios.items():
        row = [key, num(v["median"]), num(v["p95"])]
        if split:
            parts = split.get(key, {})
            row += [
                f"{num(parts[part]['median'])} / {num(parts[part]['p95'])}" if part in parts else ""
                for part in ("oracle", "calibration")
            ]
        rows.append(row)
    return (
        f"**{lab} against its clean twin** (calibrated nRMSE with {what} over without; target at "
        "most 1.1; the capture's own part is what the twin costs with the writer's true "
        "calibration)\n\n" + table(header, rows)
    )


def _flat_field_line(flat: dict | None) -> str:
    """The recovered flat fields against the writer's falloff (labs with falloff)."""
    if not flat:
        return ""
    cameras = ", ".join(
        f"{name} {pct(v['max_inner'])} / {pct(v['p95_inner'])}" for name, v in flat["rgb"].items()
    )
    band = flat["spectral"]
    return (
        " Flat field against the true falloff, |F / F_true - 1| away from the border (max / p95): "
        f"{cameras}; spectral camera {pct(band['max_inner'])} / {pct(band['p95_inner'])} (worst "
        f"band {band['worst_band_nm']:g} nm)."
    )


def full_run(data: Json) -> list[str]:
    """The full run's geometry with small frames, one row per image count measured."""
    targets = data["targets"]
    out = [
        f"The full run's geometry (24 rotations x 198 LEDs x 11 cameras = {data['full_run_images']:,} "
        "images; a subset keeps every rotation and camera and fewer LEDs) with small frames, "
        "written as a capture folder, ingested and run through the whole `btf` flow, each a fresh "
        "process. Targets: at most "
        f"{targets['files_per_image']} files per image, {targets['largest_group_metadata_bytes']:,} "
        f"bytes of metadata per group, {targets['seconds_per_1000_images']} s per 1,000 images "
        f"(ingest and flow), {targets['peak_rss_gb']} GB peak RSS, "
        f"{targets['open_and_read_coordinates_s']} s to open `spectra` and read its coordinates.",
        table(
            [
                "images",
                "frame px",
                "files / image",
                "largest group metadata B",
                "ingest s",
                "flow s",
                "s / 1000 images",
                "peak RSS GB",
                "open + coords s",
            ],
            [
                [
                    run["images"],
                    run["frame_px"],
                    run["files_per_image"],
                    run["largest_group_metadata_bytes"],
                    run["ingest_s"],
                    run["flow_s"],
                    run["seconds_per_1000_images"],
                    run["peak_rss_gb"],
                    run["open_and_read_coordinates_s"],
                ]
                for run in data["runs"]
            ],
        ),
    ]
    timed = [run for run in data["runs"] if run.get("node_s")]
    if timed:
        nodes = list(timed[-1]["node_s"])
        out.append(
            table(
                ["images", *nodes],
                [[run["images"], *(run["node_s"].get(n) for n in nodes)] for run in timed],
            )
        )
    weighed = [run for run in data["runs"] if run.get("node_peak_rss_gb")]
    if weighed:  # per node, the flow process's peak resident set while it ran
        nodes = list(weighed[-1]["node_peak_rss_gb"])
        out.append(
            table(
                ["images", *(f"{n} GB" for n in nodes)],
                [[run["images"], *(run["node_peak_rss_gb"].get(n) for n in nodes)] for run in weighed],
            )
        )
    return out


def staged_write(data: Json) -> list[str]:
    """A resumable write, before and after, side by side."""
    before, after = data["before"], data["after"]
    rows = (
        [
            label,
            side["write_s"],
            side["write_cpu_s"],
            side["peak_rss_gb"],
            "yes" if side["identical"] else "NO",
        ]
        for label, side in (
            (f"before (`{data['baseline_commit']}`)", before),
            (f"after (`{data['commit']}`)", after),
        )
    )
    return [
        f"{num(after['images'])} images of a run's spectra shape (32 bands x 32^2 px) in "
        f"{after['regions']} regions of unequal size, written two regions at a time and packed; "
        f"each side a fresh process, machine load {num(data['load_average'])}. "
        f"Speed-up {num(data['speedup'])}x.",
        table(["code", "write s", "write CPU s", "peak RSS GB", "read back identical"], rows),
    ]


def spectra_bytes(data: Json) -> list[str]:
    """A reconstructed cube stored losslessly and at its precision, side by side."""
    rows = []
    for row in data["scenes"]:
        before, after = row["before"], row["after"]
        rows.append(
            [
                row["scene"] + ("" if row["scene"] in data["choice"]["scenes"] else " (held out)"),
                f"{row['images']} x {row['size']}^2",
                before["radiance_bytes_per_mpx_image"] / 1e6,
                after["radiance_bytes_per_mpx_image"] / 1e6,
                pct(row["ratio"]),
                f"{after['max_relative_error']:.3e}",
                "yes" if after["within_bound"] and not after["validate_deep_problems"] else "NO",
                f"{num(before['write_s'])} / {num(after['write_s'])}",
                f"{num(before['read_s'])} / {num(after['read_s'])}",
                pct(row["per_spectrum_peak"]["ratio"]) if "per_spectrum_peak" in row else "-",
            ]
        )
    summary = []
    for label, key in (("codec chosen on", "choice"), ("held out", "held_out")):
        part = data[key]
        peak = part.get("per_spectrum_peak_ratio_worst")
        summary.append(
            f"{label} ({', '.join(part['scenes'])}): {pct(part['ratio_mean'])} of the lossless "
            f"bytes on average, worst {pct(part['ratio_worst'])} (target <= "
            f"{pct(data['target_ratio'])}: {verdict(part['ratio_worst'] <= data['target_ratio'])})"
            + ("" if peak is None else f"; with a quantum per spectrum worst {pct(peak)}")
        )
    return [
        f"`spectra`'s radiance rounded to {data['keepbits']} mantissa bits (every value within "
        f"{data['relative_bound']:.3e} relative of the computed one) vs float32 with zstd, as "
        f"stores were written before; machine load {num(data['load_average'])}. "
        + "; ".join(summary)
        + ".",
        table(
            [
                "scene",
                "images",
                "before MB/Mpx-image",
                "after MB/Mpx-image",
                "after/before",
                "max relative error",
                "within bound, validates",
                "write s before / after",
                "read s before / after",
                "per-spectrum quantum / before",
            ],
            rows,
        ),
    ]


def node_memory(data: Json) -> list[str]:
    sizes = [str(s) for s in data["sizes"]]
    codes = list(data["peak_gb"])
    direct = [s for s in next(iter(data["peak_gb"]["after"].values())) if s not in sizes]
    rows = []
    for node in data["peak_gb"]["after"]:
        for code in codes:
            peaks = data["peak_gb"][code][node]
            rows.append(
                [
                    f"`{node}`",
                    code,
                    *(peaks.get(s) for s in sizes),
                    data["extrapolated_2048_gb"][code][node],
                    *(peaks.get(s) for s in direct),
                ]
            )
    return [
        f"Peak resident set per calibration node [GB], each node in a fresh process as the flow "
        f"runs it, on the {data['recipe']}; before: commit `{data['baseline_commit']}`. "
        f"2048^2 extrapolated: {data['extrapolation']}. Target: {num(data['target_gb'])} GB.",
        table(
            [
                "node",
                "code",
                *(f"{s}^2" for s in sizes),
                "2048^2 extrapolated",
                *(f"{s}^2 measured" for s in direct),
            ],
            rows,
        ),
        table(
            ["node", "at most 8 GB at 2048^2"],
            ([f"`{k}`", verdict(v)] for k, v in data["met_at_2048"].items()),
        ),
    ]


Section = tuple[str, str, str, Callable[[Json], list[str]]]
SECTIONS: tuple[Section, ...] = (
    (
        "reconstruction",
        "Reconstruction on the hard scenes",
        "python benchmarks/reconstruction.py",
        reconstruction,
    ),
    (
        "reconstruction_oracle",
        "What the hard scenes allow",
        "python benchmarks/reconstruction_oracle.py",
        reconstruction_oracle,
    ),
    (
        "reconstruction_run_library",
        "The run's endmember library on the hard scenes",
        "python benchmarks/reconstruction_run_library.py",
        reconstruction_run_library,
    ),
    (
        "reconstruction_targets",
        "The reconstruction's targets, row by row",
        "python benchmarks/reconstruction_targets.py",
        reconstruction_targets,
    ),
    (
        "reconstruction_legacy",
        "Reconstruction on the earlier scene",
        "python benchmarks/reconstruction.py --legacy",
        reconstruction_legacy,
    ),
    ("calibration", "Calibration (paper section 4)", "python benchmarks/calibration.py", calibration),
    (
        "calibration_camera_matrix",
        "A camera matrix of physical shape",
        "python benchmarks/calibration.py --camera-matrix",
        calibration_camera_matrix,
    ),
    (
        "calibration_oracle",
        "What calibration costs on foreign gantries",
        "python benchmarks/calibration_oracle.py",
        calibration_oracle,
    ),
    ("btf_flow", "The whole BTF flow on the demo run", "python benchmarks/btf_flow.py", btf_flow),
    (
        "paper_scale",
        "Paper scale: tiled set reconstruction",
        "python benchmarks/paper_scale.py",
        paper_scale,
    ),
    (
        "paper_scale_2048_rerun",
        "Paper scale: 2048^2 per method",
        "python benchmarks/paper_scale_default.py",
        paper_scale_2048_rerun,
    ),
    (
        "paper_scale_throughput",
        "Paper scale: 2048^2 throughput before and after",
        "python benchmarks/paper_scale_throughput.py --baseline-commit REV",
        paper_scale_throughput,
    ),
    (
        "paper_slice",
        "Paper-scale slice through the whole flow",
        "python benchmarks/paper_slice.py",
        paper_slice,
    ),
    (
        "node_memory",
        "Peak memory of the calibration nodes",
        "python benchmarks/node_memory.py",
        node_memory,
    ),
    (
        "full_run",
        "A full run's geometry with small frames",
        "python benchmarks/full_run.py --images N",
        full_run,
    ),
    (
        "staged_write",
        "A resumable write of a run's spectra",
        "python benchmarks/staged_write.py --baseline-commit REV",
        staged_write,
    ),
    (
        "spectra_bytes",
        "Bytes of the spectra: lossless vs their precision",
        "python benchmarks/spectra_bytes.py",
        spectra_bytes,
    ),
    ("cli", "Command line start-up", "python benchmarks/cli.py", cli),
)
"""(JSON name, title, command, renderer), in page order."""


def read_notes(path: Path = NOTES) -> dict[str, str]:
    """The hand-written ``## <name>`` sections of the notes file, by benchmark name."""
    if not path.exists():
        return {}
    notes: dict[str, list[str]] = {}
    current = None
    for line in path.read_text().splitlines():
        if line.startswith("## "):
            current = line[3:].strip()
            notes[current] = []
        elif current is not None:
            notes[current].append(line)
    known = {name for name, *_ in SECTIONS}
    unknown = sorted(set(notes) - known)
    if unknown:
        raise SystemExit(f"{path}: sections {unknown} name no benchmark; known: {sorted(known)}")
    return {name: "\n".join(lines).strip() for name, lines in notes.items()}


def render(results: Path = RESULTS, notes_path: Path = NOTES) -> str:
    """The whole page, from the JSON files in ``results`` and the notes file."""
    notes = read_notes(notes_path)
    names = {path.stem for path in results.glob("*.json")}
    unused = sorted(names - {name for name, *_ in SECTIONS})
    if unused:
        raise SystemExit(f"{results}: {unused} have no section in benchmarks/results_page.py")
    parts = [
        "# Benchmarks",
        "<!-- Generated by benchmarks/results_page.py from benchmarks/results/*.json and "
        "docs/benchmarks_notes.md; do not edit by hand. -->",
        "Every figure below is read from the JSON a benchmark wrote into `benchmarks/results/`; "
        "the prose under *Findings* is hand-written (`docs/benchmarks_notes.md`). Times are from "
        "the machine named with each JSON, shared with other work while measuring, so they are "
        "upper bounds. To refresh: run the benchmark, then `python benchmarks/results_page.py`.",
        "\n".join(f"- [{title}](#{anchor(title)})" for name, title, _, _ in SECTIONS if name in names),
    ]
    for name, title, command, renderer in SECTIONS:
        if name not in names:
            continue
        data = json.loads((results / f"{name}.json").read_text())
        parts += [f"## {title}", f"Run: `{command}`. {provenance(data, name)}"]
        parts += renderer(data)
        if notes.get(name):
            parts += ["**Findings**", notes[name]]
    return "\n\n".join(parts) + "\n"


def anchor(title: str) -> str:
    """GitHub's anchor of a heading."""
    kept = "".join(c for c in title.lower() if c.isalnum() or c in " -_")
    return kept.replace(" ", "-")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if docs/benchmarks.md is stale")
    args = parser.parse_args(argv)
    page = render()
    if args.check:
        if not PAGE.exists() or PAGE.read_text() != page:
            print(f"{PAGE.relative_to(ROOT)} is stale: run python benchmarks/results_page.py")
            return 1
        return 0
    PAGE.write_text(page)
    print(f"wrote {PAGE.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
