"""Benchmark of paper-scale set reconstruction: tiled solves, throughput, memory, scale-out.

Run from the repository root::

    .venv/bin/python benchmarks/paper_scale.py            # about 30-40 min on 2 cores
    .venv/bin/python benchmarks/paper_scale.py --quick    # small sizes, a few minutes

Progress goes to stdout line by line; the LAST line is one JSON object, also written to
``benchmarks/results/paper_scale.json``.

What is measured (all on 20-image sets of the hard scene ``--scene``, 10 images with 3 band
shots each, the default method):

- ``sizes``: per image size (512^2, 1024^2, 2048^2) the seconds per Mpx-image and the peak
  resident set of a fresh process that reads the set's inputs tile by tile from disk
  (memory-mapped ``.npy``, as the flow reads them from the run store) and solves tiles of
  it (``--tile`` core, automatic halo) two at a time on a dask thread pool (2 cores). The
  inputs at 1024^2 and 2048^2 are the 512^2 capture mirrored to that size (a 2048^2 set
  with ground truth would need 10.7 GB for the truth cube alone). A sample of
  the interior tiles is solved (``--sample``, ``tiles_solved`` of ``tiles``): tiles are
  independent, so the whole set's time is the per-tile time times the tile count; the
  figure is per Mpx-image of the tiles' cores.
- ``untiled``: the same 256^2 set solved whole and by the flow's tile tasks
  (:func:`~spectralize.nodes.reconstruction.tiling.solve_tiled`; same process, same inputs):
  ``speedup_vs_untiled`` and ``tiled_vs_untiled_nrmse_ratio`` (median and p95 nRMSE against
  the truth), and the error near tile borders vs tile interiors (seams).
- ``today``: the 256^2 set solved whole by the code of ``--baseline-commit`` (the solver
  before this work), in a fresh process from a git worktree: ``speedup_vs_today``.
- ``dask``: the tile tasks of two 256^2 sets (128 px cores; each set its own dictionary
  task, as the sets of a run are) on a ``dask.distributed`` LocalCluster of 1 and then 2
  worker processes with 1 thread each: ``dask_speedup_2_workers``.
- ``full_run_hours_at_100_cores``: extrapolated from the 2048^2 throughput (see the README
  for the formula).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"

FULL_RUN_IMAGES = 24 * 198 * 11
"""Images of a full BTF run: 24 rotations x 198 LEDs x 11 cameras (paper section 4)."""

FULL_RUN_MPX_PER_IMAGE = 2048 * 2048 / 1e6


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def resident_gb(field: str = "VmHWM") -> float:
    """Peak (``VmHWM``) or current (``VmRSS``) resident set of this process in GB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return float(line.split()[1]) / 2**20
    return float("nan")


# -- inputs ------------------------------------------------------------------------------------
def capture_inputs(scene: str, size: int, seed: int, path: Path, *, truth: bool) -> None:
    """Capture a 20-image set of ``scene`` and save its inputs (and truth) as ``.npz``."""
    from spectralize.nodes.simulation.scenes import get_scene
    from spectralize.nodes.simulation.scenes.materials import sharp_led

    capture = get_scene(scene, size=size, seed=seed, n_images=20)
    bands = capture.bands
    arrays = {
        "rgb": capture.rgb.transpose("image", "y", "x", "channel").values.astype(np.float32),
        "bands": bands.values.astype(np.float32),
        "wavelength": bands["wavelength"].values,
        "band_image": bands["image"].values,
        "filter_size": bands["filter_size"].values,
        "camera_matrix": capture.camera_matrix.transpose("channel", "wavelength").values,
        "camera_wavelength": capture.camera_matrix["wavelength"].values,
        # the run's LED, L on the camera's wavelengths (the set model's illuminant)
        "illuminant": sharp_led(capture.camera_matrix["wavelength"].values),
    }
    if truth:
        arrays["truth"] = capture.truth.transpose("image", "wavelength", "y", "x").values
    np.savez(path, **arrays)


