"""Benchmark of the spectral reconstruction (eq. 1): accuracy, speed, memory, scaling.

Run from the repository root::

    .venv/bin/python benchmarks/reconstruction.py            # hard scenes (about 10-15 min)
    .venv/bin/python benchmarks/reconstruction.py --quick    # hard scenes, small sizes
    .venv/bin/python benchmarks/reconstruction.py --legacy   # the earlier single-scene run

By default every hard scene (``spectralize.nodes.simulation.scenes``) x 2 noise seeds x
every method, single image (128^2, all 32 bands) and 20-image sets (48^2, 10 images with
bands): see ``benchmarks/reconstruction_hard.py``. ``--legacy`` runs the earlier comparison
below.

Progress goes to stdout line by line; the LAST line is one JSON object, also written to
``benchmarks/results/reconstruction.json`` (``--legacy``: ``reconstruction_legacy.json``;
``--output`` to choose). All methods run on the same
simulated capture (``benchmarks/reconstruction_scene.py``: the project's ground-truth
texture and exposure plan, eq. 2/3, 3 DN noise). Per method: median, p95, p99 of the
per-pixel nRMSE (RMSE over bands / mean ground-truth intensity of the image, paper Fig. 5),
the fraction of pixels under 0.03, wall and CPU time, peak memory and iterations; on the hard
scenes also the CIEDE2000 of the spectra relit under CIE A, FL11 and D65 against the truth
relit alike (median / p95 per light, ``relit_de2000``).

Memory: ``peak_traced_mb`` is the tracemalloc peak during the call (numpy and scipy arrays
are traced; the k-d tree's own C++ buffers are not); the scaling cases run in fresh
processes and also report ``peak_rss_mb``, the process's resident-set high-water mark
(``VmHWM`` of ``/proc/self/status``; scene simulation and imports included, so an upper
bound) and ``rss_before_mb``, the resident set just before the call.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from reconstruction_hard import run_suite  # noqa: E402
from reconstruction_scene import nrmse_per_pixel, simulate_capture  # noqa: E402

from spectralize.nodes.reconstruction import (  # noqa: E402
    BASELINE_METHODS,
    DEFAULT_METHOD,
    build_problem,
    inputs_from_xarray,
    reconstruct,
)
from spectralize.nodes.reconstruction.solvers import (  # noqa: E402
    block_jacobi_pcg,
    paper_cg,
    projected_filtered_initial,
)

ACCURACY_SLACK = 0.01
"""Time-to-equal-accuracy counts a solver as there once its median nRMSE is within 1 % of
the paper-CG's final median nRMSE."""


def resident_mb(field: str = "VmHWM") -> float:
    """``VmHWM`` (peak) or ``VmRSS`` (current) resident set of this process in MB."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return float(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def statistics(nrmse: np.ndarray) -> dict:
    values = np.asarray(nrmse, dtype=np.float64).ravel()
    return {
        "median": float(np.median(values)),
        "p95": float(np.percentile(values, 95)),
        "p99": float(np.percentile(values, 99)),
        "fraction_under_0.03": float(np.mean(values < 0.03)),
        "max": float(values.max()),
    }


def measured(function, *args, **kwargs):
    """Run ``function``; return (result, wall s, cpu s, tracemalloc peak MB)."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    wall, cpu = time.perf_counter(), time.process_time()
    result = function(*args, **kwargs)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return result, wall, cpu, peak / 2**20


