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
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "paper_scale_throughput.json"


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def main() -> None:
    from spectralize.nodes.reconstruction import DEFAULT_METHOD

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline-commit", required=True)
    parser.add_argument("--scene", default="glossy-mosaic")
    parser.add_argument("--size", type=int, default=2048)
    parser.add_argument("--note", default="")
    args = parser.parse_args()
    sys.path.insert(0, str(HERE))
    from paper_scale import baseline_package, capture_inputs, run_case

    head = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    report: dict = {
        "benchmark": "paper_scale_throughput",
        "command": " ".join(sys.argv),
        "commit": head,
        "date": time.strftime("%Y-%m-%d", time.gmtime()),
        "machine": {"cpu_count": os.cpu_count(), "python": platform.python_version()},
        "method": DEFAULT_METHOD,
        "scene": args.scene,
        "set": "20 images, 10 with 3 band shots each",
        "note": args.note,
    }
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        package = baseline_package(args.baseline_commit, work)
        log(f"capturing {args.scene} at 512^2 and 128^2 (20 images)")
        capture_inputs(args.scene, 512, 0, work / "set512.npz", truth=False)
        capture_inputs(args.scene, 128, 0, work / "set128.npz", truth=True)
        folder = work / f"mirrored{args.size}"
        run_case("mirror", work / "set512.npz", args.size, folder)
        for label, where in ((f"before ({args.baseline_commit})", package), (f"after ({head})", None)):
            # first the small solve: it also fills the code's compiled-kernel cache, so the
            # timed case compiles nothing (a fresh worktree has none)
            accuracy = run_case("accuracy", work / "set128.npz", package=where)
            log(f"{label}: 128^2 accuracy {accuracy}")
            log(f"{label}: 2 tiles of the {args.size}^2 set")
            row = run_case("throughput", folder, args.size, 256, 2, 2, package=where)
            log(f"{label}: {row['seconds_per_mpx_image']} s/Mpx-image, peak {row['peak_rss_gb']} GB")
            row["accuracy_128"] = accuracy
            report["before" if where is not None else "after"] = {"commit": label, **row}
        subprocess.run(["git", "worktree", "remove", "--force", str(work / "baseline")], check=False)
    before, after = report["before"], report["after"]
    report["speedup"] = round(before["seconds_per_mpx_image"] / after["seconds_per_mpx_image"], 2)
    RESULTS.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