def mirror_inputs(path: Path, size: int, folder: Path) -> dict:
    """The saved set mirrored up to ``size`` as ``.npy`` files in ``folder`` (run in its own
    process, so the measured one never holds the whole set)."""
    data = np.load(path)
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("rgb", "bands"):
        values = data[name]
        pad = max(size - values.shape[1], 0)
        widths = [(0, 0), (0, pad), (0, pad)] + [(0, 0)] * (values.ndim - 3)
        np.save(folder / f"{name}.npy", np.pad(values, widths, mode="symmetric"))
    np.savez(folder / "meta.npz", **{k: data[k] for k in data.files if k not in ("rgb", "bands")})
    return {"folder": str(folder), "size": size}


def load_inputs(path: Path, size: int | None = None):
    """The saved set as the reconstruction API's xarray inputs, mirrored up to ``size``; from
    a folder of :func:`mirror_inputs`, memory-mapped (each tile reads its window from disk,
    as the flow reads it from the run store)."""
    import xarray as xr

    if Path(path).is_dir():
        data = np.load(Path(path) / "meta.npz")
        rgb = np.load(Path(path) / "rgb.npy", mmap_mode="r")
        bands = np.load(Path(path) / "bands.npy", mmap_mode="r")
    else:
        data = np.load(path)
        rgb, bands = data["rgb"], data["bands"]
    if size is not None and size > rgb.shape[1]:
        pad = size - rgb.shape[1]
        rgb = np.pad(rgb, ((0, 0), (0, pad), (0, pad), (0, 0)), mode="symmetric")
        bands = np.pad(bands, ((0, 0), (0, pad), (0, pad)), mode="symmetric")
    rgb_da = xr.DataArray(rgb, dims=("image", "y", "x", "channel"), coords={"channel": ["R", "G", "B"]})
    shots = xr.DataArray(
        bands,
        dims=("shot", "y", "x"),
        coords={
            "wavelength": ("shot", data["wavelength"]),
            "image": ("shot", data["band_image"]),
            "filter_size": ("shot", data["filter_size"]),
        },
    )
    camera = xr.DataArray(
        data["camera_matrix"],
        dims=("channel", "wavelength"),
        coords={"channel": ["R", "G", "B"], "wavelength": data["camera_wavelength"]},
    )
    truth = data["truth"] if "truth" in data.files else None
    return rgb_da, shots, camera, truth


def flow_settings(path: Path) -> dict:
    """The settings a run's set nodes give a tile's solve: the method and the run's
    illuminant ``L`` (wavelength,), so that the method's set model applies as in the flow
    (none in inputs saved before ``L`` was kept: the solve alone)."""
    import xarray as xr

    data = np.load(Path(path) / "meta.npz" if Path(path).is_dir() else path)
    settings: dict = {"method": _method()}
    if "illuminant" in data.files:
        wavelength = data["camera_wavelength"]
        settings["illuminant"] = xr.DataArray(
            data["illuminant"], dims="wavelength", coords={"wavelength": wavelength}
        )
    return settings