class Curve:
    """Solver callback: median nRMSE per iteration with the time spent outside it."""

    def __init__(self, truth: np.ndarray, every: int = 1):
        self.truth = np.moveaxis(np.asarray(truth, dtype=np.float32), 1, 0)  # (w, m, y, x)
        self.mean = self.truth.mean(axis=(0, 2, 3))
        self.every = every
        self.points: list[tuple[int, float, float]] = []
        self.start = time.perf_counter()
        self.excluded = 0.0

    def restart(self) -> None:
        self.start, self.excluded, self.points = time.perf_counter(), 0.0, []

    def __call__(self, iteration: int, cube: np.ndarray) -> None:
        entered = time.perf_counter()
        if iteration % self.every == 0 or iteration <= 3:
            squared = np.zeros(self.truth.shape[1:], dtype=np.float64)
            for b in range(self.truth.shape[0]):
                squared += (cube[b].astype(np.float32) - self.truth[b]) ** 2
            nrmse = np.sqrt(squared / self.truth.shape[0]) / self.mean[:, None, None]
            self.points.append(
                (iteration, entered - self.start - self.excluded, float(np.median(nrmse)))
            )
        self.excluded += time.perf_counter() - entered

    def time_to(self, target: float) -> float | None:
        for _, t, median in self.points:
            if median <= target:
                return t
        return None


def method_row(
    spectra: np.ndarray,
    truth: np.ndarray,
    wall: float,
    cpu: float,
    peak: float,
    iterations: int,
    **extra,
) -> dict:
    e = nrmse_per_pixel(spectra, truth)
    row = {
        **statistics(e),
        "wall_s": round(wall, 3),
        "cpu_s": round(cpu, 3),
        "peak_traced_mb": round(peak, 1),
        "iterations": int(iterations),
    }
    if e.shape[0] > 1:
        row["per_image_median"] = [round(float(np.median(x)), 5) for x in e]
    row.update(extra)
    return row


