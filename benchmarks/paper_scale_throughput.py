"""Reconstruction throughput at 2048^2 before and after a change, side by side in one run.

Run from the repository root::

    .venv/bin/python benchmarks/paper_scale_throughput.py --baseline-commit REV

The ``throughput`` case of ``benchmarks/paper_scale.py`` (the 512^2 glossy-mosaic capture
of 20 images mirrored up to 2048^2, two interior 256 px tiles solved two at a time on 2
threads, inputs memory-mapped) for the default method, first with the code of
``--baseline-commit`` (a git worktree), then with this checkout, each in a fresh process;
then both solve a 128^2 capture with truth whole (nRMSE: the speed-up must not change the
result). The LAST line is one JSON object, also written to
``benchmarks/results/paper_scale_throughput.json``.

``--profile`` instead profiles one interior 256 px tile of the 512^2 capture mirrored to
768^2 (``solve_tile`` as the flow calls it: the set's endmembers, the confidence, the run's
illuminant), before and after, each in a fresh process under cProfile timed in CPU seconds
(the process's, not the wall clock's: other work on a shared machine shows less in it; its
user and system parts apart, the system part mostly the kernel's page faults on fresh
memory): the cumulative seconds of the tile's stages (:data:`TILE_SECTIONS`), its resident
peak and per stage the resident set it had reached (:class:`StagePeaks`), whether both sides'
spectra and confidence are bit-identical, and both sides' 128^2 accuracy;
stored under the key ``profile_256`` of the same file (the other rows are kept).
``--after-commit REV`` (here and in the 2048^2 case) takes the "after" side from a worktree of
``REV`` too, instead of this checkout (a comparison of two commits while the checkout holds
other work).

``--mixture-tile`` instead times the mixture prior's centre (the endmember mixture) and the
whole tile (``solve_tile``, with the set's endmembers and the confidence) on one 256^2 x
20-image tile, before and after, each in a fresh process, with a cProfile of the mixture's
sections; the 128^2 accuracy of both; and stores them under the key ``mixture_tile`` of
the same file (the 2048^2 rows are kept).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "paper_scale_throughput.json"


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


MIXTURE_SECTIONS = {
    "endmember_mixture": "mixture (whole, profiled)",
    "local_correction": "  local correction (guided filters, shrinkage)",
    "guided_filtered_stacks": "    guided filters (2 window scales x 3 stacks)",
    "gaussian_window": "    box / Gaussian windows",
    "neighbourhood_candidates": "  spatial candidates (step 2b)",
    "candidates": "  chromaticity candidates",
    "rgb_abundances": "  abundance solves (2)",
    "_project": "  projection onto C S = R, S >= 0 (2)",
}


TILE_SECTIONS = {
    ("tiling", "solve_tile"): "tile (solve_tile)",
    ("operators", "build_problem"): "eq. 1 set-up (neighbours, Laplacian, filters)",
    ("neighbourhoods", "appearance_neighbours"): "  neighbour search (k-d tree)",
    ("prior_pcg", "_spectral_prior"): "spectral prior's centre",
    ("endmember_mixture", "endmember_mixture"): "  endmember mixture",
    ("natural_prior", "natural_prior"): "  natural-spectra (Wiener) prior",
    ("preconditioner", "__init__"): "block-Jacobi set-up",
    ("common", "pixel_pcg"): "PCG",
    ("projected_refinement", "projected_refinement"): "refinement (S >= 0)",
    ("kernels", "prior_normal_pixels"): "operator's compiled pass (every call)",
    ("operators", "add_normal"): "operator's filter term (every call)",
    ("material_pooled", "material_pooled_refine"): "set model (material-pooled)",
    ("material_pooled", "texel_shapes"): "  its shapes steps",
    ("material_pooled", "texel_weights"): "  its weights steps",
    ("evidence_blend", "material_choice_blend"): "set step (evidence-blend)",
    ("sparse_choice", "sparse_choice"): "  the material choice",
    ("evidence_blend", "choice_log_odds"): "  the band evidence",
    ("confidence", "neighbourhood_spread"): "confidence",
    ("operators", "to_pixels"): "pixel-major copies (to_pixels)",
}
"""The stages of a tile in ``--profile``: (module, function) -> the row's name."""


