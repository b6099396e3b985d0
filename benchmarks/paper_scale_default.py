"""The 2048^2 throughput and memory of one reconstruction method, in fresh processes.

Run from the repository root::

    .venv/bin/python benchmarks/paper_scale_default.py [--method NAME] [--size 2048]

The ``sizes`` row of ``benchmarks/paper_scale.py`` for one method (default: the default
method) without the rest of that benchmark (about 10 minutes instead of 30-40): the 512^2
capture of ``--scene`` mirrored up to ``--size``, two interior 256 px tiles solved two at a
time on 2 threads, inputs memory-mapped and read per tile. The method is set through
``SPECTRALIZE_BENCH_METHOD`` in the measured process. The LAST line is one JSON object,
merged by method into ``benchmarks/results/paper_scale_2048_rerun.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "paper_scale_2048_rerun.json"


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def main() -> None:
    from spectralize.nodes.reconstruction import DEFAULT_METHOD

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--method", default=DEFAULT_METHOD)
    parser.add_argument("--scene", default="glossy-mosaic")
    parser.add_argument("--size", type=int, default=2048)
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from paper_scale import capture_inputs, run_case

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        log(f"capturing {args.scene} at 512^2 (20 images)")
        capture_inputs(args.scene, 512, 0, work / "set512.npz", truth=False)
        folder = work / f"mirrored{args.size}"
        run_case("mirror", work / "set512.npz", args.size, folder)
        log(f"solving 2 tiles of the {args.size}^2 set with {args.method}")
        row = run_case("throughput", folder, args.size, 256, 2, 2, method=args.method)
    row["method"] = args.method
    log(
        f"{row['seconds_per_mpx_image']} s/Mpx-image, peak {row['peak_rss_gb']} GB, "
        f"iterations {row['iterations']}"
    )
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    results[args.method] = {k: v for k, v in row.items() if k != "method"}
    RESULTS.write_text(json.dumps(results) + "\n")
    print(json.dumps(row))


if __name__ == "__main__":
    main()
