"""Benchmark of the full-BTF flow on a small simulated run, end to end.

Run from the repository root::

    .venv/bin/python benchmarks/btf_flow.py            # 3 elevations x 12 LEDs x 3 rotations, 64 px
    .venv/bin/python benchmarks/btf_flow.py --quick    # the 'tiny' recipe

Progress goes to stdout; the LAST line is one JSON object (also written to
``benchmarks/results/btf_flow.json``):

- wall time of every node and per image, for the whole ``btf`` flow (a real Prefect run);
- iterations per set with the warm start (as run) and from a cold start (solved again here);
- throughput of the reconstruction of all sets with 1 and with 2 dask workers
  (``dask.distributed.LocalCluster``, one thread each), side by side in this run;
- peak memory (``ru_maxrss`` of this process: an upper bound);
- accuracy against the ground truth for images with and without band shots (paper Fig. 7).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def log(message: str) -> None:
    print(f"[btf-bench {time.strftime('%H:%M:%S')}] {message}", flush=True)


def recipe_parameters(quick: bool) -> dict:
    if quick:
        return {"recipe": "tiny"}
    return {
        "recipe": "demo",
        "size": 64,
        "n_rotations": 3,
        "overrides": {"rgb_camera_thetas": [15.0, 45.0, 75.0]},
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--store", type=Path, default=None, help="keep the run store here")
    parser.add_argument("--output", type=Path, default=HERE / "results" / "btf_flow.json")
    args = parser.parse_args(argv)

    import spectralize.flows  # noqa: F401  (Prefect environment defaults)
    from spectralize.engine import Step
    from spectralize.flows.pipelines import BTF_STEPS
    from spectralize.flows.runtime import run_steps
    from spectralize.nodes.reconstruction.image_sets import set_members
    from spectralize.nodes.reconstruction.set_reconstruction import (
        _camera_matrix,
        _set_inputs,
        _wavelengths,
        reconstruct_image_sets,
    )
    from spectralize.nodes.reconstruction.tiling import solve_set
    from spectralize.store import RunStore

    root = Path(tempfile.mkdtemp(prefix="btf-bench-")) if args.store is None else args.store
    store_path = root / "run.zarr" if args.store is None else args.store
    steps = [Step("simulate", parameters=recipe_parameters(args.quick)), *BTF_STEPS]
    log(f"running {len(steps)} nodes on {store_path}")
    start = time.perf_counter()
    report = run_steps(store_path, steps, flow_name="btf-benchmark")
    flow_seconds = time.perf_counter() - start
    store = RunStore.open(store_path)
    spectra = store.read("spectra")
    n_images = int(spectra.sizes["image"])
    nodes = {s.node: round(s.seconds, 2) for s in report.steps}
    processing = sum(t for n, t in nodes.items() if n != "simulate")
    log(f"flow done in {flow_seconds:.1f} s for {n_images} images")

    # iterations: warm (as run) vs cold (solved again from scratch) for every non-seed set
    hdr, bands = store.read("hdr"), store.read("bands")
    sets = store.read("image_sets").load()
    calibration = store.read("calibration/spectral")
    camera_matrix = _camera_matrix(calibration, _wavelengths(bands))
    seed = int(sets.attrs["seed_set"])
    per_image = spectra[["iterations", "image_set"]].load()
    warm_iterations = per_image["iterations"].groupby(per_image["image_set"]).first().to_series()
    cold, warm = {}, {}
    for index in range(sets.sizes["set"]):
        if index == seed:
            continue
        members, _ = set_members(sets, index)
        rgb, shots = _set_inputs(hdr, bands, members)
        _, iterations, seconds = solve_set(
            rgb, shots, camera_matrix, **_settings(store.provenance("spectra"))
        )
        cold[index] = iterations
        warm[index] = int(warm_iterations[index])
        log(f"set {index}: {warm[index]} iterations warm-started, {iterations} cold")

    # throughput with 1 vs 2 dask workers, same graph
    from distributed import Client, LocalCluster

    seed_group = store.read("spectra_seed")
    throughput = {}
    for workers in (1, 2):
        with (
            LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0"
            ) as cluster,
            Client(cluster),
        ):
            lazy = reconstruct_image_sets(
                hdr,
                bands,
                calibration,
                sets,
                seed_group,
                **_settings(store.provenance("spectra"), full=True),
            )
            begin = time.perf_counter()
            lazy["radiance"].data.sum().compute()
            seconds = time.perf_counter() - begin
        throughput[f"{workers}_workers"] = {
            "seconds": round(seconds, 2),
            "images_per_second": round(n_images / seconds, 3),
        }
        log(f"{workers} worker(s): {seconds:.1f} s")

    evaluation = store.read("evaluation") if store.has("evaluation") else None
    accuracy = {}
    if evaluation is not None:
        stats = evaluation["nrmse_subset_statistics"]
        below = evaluation["nrmse_subset_fraction_below"]
        for subset in evaluation["subset"].values.tolist():
            accuracy[subset] = {
                "median_nrmse": round(float(stats.sel(subset=subset, statistic="median")), 4),
                "p95_nrmse": round(float(stats.sel(subset=subset, statistic="p95")), 4),
                "fraction_under_0.03": round(float(below.sel(subset=subset)), 4),
            }
    result = {
        "benchmark": "btf_flow",
        "recipe": recipe_parameters(args.quick),
        "images": n_images,
        "image_size": [int(spectra.sizes["y"]), int(spectra.sizes["x"])],
        "sets": int(sets.sizes["set"]),
        "flow_seconds": round(flow_seconds, 1),
        "node_seconds": nodes,
        "processing_seconds_per_image": round(processing / n_images, 3),
        "iterations": {
            "warm_start": warm,
            "cold_start": cold,
            "mean_saved_fraction": round(
                1 - np.mean(list(warm.values())) / max(np.mean(list(cold.values())), 1), 3
            )
            if cold
            else None,
        },
        "throughput": throughput,
        "speedup_2_vs_1_workers": round(
            throughput["1_workers"]["seconds"] / throughput["2_workers"]["seconds"], 2
        ),
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
        "accuracy": accuracy,
        "cpu_count": os.cpu_count(),
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=1))
    print(json.dumps(result))
    return result


def _settings(provenance: dict, full: bool = False) -> dict:
    """The solver settings a run used, from its ``spectra`` provenance (RunStore.provenance)."""
    parameters = dict(provenance.get("parameters", {}))
    keys = ("method", "gamma_hat", "tolerance", "max_iterations", "k")
    if full:
        keys += ("warm_start_pixels", "tile")
    return {k: parameters[k] for k in keys if k in parameters}


if __name__ == "__main__":
    sys.exit(0 if main() else 1)