# -- the comparison on one capture -------------------------------------------------------------
def compare_methods(size: int, seed: int, *, ablation_size: int | None) -> dict:
    log(f"simulating the default scene, one image {size}x{size}x32, seed {seed}")
    capture = simulate_capture(size, seed=seed)
    truth = capture.truth.values
    rgb, bands, c = capture.rgb, capture.bands, capture.camera_matrix
    methods: dict[str, dict] = {}

    for name in BASELINE_METHODS:
        out, wall, cpu, peak = measured(reconstruct, rgb, bands, c, method=name)
        methods[name] = method_row(out.values, truth, wall, cpu, peak, 0, kind="baseline")
        log(
            f"baseline {name:20s} median {methods[name]['median']:.4f} "
            f"<0.03 {methods[name]['fraction_under_0.03']:.3f}  {wall:.2f} s"
        )

    runs = {}
    for name in (DEFAULT_METHOD, "paper-cg"):
        result, wall, cpu, peak = measured(reconstruct, rgb, bands, c, method=name, full_output=True)
        runs[name] = result
        methods[name] = method_row(
            result.spectra.values,
            truth,
            wall,
            cpu,
            peak,
            result.iterations,
            kind="solver",
            setup_s=round(result.setup_time, 3),
            converged=bool(result.converged),
            final_relative_residual=float(result.residual_history[-1]),
        )
        log(
            f"solver {name:22s} median {methods[name]['median']:.4f} "
            f"<0.03 {methods[name]['fraction_under_0.03']:.3f}  {wall:.2f} s, "
            f"{result.iterations} iterations"
        )

    # the bias floor of eq. 1 itself: the default solver on noise-free bands
    clean = bands.copy(
        data=truth[0][np.searchsorted(c["wavelength"].values, bands["wavelength"].values)]
    )
    result, wall, cpu, peak = measured(reconstruct, rgb, clean, c, full_output=True)
    noise_free = method_row(result.spectra.values, truth, wall, cpu, peak, result.iterations)
    log(
        f"default solver on noise-free bands: median {noise_free['median']:.4f} "
        f"<0.03 {noise_free['fraction_under_0.03']:.3f}"
    )

    # time to equal accuracy: convergence curves with the metric's own time excluded
    curve = Curve(truth)
    log("convergence curves (paper-cg, then the default)")
    curve.restart()
    paper_run = reconstruct(rgb, bands, c, method="paper-cg", callback=curve, full_output=True)
    paper_curve = list(curve.points)
    paper_final = paper_curve[-1][2] if paper_curve else methods["paper-cg"]["median"]
    target = paper_final * (1 + ACCURACY_SLACK)
    paper_total = curve.time_to(target)
    curve.restart()
    default_run = reconstruct(rgb, bands, c, callback=curve, full_output=True)
    default_curve = list(curve.points)
    default_total = curve.time_to(target)
    speed = {
        "target_median_nrmse": target,
        "paper_cg_final_median_nrmse": paper_final,
        "paper_cg_seconds_to_target": paper_total,
        "default_seconds_to_target": default_total,
        "paper_cg_setup_s": round(paper_run.setup_time, 3),
        "default_setup_s": round(default_run.setup_time, 3),
        "speedup_time_to_equal_accuracy": (
            None if not (paper_total and default_total) else round(paper_total / default_total, 2)
        ),
        "paper_cg_iterations_to_target": next((i for i, _, m in paper_curve if m <= target), None),
        "default_iterations_to_target": next((i for i, _, m in default_curve if m <= target), None),
        "speedup_total_wall": round(
            methods["paper-cg"]["wall_s"] / methods[DEFAULT_METHOD]["wall_s"], 2
        ),
        "paper_cg_curve": [[i, round(t, 3), round(m, 6)] for i, t, m in paper_curve[::5]],
        "default_curve": [[i, round(t, 3), round(m, 6)] for i, t, m in default_curve],
        "note": "seconds from the start of the reconstruct call (input checks, "
        "neighbour search and operator set-up included) to the first iteration "
        f"whose median nRMSE is within {ACCURACY_SLACK:.0%} of the paper-CG's final "
        "median; the metric's own time is excluded",
    }
    log(
        f"time to median nRMSE {target:.5f}: paper-cg {paper_total} s, default "
        f"{default_total} s -> {speed['speedup_time_to_equal_accuracy']}x"
    )

    out = {
        "scene": {
            "size": size,
            "n_images": 1,
            "seed": seed,
            "filter_size_px": [round(float(s), 2) for s in bands["filter_size"].values],
            "exposure_time_s": [round(float(t), 4) for t in capture.plan["exposure_time"].values],
            "truth_mean": float(truth.mean()),
            "truth_max": float(truth.max()),
        },
        "methods": methods,
        "default_on_noise_free_bands": noise_free,
        "time_to_equal_accuracy": speed,
    }
    baseline_best = min(v["median"] for v in methods.values() if v["kind"] == "baseline")
    out["targets"] = {
        "default_median_vs_best_baseline": round(baseline_best / methods[DEFAULT_METHOD]["median"], 3),
        "beats_every_baseline_median_2x": baseline_best >= 2 * methods[DEFAULT_METHOD]["median"],
        "default_fraction_under_0.03": methods[DEFAULT_METHOD]["fraction_under_0.03"],
        "at_least_99_percent_under_0.03": methods[DEFAULT_METHOD]["fraction_under_0.03"] >= 0.99,
        "time_to_equal_accuracy_at_least_5x": (speed["speedup_time_to_equal_accuracy"] or 0) >= 5,
    }
    if ablation_size:
        if ablation_size != size:
            log(f"ablation on a {ablation_size}x{ablation_size} capture of the same scene")
            capture = simulate_capture(ablation_size, seed=seed)
            target = None
        out["ablation"] = solver_ablation(capture, target)
        out["weight_sensitivity"] = weight_sensitivity(capture)
    return out