def nrmse(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-pixel RMSE over wavelengths / the image's mean truth, ``(image, y, x)``."""
    rmse = np.sqrt(np.mean((np.asarray(estimate, np.float64) - truth) ** 2, axis=1))
    return rmse / truth.mean(axis=(1, 2, 3))[:, None, None]


# -- cases, each run in a fresh process ---------------------------------------------------------
def _method() -> str:
    from spectralize.nodes.reconstruction import DEFAULT_METHOD

    return os.environ.get("SPECTRALIZE_BENCH_METHOD", DEFAULT_METHOD)


def _set_endmembers(rgb, shots, camera) -> tuple[object, float]:
    """The set's shared endmember dictionary (as the flow learns it once per set, from a
    strided sample) and the seconds it took; ``(None, 0)`` for a method without one."""
    from spectralize.nodes.reconstruction.methods import get_method
    from spectralize.nodes.reconstruction.tiling import sample_grid, shared_endmembers

    if "endmembers" not in get_method(_method()).options:
        return None, 0.0
    started = time.perf_counter()
    grid = sample_grid(rgb)
    endmembers = shared_endmembers(rgb.isel(grid), shots.isel(grid), camera)
    return endmembers, time.perf_counter() - started


@contextlib.contextmanager
def _as_a_run():
    """The threads' inner BLAS/OpenMP threads as a run on local threads sets them
    (``spectralize.flows.runtime.INNER_THREADS``; code from before it: the libraries' own),
    and its heap kept for the next tile before the threads start
    (``spectralize.nodes.reconstruction.heap.keep_freed_memory``, where the code has it)."""
    try:
        from spectralize.nodes.reconstruction.heap import keep_freed_memory
    except ImportError:  # code from before it
        pass
    else:
        keep_freed_memory()
    try:
        from spectralize.flows.runtime import INNER_THREADS
    except ImportError:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=INNER_THREADS):
        yield


def tile_method(solve_tile, settings: dict) -> dict:
    """The keywords that give ``solve_tile`` (or ``tile_tasks``) the method and the run's
    illuminant (``settings``: ``method``, ``illuminant``): as they are, or as ``settings=`` for
    code from before the tile tasks took the method itself."""
    import inspect

    return {"settings": settings} if "settings" in inspect.signature(solve_tile).parameters else settings


def _solve_window(rgb, shots, camera, window, settings, endmembers=None) -> tuple[float, int]:
    """One tile as the flow solves it (its tile task, :func:`~.tiling.solve_tile`): with the
    set's endmembers and the per-pixel confidence; ``(seconds, iterations)``."""
    from spectralize.nodes.reconstruction.tiling import solve_tile

    oy, ox = window.outer
    started = time.perf_counter()
    _, iterations, _ = solve_tile(
        rgb.isel(y=oy, x=ox),
        shots.isel(y=oy, x=ox),
        camera,
        window.inner,
        **tile_method(solve_tile, settings),
        confidence=True,
        endmembers=endmembers,
    )
    return time.perf_counter() - started, int(iterations.max())


def _warm_training() -> None:
    """Read the natural prior's training reflectances (colour-science's import and its data
    file) as a run's worker does once, before its first tile, not in every tile."""
    try:
        from spectralize.nodes.reconstruction.baselines.training import training_reflectances
    except ImportError:  # code from before the natural prior
        return
    training_reflectances(np.linspace(400.0, 700.0, 31))


def case_throughput(inputs: Path, size: int, tile: int, sample: int, threads: int) -> dict:
    """Solve ``sample`` interior tiles of the set at ``size`` two at a time; per-Mpx figures."""
    import dask

    from spectralize.nodes.reconstruction.tiling import default_halo, tile_windows

    rgb, shots, camera, _ = load_inputs(inputs, None if Path(inputs).is_dir() else size)
    halo = default_halo(shots["filter_size"].values)
    windows = tile_windows(size, size, tile, halo)
    n_side = int(np.ceil(size / tile))
    interior = [
        w for i, w in enumerate(windows) if 0 < i // n_side < n_side - 1 and 0 < i % n_side < n_side - 1
    ]
    chosen = (interior or windows)[: max(1, sample)] if sample < len(windows) else windows
    rss_inputs = resident_gb("VmRSS")
    endmembers, learn_s = _set_endmembers(rgb, shots, camera)
    _warm_training()
    settings = flow_settings(inputs)
    started = time.perf_counter()
    tasks = [dask.delayed(_solve_window)(rgb, shots, camera, w, settings, endmembers) for w in chosen]
    with _as_a_run():
        results = dask.compute(*tasks, scheduler="threads", num_workers=threads)
    # the set's dictionary is learnt once: each tile's share of it
    wall = time.perf_counter() - started + learn_s * len(chosen) / len(windows)
    core_mpx = sum(np.prod(w.core_shape) for w in chosen) * rgb.sizes["image"] / 1e6
    outer_mpx = sum(np.prod(w.outer_shape) for w in chosen) * rgb.sizes["image"] / 1e6
    return {
        "method": _method(),
        "endmembers_s": round(learn_s, 2),
        "size": size,
        "tile": tile,
        "halo": halo,
        "tiles": len(windows),
        "tiles_solved": len(chosen),
        "threads": threads,
        "wall_s": round(wall, 2),
        "iterations": [r[1] for r in results],
        "seconds_per_tile": [round(r[0], 2) for r in results],
        "seconds_per_mpx_image": round(wall / core_mpx, 2),
        "seconds_per_mpx_image_of_windows": round(wall / outer_mpx, 2),
        "set_seconds_extrapolated": round(wall / len(chosen) * len(windows), 1),
        "rss_inputs_gb": round(rss_inputs, 3),
        "peak_rss_gb": round(resident_gb(), 3),
        "load_average_1min": round(os.getloadavg()[0], 1),  # other work on the cores meanwhile
    }