class StagePeaks:
    """The resident set (``VmRSS``) sampled while one thread solves a tile, each sample
    given to the stage of :data:`TILE_SECTIONS` innermost on that thread's stack: per stage
    the largest resident set seen (GB), and the first stage that came within 10 MB of the
    peak.

    With the heap kept between tiles (``keep_freed_memory``) the resident set only grows,
    so a stage's value is the heap the tile had grown to by its end, and the stages where
    it grows are where the peak forms."""

    def __init__(self, thread_id: int, interval: float = 0.02) -> None:
        self.thread_id, self.interval = thread_id, interval
        self.peaks: dict[str, float] = {}
        self.peak_stage = ""
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)

    def _stage(self) -> str:
        frame = sys._current_frames().get(self.thread_id)
        stage = "other"
        while frame is not None:  # innermost first
            code = frame.f_code
            key = (Path(code.co_filename).stem, code.co_name)
            if key in TILE_SECTIONS and "reconstruction" in code.co_filename:
                return TILE_SECTIONS[key].strip()
            frame = frame.f_back
        return stage

    def _sample(self) -> None:
        page = os.sysconf("SC_PAGE_SIZE") / 2**30
        trace = []
        while not self._done.wait(self.interval):
            resident = int(Path("/proc/self/statm").read_text().split()[1]) * page
            stage = self._stage()
            self.peaks[stage] = round(max(self.peaks.get(stage, 0.0), resident), 3)
            trace.append((resident, stage))
        top = max((resident for resident, _ in trace), default=0.0)
        # the first stage within 10 MB of the peak (a kept heap stays there afterwards)
        self.peak_stage = next((stage for resident, stage in trace if resident >= top - 0.01), "")

    def __enter__(self) -> StagePeaks:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._done.set()
        self._thread.join()