def weight_sensitivity(capture) -> dict:
    """Accuracy of the default solver for other relative weights of eq. 4 (same capture)."""
    truth = capture.truth.values
    rows = {"size": int(capture.truth.sizes["y"])}
    for options in (
        {},
        {"gamma_hat": 0.3},
        {"gamma_hat": 3.0},
        {"beta_hat": 10.0},
        {"alpha_hat": 3.0},
        {"k": 6},
    ):
        result = reconstruct(
            capture.rgb, capture.bands, capture.camera_matrix, full_output=True, **options
        )
        name = ", ".join(f"{k}={v}" for k, v in options.items()) or "paper defaults"
        rows[name] = {
            **statistics(nrmse_per_pixel(result.spectra.values, truth)),
            "iterations": result.iterations,
        }
        log(
            f"weights {name:16s} median {rows[name]['median']:.4f} "
            f"<0.03 {rows[name]['fraction_under_0.03']:.3f}"
        )
    return rows


def solver_ablation(capture, target: float | None) -> dict:
    """What each ingredient of the default solver buys, on the same problem.

    ``target``: median nRMSE to reach; ``None``: the paper-CG's final one (+1 %) here.
    """
    inputs = inputs_from_xarray(capture.rgb, capture.bands, capture.camera_matrix)
    truth = capture.truth.values
    problem64 = build_problem(inputs, dtype=np.float64)
    if target is None:
        curve = Curve(truth)
        paper_cg(problem64, callback=curve)
        target = curve.points[-1][2] * (1 + ACCURACY_SLACK)
    problem32 = problem64.astype(np.float32)
    initial = projected_filtered_initial(problem64)
    zeros = np.zeros(problem64.shape)
    variants = {
        "paper-cg (CGNR, float64, zero start)": (paper_cg, problem64, {}),
        "cg on A^T A, float64, zero start": (
            block_jacobi_pcg,
            problem64,
            {"dtype": np.float64, "initial": zeros, "ridge": 0.0, "precondition": False},
        ),
        "+ block-Jacobi preconditioner": (
            block_jacobi_pcg,
            problem64,
            {"dtype": np.float64, "initial": zeros, "ridge": 0.0},
        ),
        "+ float32": (block_jacobi_pcg, problem32, {"initial": zeros, "ridge": 0.0}),
        "+ initial guess (filtered bands projected)": (
            block_jacobi_pcg,
            problem32,
            {"initial": initial, "ridge": 0.0},
        ),
        "+ ridge 1e-4 (eq. 1 alone)": (block_jacobi_pcg, problem32, {"initial": initial}),
        "+ guided-filter start and prior 0.1 (guided-prior-pcg)": (
            block_jacobi_pcg,
            problem32,
            {"prior": 0.1},
        ),
        "guided-prior-pcg without preconditioner": (
            block_jacobi_pcg,
            problem32,
            {"prior": 0.1, "precondition": False},
        ),
    }
    rows = {"size": int(capture.truth.sizes["y"]), "target_median_nrmse": target}
    for name, (solver, problem, options) in variants.items():
        curve = Curve(truth)
        result = solver(problem, callback=curve, max_iterations=1500, **options)
        reached = curve.time_to(target)
        rows[name] = {
            "seconds_to_target": None if reached is None else round(reached, 3),
            "iterations_to_target": next((i for i, _, m in curve.points if m <= target), None),
            "iterations": result.iterations,
            "final_median_nrmse": round(curve.points[-1][2], 6) if curve.points else None,
            "solver_seconds": round(result.wall_time - curve.excluded, 3),
        }
        log(
            f"ablation {name:45s} to target {rows[name]['seconds_to_target']} s "
            f"({rows[name]['iterations_to_target']} it), final "
            f"{rows[name]['final_median_nrmse']}"
        )
    return rows