def case_untiled(inputs: Path, tile: int) -> dict:
    """The 256^2 set solved whole and by the flow's tile tasks (one after the other, on the
    synchronous scheduler): time, accuracy, seams."""
    from spectralize.nodes.reconstruction.tiling import solve_set, solve_tiled, tile_windows

    rgb, shots, camera, truth = load_inputs(inputs)
    started = time.perf_counter()
    whole, whole_iterations, _ = solve_set(rgb, shots, camera, method=_method())
    whole_s = time.perf_counter() - started
    peak_whole = resident_gb()
    started = time.perf_counter()
    tiled, tiled_iterations, _ = solve_tiled(
        rgb, shots, camera, tile=tile, confidence=True, method=_method()
    )
    tiled_s = time.perf_counter() - started
    e_whole = nrmse(whole.transpose("image", "wavelength", "y", "x").values, truth)
    e_tiled = nrmse(tiled.transpose("image", "wavelength", "y", "x").values, truth)
    # seams: error within 4 px of an internal core border vs the rest
    size = rgb.sizes["y"]
    border = np.zeros((size, size), dtype=bool)
    for w in tile_windows(size, size, tile, 0):
        for axis, s in enumerate(w.core):
            for edge in (s.start, s.stop):
                if 0 < edge < size:
                    index = [slice(None), slice(None)]
                    index[axis] = slice(max(edge - 4, 0), min(edge + 4, size))
                    border[tuple(index)] = True
    stats = {}
    for name, e in (("untiled", e_whole), ("tiled", e_tiled)):
        stats[name] = {
            "median": round(float(np.median(e)), 5),
            "p95": round(float(np.percentile(e, 95)), 5),
            "fraction_under_0.03": round(float(np.mean(e < 0.03)), 4),
        }
    return {
        "size": size,
        "tile": tile,
        "halo": int(tiled.attrs.get("halo", -1)),
        "untiled_s": round(whole_s, 2),
        "tiled_s": round(tiled_s, 2),
        "untiled_iterations": whole_iterations,
        "tiled_iterations": tiled_iterations,
        "peak_rss_gb_untiled": round(peak_whole, 3),
        "accuracy": stats,
        "tiled_vs_untiled_nrmse_ratio": {
            k: round(stats["tiled"][k] / stats["untiled"][k], 4) for k in ("median", "p95")
        },
        "seam_median_border_vs_interior": round(
            float(np.median(e_tiled[:, border]) / np.median(e_tiled[:, ~border])), 4
        ),
        "untiled_median_border_vs_interior": round(
            float(np.median(e_whole[:, border]) / np.median(e_whole[:, ~border])), 4
        ),
    }