def profile_tile_case(folder: str, package: str | None, keep: str | None = None) -> dict:
    """In this process: one interior 256 px tile of the set in ``folder`` under cProfile (CPU
    seconds); its spectra and confidence saved to ``keep`` (``.npz``) where given."""
    import cProfile
    import pstats

    import numpy as np

    sys.path.insert(0, str(HERE))
    if package:
        from paper_scale import use_package

        use_package(package)
    from paper_scale import (
        _as_a_run,
        _set_endmembers,
        _warm_training,
        flow_settings,
        load_inputs,
        resident_gb,
        tile_method,
    )

    from spectralize.nodes.reconstruction.tiling import default_halo, solve_tile, tile_windows

    rgb, shots, camera, _ = load_inputs(Path(folder))
    size = rgb.sizes["y"]
    windows = tile_windows(size, size, 256, default_halo(shots["filter_size"].values))
    window = windows[len(windows) // 2]  # the centre tile: a full halo on every side
    endmembers, _ = _set_endmembers(rgb, shots, camera)
    _warm_training()
    oy, ox = window.outer
    profile = cProfile.Profile(time.process_time)
    started, cpu_started, times = time.perf_counter(), time.process_time(), os.times()
    with _as_a_run(), StagePeaks(threading.get_ident()) as stages:
        profile.enable()
        spectra, iterations, spread = solve_tile(
            rgb.isel(y=oy, x=ox),
            shots.isel(y=oy, x=ox),
            camera,
            window.inner,
            **tile_method(solve_tile, flow_settings(Path(folder))),
            confidence=True,
            endmembers=endmembers,
        )
        profile.disable()
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu_started
    done = os.times()
    if keep:  # the tile's results, for the other side to compare with
        np.savez(keep, spectra=spectra, confidence=spread)
    sections: dict[str, float] = {}
    for (filename, _, name), (_, _, _, cumulative, _) in pstats.Stats(profile).stats.items():
        module = Path(filename).stem
        if (module, name) in TILE_SECTIONS and "reconstruction" in filename:
            label = TILE_SECTIONS[(module, name)]
            sections[label] = round(sections.get(label, 0.0) + cumulative, 2)
    return {
        "window": list(window.outer_shape),
        "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2),
        "user_s": round(done.user - times.user, 2),  # the CPU seconds: the code's own
        "system_s": round(done.system - times.system, 2),  # and the kernel's (page faults)
        "iterations": int(iterations.max()),
        "peak_rss_gb": round(resident_gb(), 3),
        "stage_peak_rss_gb": stages.peaks,  # sampled (StagePeaks)
        "peak_stage": stages.peak_stage,
        "load_average_1min": round(os.getloadavg()[0], 1),
        "sections_s": sections,
    }


def _before_and_after(
    work: Path, package: Path, case: str, inputs: Path, after: Path | None = None
) -> dict[str, dict]:
    """One ``case`` (``--profile-case``, ``--tile-case``) on ``inputs`` with the baseline
    ``package`` and with this checkout (or the ``after`` package), each in a fresh process,
    with the 128^2 accuracy row of the same code (its first run compiles too)."""
    from paper_scale import run_case

    rows = {}
    for key, where in (("before", package), ("after", after)):
        accuracy = run_case("accuracy", work / "set128.npz", package=where)
        command = [sys.executable, str(Path(__file__).resolve()), case, str(inputs)]
        command += ["--package", str(where)] if where is not None else []
        command += ["--keep", str(work / f"{key}.npz")] if case == "--profile-case" else []
        out = subprocess.run(command, capture_output=True, text=True, check=False)
        if out.returncode != 0:
            raise RuntimeError(f"{case} ({key}) failed:\n{out.stderr[-4000:]}")
        rows[key] = {**json.loads(out.stdout.strip().splitlines()[-1]), "accuracy_128": accuracy}
        log(f"{key}: {rows[key]}")
    return rows


def _after_package(commit: str | None, work: Path) -> Path | None:
    """A worktree of ``commit`` importable as ``spectralize`` (as the baseline's, beside it),
    or None for this checkout."""
    if not commit:
        return None
    tree, shim = work / "after", work / "after-shim"
    subprocess.run(
        ["git", "worktree", "add", "--detach", "-f", str(tree), commit],
        cwd=HERE.parent,
        check=True,
        capture_output=True,
    )
    shim.mkdir()
    (shim / "spectralize").symlink_to(tree)
    return shim


def _identical(before: Path, after: Path) -> dict[str, bool]:
    """Whether the two sides' tile results are equal bit for bit, per array."""
    import numpy as np

    with np.load(before) as old, np.load(after) as new:
        return {name: bool(np.array_equal(old[name], new[name])) for name in old.files}


def profile_tile(args: argparse.Namespace, report: dict) -> None:
    """``--profile``: a 256 px tile profiled before and after, each in a fresh process."""
    from paper_scale import baseline_package, capture_inputs, run_case

    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        package = baseline_package(args.baseline_commit, work)
        after_package = _after_package(args.after_commit, work)
        log(f"capturing {args.scene} at 512^2 and 128^2 (20 images)")
        capture_inputs(args.scene, 512, 0, work / "set512.npz", truth=False)
        capture_inputs(args.scene, 128, 0, work / "set128.npz", truth=True)
        run_case("mirror", work / "set512.npz", 768, work / "mirrored768")
        rows = _before_and_after(work, package, "--profile-case", work / "mirrored768", after_package)
        identical = _identical(work / "before.npz", work / "after.npz")
        for tree in ("baseline", "after"):
            if (work / tree).exists():  # "after" is a worktree only with --after-commit
                subprocess.run(["git", "worktree", "remove", "--force", str(work / tree)], check=False)
    before, after = rows["before"], rows["after"]
    previous["profile_256"] = {
        "note": f"cProfile of one interior 256 px tile ({before['window'][0]}^2 window x 20 images, "
        f"{args.scene} 512^2 mirrored to 768^2) solved by solve_tile with the set's endmembers, "
        f"the illuminant and the confidence; before `{args.baseline_commit}`, after "
        f"`{args.after_commit or report['commit']}`, each in a fresh process in one run (load "
        f"{before['load_average_1min']} / {after['load_average_1min']}); cumulative CPU "
        "seconds, every call of a stage summed. " + args.note,
        "command": report["command"],
        "bit_identical": identical,
        "cpu_ratio": round(before["cpu_s"] / after["cpu_s"], 3),
        "user_ratio": round(before["user_s"] / after["user_s"], 3),
        "system_ratio": round(before["system_s"] / max(after["system_s"], 0.01), 3),
        "before": before,
        "after": after,
        "sections": [
            {
                "section": label,
                "before_s": before["sections_s"].get(label),
                "after_s": after["sections_s"].get(label),
            }
            for label in dict.fromkeys(TILE_SECTIONS.values())
        ],
    }
    RESULTS.write_text(json.dumps(previous, indent=1) + "\n")
    print(json.dumps(previous["profile_256"]))


def mixture_tile_case(path: str, package: str | None) -> dict:
    """In this process: the mixture and the whole tile of the 256^2 set at ``path``."""
    import cProfile
    import importlib
    import pstats

    if package:
        sys.path.insert(0, str(HERE))
        from paper_scale import use_package

        use_package(package)
    sys.path.insert(0, str(HERE))
    from paper_scale import load_inputs, tile_method

    from spectralize.nodes.reconstruction import DEFAULT_METHOD
    from spectralize.nodes.reconstruction.inputs import inputs_from_xarray
    from spectralize.nodes.reconstruction.tiling import sample_grid, shared_endmembers, solve_tile

    mixture = importlib.import_module("spectralize.nodes.reconstruction.estimators.endmember_mixture")
    rgb, shots, camera, _ = load_inputs(Path(path))
    endmembers = shared_endmembers(rgb.isel(sample_grid(rgb)), shots.isel(sample_grid(rgb)), camera)
    corner = {"y": slice(0, 64), "x": slice(0, 64)}  # compiles every kernel before the timing
    small = inputs_from_xarray(rgb.isel(corner), shots.isel(corner), camera)
    mixture.endmember_mixture(small, endmembers=endmembers)
    inputs = inputs_from_xarray(rgb, shots, camera)
    started = time.perf_counter()
    mixture.endmember_mixture(inputs, endmembers=endmembers)
    seconds = time.perf_counter() - started
    profile = cProfile.Profile()
    profile.enable()
    mixture.endmember_mixture(inputs, endmembers=endmembers)
    profile.disable()
    stats = pstats.Stats(profile).stats
    sections = {}
    for (filename, _, name), (_, _, _, cumulative, _) in stats.items():
        if name in MIXTURE_SECTIONS and "reconstruction" in filename:
            sections[MIXTURE_SECTIONS[name]] = round(
                sections.get(MIXTURE_SECTIONS[name], 0.0) + cumulative, 3
            )
    size = rgb.sizes["y"]
    started = time.perf_counter()
    _, iterations, _ = solve_tile(
        rgb,
        shots,
        camera,
        (slice(0, size), slice(0, rgb.sizes["x"])),
        **tile_method(solve_tile, {"method": DEFAULT_METHOD}),
        confidence=True,
        endmembers=endmembers,
    )
    tile = time.perf_counter() - started
    return {
        "mixture_s": round(seconds, 3),
        "tile_s": round(tile, 3),
        "iterations": int(iterations.max()),
        "sections_s": sections,
    }


def mixture_tile(args: argparse.Namespace, report: dict) -> None:
    """``--mixture-tile``: before and after on one 256^2 tile, each in a fresh process."""
    from paper_scale import baseline_package, capture_inputs

    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        package = baseline_package(args.baseline_commit, work)
        log(f"capturing {args.scene} at 256^2 and 128^2 (20 images)")
        capture_inputs(args.scene, 256, 0, work / "set256.npz", truth=False)
        capture_inputs(args.scene, 128, 0, work / "set128.npz", truth=True)
        rows = _before_and_after(work, package, "--tile-case", work / "set256.npz")
        subprocess.run(["git", "worktree", "remove", "--force", str(work / "baseline")], check=False)
    before, after = rows["before"], rows["after"]
    previous["mixture_tile"] = {
        "command": report["command"],
        "commit": report["commit"],
        "baseline_commit": args.baseline_commit,
        "date": report["date"],
        "note": args.note,
        "set": f"{args.scene}, 256^2 x 20 images (10 with 3 band shots each), one tile, whole",
        "before": before,
        "after": after,
        "mixture_speedup": round(before["mixture_s"] / after["mixture_s"], 2),
        "tile_speedup": round(before["tile_s"] / after["tile_s"], 2),
    }
    RESULTS.write_text(json.dumps(previous, indent=1) + "\n")
    print(json.dumps(previous["mixture_tile"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-commit")
    parser.add_argument("--mixture-tile", action="store_true", help="the 256^2 tile case")
    parser.add_argument("--profile", action="store_true", help="profile a 256 px tile")
    parser.add_argument("--profile-case", help=argparse.SUPPRESS)
    parser.add_argument("--tile-case", help=argparse.SUPPRESS)
    parser.add_argument("--package", help=argparse.SUPPRESS)
    parser.add_argument("--keep", help=argparse.SUPPRESS)
    parser.add_argument("--after-commit", help="the 'after' side from this commit (not the checkout)")
    parser.add_argument(
        "--into-mixture-tile",
        action="store_true",
        help="store the 2048^2 rows under mixture_tile/throughput_2048 (keep the rest)",
    )
    parser.add_argument("--scene", default="glossy-mosaic")
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--note", default="")
    args = parser.parse_args()
    if args.profile_case:
        print(json.dumps(profile_tile_case(args.profile_case, args.package, args.keep)))
        return
    if args.tile_case:
        print(json.dumps(mixture_tile_case(args.tile_case, args.package)))
        return
    if not args.baseline_commit:
        parser.error("--baseline-commit is required")
    from spectralize.nodes.reconstruction import DEFAULT_METHOD

    sys.path.insert(0, str(HERE))
    from paper_scale import baseline_package, capture_inputs, head_commit, run_case

    head = head_commit()
    report: dict = {
        "benchmark": "paper_scale_throughput",
        "command": " ".join(sys.argv),
        "commit": args.after_commit or head,
        "date": time.strftime("%Y-%m-%d", time.gmtime()),
        "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version()},
        "method": DEFAULT_METHOD,
        "scene": args.scene,
        "set": "20 images, 10 with 3 band shots each",
        "note": args.note,
    }
    if args.mixture_tile:
        mixture_tile(args, report)
        return
    if args.profile:
        profile_tile(args, report)
        return
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        package = baseline_package(args.baseline_commit, work)
        log(f"capturing {args.scene} at 512^2 and 128^2 (20 images)")
        capture_inputs(args.scene, 512, 0, work / "set512.npz", truth=False)
        capture_inputs(args.scene, 128, 0, work / "set128.npz", truth=True)
        folder = work / f"mirrored{args.size}"
        run_case("mirror", work / "set512.npz", args.size, folder)
        after_package = _after_package(args.after_commit, work)
        after = args.after_commit or head
        for label, where in (
            (f"before ({args.baseline_commit})", package),
            (f"after ({after})", after_package),
        ):
            # first the small solve: it also fills the code's compiled-kernel cache, so the
            # timed case compiles nothing (a fresh worktree has none)
            accuracy = run_case("accuracy", work / "set128.npz", package=where)
            log(f"{label}: 128^2 accuracy {accuracy}")
            log(f"{label}: 2 tiles of the {args.size}^2 set")
            row = run_case("throughput", folder, args.size, 256, 2, 2, package=where)
            log(f"{label}: {row['seconds_per_mpx_image']} s/Mpx-image, peak {row['peak_rss_gb']} GB")
            row["accuracy_128"] = accuracy
            report["before" if where is package else "after"] = {"commit": label, **row}
        for tree in ("baseline", "after"):
            if (work / tree).exists():  # "after" is a worktree only with --after-commit
                subprocess.run(["git", "worktree", "remove", "--force", str(work / tree)], check=False)
    before, after = report["before"], report["after"]
    report["speedup"] = round(before["seconds_per_mpx_image"] / after["seconds_per_mpx_image"], 2)
    from paper_scale import FULL_RUN_IMAGES, FULL_RUN_MPX_PER_IMAGE

    for row in (before, after):  # as paper_scale.py extrapolates it (target: <= 10 h)
        row["full_run_hours_at_100_cores"] = round(
            FULL_RUN_IMAGES
            * FULL_RUN_MPX_PER_IMAGE
            * row["seconds_per_mpx_image"]
            * row["threads"]
            / 100
            / 3600,
            1,
        )
    if args.into_mixture_tile:  # the 2048^2 rows of the mixture-tile change, beside its tile rows
        previous = json.loads(RESULTS.read_text())
        previous["mixture_tile"]["throughput_2048"] = report
        RESULTS.write_text(json.dumps(previous, indent=1) + "\n")
        print(json.dumps(report))
        return
    previous = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    for key in ("profile_256", "mixture_tile"):  # kept from their own runs (a profile, --mixture-tile)
        if key in previous:
            report[key] = previous[key]
    RESULTS.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