# -- scaling: each case in a fresh process ------------------------------------------------------
def scaling_case(size: int, n_images: int, seed: int) -> dict:
    capture = simulate_capture(size, n_images=n_images, seed=seed)
    truth = capture.truth.values
    rss_before = resident_mb("VmRSS")
    result, wall, cpu, peak = measured(
        reconstruct, capture.rgb, capture.bands, capture.camera_matrix, full_output=True
    )
    row = method_row(
        result.spectra.values,
        truth,
        wall,
        cpu,
        peak,
        result.iterations,
        setup_s=round(result.setup_time, 3),
        converged=bool(result.converged),
    )
    row.update(
        {
            "size": size,
            "n_images": n_images,
            "pixels": size * size * n_images,
            "peak_rss_mb": round(resident_mb("VmHWM"), 1),
            "rss_before_mb": round(rss_before, 1),
        }
    )
    if n_images > 1:
        e = nrmse_per_pixel(result.spectra.values, truth)
        with_bands = np.unique(capture.bands["image"].values)
        without = np.setdiff1d(np.arange(n_images), with_bands)
        row["images_with_bands"] = statistics(e[with_bands])
        row["images_without_bands"] = statistics(e[without]) if without.size else None
        for name in ("filtered-projected", "wiener"):
            base = reconstruct(capture.rgb, capture.bands, capture.camera_matrix, method=name)
            row[f"baseline_{name}"] = statistics(nrmse_per_pixel(base.values, truth))
    return row