def case_accuracy(inputs: Path) -> dict:
    """The small set (with truth) solved whole by the method: nRMSE, iterations, time."""
    from spectralize.nodes.reconstruction.tiling import solve_set

    rgb, shots, camera, truth = load_inputs(inputs)
    started = time.perf_counter()
    cube, iterations, _ = solve_set(rgb, shots, camera, **flow_settings(inputs))
    seconds = time.perf_counter() - started
    e = nrmse(cube.transpose("image", "wavelength", "y", "x").values, truth)
    return {
        "size": rgb.sizes["y"],
        "seconds": round(seconds, 2),
        "iterations": int(iterations),
        "median": round(float(np.median(e)), 5),
        "p95": round(float(np.percentile(e, 95)), 5),
    }


def case_today(inputs: Path) -> dict:
    """The 256^2 set solved whole (run inside the baseline commit's worktree)."""
    from spectralize.nodes.reconstruction import reconstruct

    rgb, shots, camera, truth = load_inputs(inputs)
    started = time.perf_counter()
    result = reconstruct(rgb, shots, camera, full_output=True)
    wall = time.perf_counter() - started
    e = nrmse(result.spectra.transpose("image", "wavelength", "y", "x").values, truth)
    import spectralize.nodes.reconstruction.api as api

    return {
        "code": str(Path(api.__file__).resolve().parents[2]),
        "wall_s": round(wall, 2),
        "iterations": int(result.iterations),
        "median": round(float(np.median(e)), 5),
        "p95": round(float(np.percentile(e, 95)), 5),
        "peak_rss_gb": round(resident_gb(), 3),
    }


def _warm_worker() -> None:
    """Import the solver and load its compiled kernels (numba's disk cache) in a worker:
    once per worker of a nightly run, so not part of the throughput measured."""
    from spectralize.nodes.reconstruction import reconstruct
    from spectralize.nodes.simulation.scenes import get_scene

    small = get_scene("glossy-mosaic", size=32, n_images=2, seed=0)
    reconstruct(small.rgb, small.bands, small.camera_matrix, method=_method())


def case_dask(inputs: Path, tile: int, workers: int, sets: int = 2) -> dict:
    """The tile tasks of ``sets`` sets (:func:`~.tiling.tile_tasks`, as the flow builds them;
    the same inputs under other task names, as a run's sets are other tasks of one graph) on
    a LocalCluster of ``workers`` processes x 1 thread, each worker warmed up first (imports
    and compiled kernels loaded)."""
    import dask
    from distributed import Client, LocalCluster

    from spectralize.nodes.reconstruction.tiling import set_windows, tile_tasks

    rgb, shots, camera, _ = load_inputs(inputs)
    windows, _ = set_windows(shots, rgb.sizes["y"], rgb.sizes["x"], tile)
    method = tile_method(tile_tasks, {"method": _method()})
    graphs = [
        tile_tasks(rgb, shots, camera, windows, **method, confidence=True, name=f"set-{i}")
        for i in range(sets)
    ]
    with (
        LocalCluster(
            n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
        ) as cluster,
        Client(cluster) as client,
    ):
        client.run(_warm_worker)
        started = time.perf_counter()
        # reduced where they are solved (the flow writes them there): no cube to gather
        dask.compute(
            *[(g.spectra.sum(), g.confidence.sum(), g.iterations) for g in graphs], scheduler=client
        )
        wall = time.perf_counter() - started
    return {"workers": workers, "sets": sets, "tiles": sets * len(windows), "wall_s": round(wall, 2)}


# -- the paper-scale slice through the whole flow ---------------------------------------------
SLICE_AZIMUTHS = [120 + 15 * k for k in range(11)]
"""LED azimuths [deg] of the slice on the 40 deg ring: 11 LEDs, so that 10 have a partner one
rotation step on (the spectral camera sees one rotation later what the RGB camera saw)."""


