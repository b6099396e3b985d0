"""A paper-scale slice through the whole ``btf`` flow: wall time and peak memory at 2048^2.

Run from the repository root::

    .venv/bin/python benchmarks/paper_slice.py                # 2048^2: about 1.5 h on 2 cores
    .venv/bin/python benchmarks/paper_slice.py --size 256     # the same slice small (2 min)

The slice is the paper recipe at ``--size`` with one RGB camera at 45 deg, 11 LEDs of the
40 deg ring and two rotations: 22 images, 10 of them with the 32 band shots of one filter
sweep (the spectral camera sees one rotation later what the RGB camera saw, so one sweep
needs two rotations), solved as one set of 10 + 12, with the calibration shots and
``--dark-frames`` dark frames per exposure time (45 exposure times). Every node of the
``btf`` flow runs (a real Prefect run on a zarr store on disk, dask threads), from the
simulation to the evaluation, in a fresh process whose peak resident set is measured.

``node_peak_rss_gb``: per node, the peak resident set of the process while it ran (GB of
1e9 bytes; the flow resets the process's high-water mark before each node, see
``flows/memory.py``; dask threads count, workers in other processes would not).

The LAST line is one JSON object, also written to ``benchmarks/results/paper_slice.json``;
``paper_scale.py`` reports its ``paper_slice_wall_s`` and ``paper_slice_peak_rss_gb`` from
there. ``full_run_hours_at_100_cores`` extrapolates the whole flow's processing time (every
node but the simulation) per Mpx-image to the full run::

    hours = 52,272 images x 4.19 Mpx x (processing s per Mpx-image) x cores / 100 / 3600
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "paper_slice.json"
MEMORY_LIMIT_GB = 24.0
"""The slice must run within the machine's 24 GB (issue: paper-scale runs, item 5)."""


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=2048, help="image height = width [px]")
    parser.add_argument(
        "--dark-frames",
        type=int,
        default=16,
        help="dark frames per exposure time (the paper: 200; 16 keeps the raw darks of a "
        "2048^2 slice at 6 GB instead of 75 GB)",
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(HERE))
    import paper_scale

    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=HERE, capture_output=True, text=True, check=False
    ).stdout.strip()
    log(f"slice at {args.size}^2, {args.dark_frames} dark frames per exposure time")
    with tempfile.TemporaryDirectory(prefix="paper-slice-") as folder:
        row = paper_scale.run_case("paper_slice", args.size, args.dark_frames, Path(folder))
    cores = os.cpu_count() or 2
    per_mpx = row["processing_seconds_per_mpx_image"]
    row.update(
        benchmark="paper_slice",
        commit=commit,
        date=time.strftime("%Y-%m-%d"),
        cores_measured=cores,
        under_24_gb=row["peak_rss_gb"] <= MEMORY_LIMIT_GB,
        full_run_hours_at_100_cores=round(
            paper_scale.FULL_RUN_IMAGES
            * paper_scale.FULL_RUN_MPX_PER_IMAGE
            * per_mpx
            * cores
            / 100
            / 3600,
            1,
        ),
    )
    log(
        f"{row['wall_s']} s wall ({row['processing_s']} s after the simulation), peak "
        f"{row['peak_rss_gb']} GB, nodes {row['node_seconds']}"
    )
    log(f"peak resident set per node [GB]: {row.get('node_peak_rss_gb')}")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(row, indent=1) + "\n")
    print(json.dumps(row))
    return row


if __name__ == "__main__":
    main()