def run_scaling(cases: list[tuple[int, int]], seed: int) -> list[dict]:
    rows = []
    for size, n_images in cases:
        log(f"scaling case {n_images} x {size}^2 (fresh process)")
        done = subprocess.run(
            [sys.executable, __file__, "--case", f"{size}x{n_images}", "--seed", str(seed)],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode != 0:
            log(f"  failed: {done.stderr.strip().splitlines()[-1:]}")
            rows.append({"size": size, "n_images": n_images, "error": done.stderr[-2000:]})
            continue
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        log(
            f"  {row['wall_s']:.2f} s (set-up {row['setup_s']:.2f} s), {row['iterations']} "
            f"iterations, traced peak {row['peak_traced_mb']:.0f} MB, RSS peak "
            f"{row['peak_rss_mb']:.0f} MB, median nRMSE {row['median']:.4f}, "
            f"<0.03 {row['fraction_under_0.03']:.3f}"
        )
    singles = [r for r in rows if r.get("n_images") == 1 and "error" not in r]
    if len(singles) >= 2:
        pixels = np.array([r["pixels"] for r in singles], dtype=float)
        seconds = np.array([r["wall_s"] for r in singles])
        memory = np.array([r["peak_traced_mb"] for r in singles])
        for r in singles:
            r["seconds_per_megapixel"] = round(r["wall_s"] / (r["pixels"] / 1e6), 2)
            r["traced_mb_per_megapixel"] = round(r["peak_traced_mb"] / (r["pixels"] / 1e6), 1)
        log(
            "log-log slope of time vs pixels "
            f"{np.polyfit(np.log(pixels), np.log(seconds), 1)[0]:.2f}, of memory "
            f"{np.polyfit(np.log(pixels), np.log(memory), 1)[0]:.2f} (1 = linear)"
        )
    return rows


def hard_scenes(args) -> dict:
    """The default run: every hard scene x seed x method (:mod:`reconstruction_hard`)."""
    started = time.perf_counter()
    report = {
        "benchmark": "spectral reconstruction on the hard scenes",
        "command": "python benchmarks/reconstruction.py" + (" --quick" if args.quick else ""),
        "machine": {
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "load_average_at_start": os.getloadavg(),
        },
        **run_suite(
            quick=args.quick,
            size=args.size,
            set_size=args.set_size,
            seeds=tuple(args.seeds),
            paper_cg_sets=args.paper_cg_sets,
        ),
    }
    report["machine"]["load_average_at_end"] = os.getloadavg()
    report["total_seconds"] = round(time.perf_counter() - started, 1)
    for mode, scenes in report["summary"].items():
        for name, row in scenes.items():
            log(
                f"{mode:6s} {name:16s} default median {row['default']['median']:.4f} p95 "
                f"{row['default']['p95']:.4f} <0.03 {row['default']['fraction_under_0.03']:.3f}; best "
                f"baseline {row['best_baseline_median']['method']} "
                f"{row['best_baseline_median']['value']:.4f}"
                f" / {row['best_baseline_p95']['method']} {row['best_baseline_p95']['value']:.4f}"
                "; default relit dE00 "
                + " ".join(
                    f"{light} {v['median']:.2f}/{v['p95']:.2f}"
                    for light, v in row["relit_de2000"][DEFAULT_METHOD].items()
                )
            )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=1) + "\n")
    log(f"written {args.output}")
    print(json.dumps(report))
    return report


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, no ablation")
    parser.add_argument(
        "--size",
        type=int,
        default=None,
        help="image size of the method comparison (default 512, quick 96)",
    )
    parser.add_argument(
        "--ablation-size", type=int, default=256, help="image size of the solver ablation (default 256)"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-scaling", action="store_true")
    parser.add_argument("--no-ablation", action="store_true")
    parser.add_argument(
        "--output",
        type=Path,
        default=None,
        help="results JSON (default results/reconstruction.json; with --legacy "
        "results/reconstruction_legacy.json)",
    )
    parser.add_argument("--case", help=argparse.SUPPRESS)  # internal: one scaling case
    parser.add_argument(
        "--legacy",
        action="store_true",
        help="the earlier single-scene comparison, ablation and scaling instead of the hard scenes",
    )
    parser.add_argument(
        "--set-size", type=int, default=None, help="set image size (default 48, quick 32)"
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="noise seeds (default 0 1)")
    parser.add_argument(
        "--paper-cg-sets", action="store_true", help="also run paper-cg on the sets (slow)"
    )
    args = parser.parse_args(argv)
    if args.output is None:
        name = "reconstruction_legacy.json" if args.legacy else "reconstruction.json"
        args.output = HERE / "results" / name
    if not args.legacy and not args.case:
        return hard_scenes(args)

    if args.case:
        size, n_images = (int(v) for v in args.case.split("x"))
        print(json.dumps(scaling_case(size, n_images, args.seed)))
        return {}

    started = time.perf_counter()
    size = args.size or (96 if args.quick else 512)
    report = {
        "benchmark": "spectral reconstruction (eq. 1)",
        "command": "python benchmarks/reconstruction.py" + (" --quick" if args.quick else ""),
        "machine": {
            "cpu_count": os.cpu_count(),
            "python": platform.python_version(),
            "numpy": np.__version__,
            "load_average_at_start": os.getloadavg(),
        },
        "default_method": DEFAULT_METHOD,
        "memory_note": "peak_traced_mb: tracemalloc peak during the call; peak_rss_mb: the "
        "fresh scaling process's VmHWM (imports and scene simulation "
        "included); rss_before_mb: its VmRSS just before the call",
    }
    ablation_size = None if (args.quick or args.no_ablation) else args.ablation_size
    report["comparison"] = compare_methods(size, args.seed, ablation_size=ablation_size)
    if not args.no_scaling:
        cases = (
            [(64, 1), (128, 1), (192, 1), (64, 20)]
            if args.quick
            else [(128, 1), (512, 1), (1024, 1), (256, 20)]
        )
        report["scaling"] = run_scaling(cases, args.seed)
        big = [r for r in report["scaling"] if r.get("size") == 512 and r.get("n_images") == 1]
        if big and "error" not in big[0]:
            report["comparison"]["targets"]["512px_under_20s"] = big[0]["wall_s"] < 20
            report["comparison"]["targets"]["512px_under_4GB"] = (
                max(big[0]["peak_traced_mb"], big[0]["peak_rss_mb"]) < 4096
            )
    report["machine"]["load_average_at_end"] = os.getloadavg()
    report["total_seconds"] = round(time.perf_counter() - started, 1)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=1) + "\n")
    log(f"written {args.output}")
    print(json.dumps(report))
    return report


if __name__ == "__main__":
    main()