def slice_steps(size: int, dark_frames: int) -> list:
    """The ``btf`` flow's steps after a ``simulate`` step of the paper-scale slice.

    The paper recipe at ``size`` with one RGB camera at 45 deg, the 11 LEDs of
    :data:`SLICE_AZIMUTHS` and two rotations (the least that gives the spectral camera a
    sweep): 22 images, 10 of them with the 32 band shots, in one set of 10 + 12.
    """
    import dataclasses

    from spectralize.engine import Step
    from spectralize.flows.pipelines import BTF_STEPS
    from spectralize.nodes.simulation.recipes import ring_leds

    recipe = {
        "recipe": "paper",
        "size": size,
        "n_rotations": 2,
        "overrides": {
            "rgb_camera_thetas": [45.0],
            "leds": list(ring_leds(40.0, SLICE_AZIMUTHS)),
            "n_dark_frames": dark_frames,
        },
    }
    steps = [Step("simulate", parameters=recipe)]
    for step in BTF_STEPS:
        if step.node == "select_image_sets":  # all 22 images in one set (the seed set)
            step = dataclasses.replace(step, parameters={"others_per_set": 12})
        steps.append(step)
    return steps


def case_paper_slice(size: int, dark_frames: int, folder: Path) -> dict:
    """Simulate the slice and run the whole ``btf`` flow on it (a real Prefect run)."""
    import shutil

    import spectralize.flows  # noqa: F401  (Prefect environment defaults)
    from spectralize.flows.runtime import run_steps
    from spectralize.store import RunStore

    store_path = Path(folder) / "slice.zarr"
    begin = time.perf_counter()
    report = run_steps(store_path, slice_steps(int(size), int(dark_frames)), flow_name="paper-slice")
    wall = time.perf_counter() - begin
    nodes = {step.node: round(step.seconds, 1) for step in report.steps}
    store = RunStore.open(store_path)
    spectra = store.read("spectra")
    images = int(spectra.sizes["image"])
    sets = store.read("image_sets")
    accuracy = {}
    if store.has("evaluation"):
        evaluation = store.read("evaluation")
        stats = evaluation["nrmse_subset_statistics"]
        for subset in evaluation["subset"].values.tolist():
            accuracy[subset] = {
                "median": round(float(stats.sel(subset=subset, statistic="median")), 4),
                "p95": round(float(stats.sel(subset=subset, statistic="p95")), 4),
            }
    store_gb = sum(f.stat().st_size for f in store_path.rglob("*") if f.is_file()) / 1e9
    processing = wall - nodes.get("simulate", 0.0)
    mpx_images = images * int(spectra.sizes["y"]) * int(spectra.sizes["x"]) / 1e6
    row = {
        "size": int(size),
        "images": images,
        "images_with_bands": int(sets["has_bands"].sum()),
        "sets": int(sets.sizes["set"]),
        "dark_frames_per_exposure": int(dark_frames),
        "wall_s": round(wall, 1),
        "processing_s": round(processing, 1),
        "processing_seconds_per_mpx_image": round(processing / mpx_images, 2),
        "node_seconds": nodes,
        # per node, this process's peak resident set while it ran (flows/memory.py); the
        # flow resets VmHWM per node, so the whole peak is the run report's (resets included)
        "node_peak_rss_gb": {
            step.node: step.peak_rss_gb for step in report.steps if getattr(step, "peak_rss_gb", None)
        },
        "peak_rss_gb": round(max(resident_gb(), getattr(report, "peak_rss_gb", None) or 0.0), 3),
        "store_gb": round(store_gb, 2),
        "accuracy": accuracy,
    }
    shutil.rmtree(store_path, ignore_errors=True)
    return row


def paper_slice_summary(path: Path = RESULTS / "paper_slice.json") -> dict:
    """The slice's figures from ``benchmarks/paper_slice.py`` (its own run of about 1.5 h)."""
    if not path.exists():
        return {
            "paper_slice_wall_s": None,
            "paper_slice_peak_rss_gb": None,
            "paper_slice_note": "not run: see benchmarks/paper_slice.py",
        }
    row = json.loads(path.read_text())
    return {
        "paper_slice_wall_s": row["wall_s"],
        "paper_slice_peak_rss_gb": row["peak_rss_gb"],
        "paper_slice_note": f"benchmarks/paper_slice.py at {row['size']}^2, {row['images']} images, "
        f"commit {row['commit']} on {row['date']} (results/paper_slice.json)",
    }


CASES = {
    "throughput": case_throughput,
    "untiled": case_untiled,
    "accuracy": case_accuracy,
    "today": case_today,
    "dask": case_dask,
    "mirror": mirror_inputs,
    "paper_slice": case_paper_slice,
}


def run_case(name: str, *args, package: Path | None = None, method: str | None = None) -> dict:
    """Run one case in a fresh Python process (its own peak RSS); returns its JSON.

    ``package``: a folder whose ``spectralize`` is imported instead of this checkout's;
    ``method``: the reconstruction method of the case (``SPECTRALIZE_BENCH_METHOD``;
    default: the default method).
    """
    argv = [str(a) if isinstance(a, Path) else a for a in args]
    command = [sys.executable, str(Path(__file__).resolve())]
    if package is not None:
        command += ["--package", str(package)]
    env = dict(os.environ)
    if method:
        env["SPECTRALIZE_BENCH_METHOD"] = method
    out = subprocess.run(
        [*command, "--case", name, json.dumps(argv)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
        env=env,
    )
    if out.returncode != 0:
        raise RuntimeError(f"case {name}{tuple(argv)} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def head_commit() -> str:
    """This checkout's commit, short (empty outside git)."""
    done = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=False
    )
    return done.stdout.strip()


def baseline_package(commit: str, workdir: Path) -> Path:
    """A git worktree of ``commit``, importable as ``spectralize`` from the returned folder."""
    tree = workdir / "baseline"
    subprocess.run(
        ["git", "worktree", "add", "--detach", "-f", str(tree), commit],
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    shim = workdir / "shim"
    shim.mkdir()
    (shim / "spectralize").symlink_to(tree)
    return shim


def use_package(folder: str) -> None:
    """Import ``spectralize`` from ``folder``: drop this checkout's editable-install hooks."""
    sys.meta_path[:] = [f for f in sys.meta_path if "editable" not in repr(f).lower()]
    sys.path_hooks[:] = [h for h in sys.path_hooks if "editable" not in repr(h).lower()]
    sys.path[:] = [folder] + [p for p in sys.path if "__editable__" not in p]
    sys.path_importer_cache.clear()


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    parser.add_argument("--scene", default="glossy-mosaic")
    parser.add_argument("--tile", type=int, default=256, help="tile core [px]")
    parser.add_argument("--sample", type=int, default=2, help="tiles solved above 512^2")
    parser.add_argument("--baseline-commit", default="fa301f1", help="the solver before this work")
    parser.add_argument("--output", type=Path, default=RESULTS / "paper_scale.json")
    args = parser.parse_args(argv)
    begun = time.perf_counter()
    base = 128 if args.quick else 512
    small = 96 if args.quick else 256
    tile = 64 if args.quick else args.tile
    sizes = (base, 2 * base) if args.quick else (base, 2 * base, 4 * base)
    report: dict = {
        "benchmark": "paper_scale",
        "command": " ".join(sys.argv),
        "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version()},
        "scene": args.scene,
        "set": "20 images, 10 with 3 band shots each",
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        big, little = work / f"set{base}.npz", work / f"set{small}.npz"
        log(f"capturing {args.scene} at {base}^2 and {small}^2 (20 images)")
        capture_inputs(args.scene, base, 0, big, truth=False)
        capture_inputs(args.scene, small, 0, little, truth=True)

        report["sizes"] = {}
        for size in sizes:
            sample = args.sample
            folder = work / f"mirrored{size}"
            run_case("mirror", big, size, folder)
            row = run_case("throughput", folder, size, tile, sample, 2)
            row["inputs"] = "memory-mapped .npy, read per tile"
            report["sizes"][str(size)] = row
            log(
                f"{size}^2: {row['seconds_per_mpx_image']} s/Mpx-image, peak {row['peak_rss_gb']} GB "
                f"({row['tiles_solved']}/{row['tiles']} tiles, iterations {row['iterations']})"
            )
        row = run_case("untiled", little, tile // 2 if not args.quick else 48)
        report["untiled"] = row
        log(f"{small}^2 untiled {row['untiled_s']} s vs tiled {row['tiled_s']} s; {row['accuracy']}")
        try:
            package = baseline_package(args.baseline_commit, work)
            report["today"] = run_case("today", little, package=package)
            log(f"{small}^2 with {args.baseline_commit}: {report['today']}")
        except (subprocess.CalledProcessError, RuntimeError) as error:
            report["today"] = {"error": str(error)[-2000:]}
            log(f"baseline failed: {error}")
        finally:
            subprocess.run(
                ["git", "worktree", "remove", "--force", str(work / "baseline")],
                cwd=ROOT,
                capture_output=True,
                check=False,
            )
        dask_rows = [run_case("dask", little, tile // 2, n) for n in (1, 2)]
        report["dask"] = dask_rows
        log(f"dask: {dask_rows}")

    per_size = report["sizes"]
    largest = per_size[str(sizes[-1])]
    cores = report["machine"]["cpu_count"] or 2
    untiled = report["untiled"]
    summary = {
        "seconds_per_mpx_image": {k: v["seconds_per_mpx_image"] for k, v in per_size.items()},
        "peak_rss_gb": {k: v["peak_rss_gb"] for k, v in per_size.items()},
        "speedup_vs_untiled": round(untiled["untiled_s"] / untiled["tiled_s"], 3),
        "tiled_vs_untiled_nrmse_ratio": untiled["tiled_vs_untiled_nrmse_ratio"],
        "seam_median_border_vs_interior": untiled["seam_median_border_vs_interior"],
        "dask_speedup_2_workers": round(dask_rows[0]["wall_s"] / dask_rows[1]["wall_s"], 3),
        **paper_slice_summary(),
        # hours = images x Mpx/image x (s per Mpx-image on `cores` cores) x cores / N / 3600
        "full_run_hours_at_100_cores": round(
            FULL_RUN_IMAGES
            * FULL_RUN_MPX_PER_IMAGE
            * largest["seconds_per_mpx_image"]
            * cores
            / 100
            / 3600,
            1,
        ),
        "cores_measured": cores,
    }
    if "wall_s" in report.get("today", {}):
        small_mpx = 20 * small * small / 1e6
        summary["today_seconds_per_mpx_image"] = round(report["today"]["wall_s"] / small_mpx, 2)
        summary["untiled_seconds_per_mpx_image"] = round(untiled["untiled_s"] / small_mpx, 2)
        summary["tiled_seconds_per_mpx_image_small"] = round(untiled["tiled_s"] / small_mpx, 2)
        summary["speedup_vs_today"] = round(report["today"]["wall_s"] / untiled["tiled_s"], 3)
    summary["targets"] = {
        "seconds_per_mpx_image_le_10": {k: v <= 10 for k, v in summary["seconds_per_mpx_image"].items()},
        "peak_rss_2048_le_6gb": per_size.get(str(4 * base), {}).get("peak_rss_gb", 99) <= 6,
        "tiled_within_1pct": all(
            abs(v - 1) <= 0.01 for v in untiled["tiled_vs_untiled_nrmse_ratio"].values()
        ),
        "dask_speedup_ge_1.8": summary["dask_speedup_2_workers"] >= 1.8,
        "speedup_vs_today_ge_10": summary.get("speedup_vs_today", 0) >= 10,
    }
    report["summary"] = summary
    report["total_seconds"] = round(time.perf_counter() - begun, 1)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report))
    return report


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--package":
        use_package(sys.argv[2])
        del sys.argv[1:3]
    if len(sys.argv) == 4 and sys.argv[1] == "--case":
        case_args = [
            Path(a) if isinstance(a, str) and (a.endswith(".npz") or os.sep in a) else a
            for a in json.loads(sys.argv[3])
        ]
        print(json.dumps(CASES[sys.argv[2]](*case_args)))
    else:
        main()
