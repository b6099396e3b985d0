"""Benchmark: how fast the command line answers.

Each command runs in a fresh interpreter (as a user types it), ``--repeat`` times, with a
private listing cache; the figure is the median wall time in seconds. ``nodes --refresh``
loads every node (what ``nodes`` costs when its cache is stale: after an edit of a node's
source, an upgrade or a new plugin); ``nodes`` reads the cached listing; ``error_flow`` and
``error_set`` are a mistyped flow and ``--set``, refused before Prefect and the engine load.
Target: ``--help``, ``--version``, ``nodes`` and the errors under 1 s. Side by side:
``python -c pass`` (the interpreter's own start).

Run ``python benchmarks/cli.py [--repeat N]``; the last line printed is one JSON object,
also written to ``benchmarks/results/cli.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

COMMANDS = {
    "python_start": [sys.executable, "-c", "pass"],
    "help": [sys.executable, "-m", "spectralize.flows.cli", "--help"],
    "version": [sys.executable, "-m", "spectralize.flows.cli", "--version"],
    "nodes_uncached": [sys.executable, "-m", "spectralize.flows.cli", "nodes", "--refresh"],
    "nodes": [sys.executable, "-m", "spectralize.flows.cli", "nodes"],
    # refused before Prefect and the engine load (exit 2): a flow name, a --set and a store
    "error_flow": [sys.executable, "-m", "spectralize.flows.cli", "run", "btff", "missing.zarr"],
    "error_set": [
        sys.executable,
        "-m",
        "spectralize.flows.cli",
        "run",
        "btf",
        "missing.zarr",
        "--set",
        "reconstruct_image_sets.tolerence=1e-3",
    ],
}
#: Commands that answer with an error (exit 2) by design.
ERRORS = ("error_flow", "error_set")
TARGET_S = 1.0


def wall_time(command: list[str], env: dict[str, str], *, code: int = 0) -> float:
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, env=env)
    seconds = time.perf_counter() - start
    if done.returncode != code:
        raise RuntimeError(f"{command}: exit {done.returncode}: {done.stderr.decode()[-500:]}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, SPECTRALIZE_CACHE_DIR=cache)
        wall_time(COMMANDS["nodes"], env)  # fills the cache
        times = {name: [] for name in COMMANDS}
        for _ in range(args.repeat):  # interleaved: the machine's load hits all alike
            for name, command in COMMANDS.items():
                times[name].append(wall_time(command, env, code=2 if name in ERRORS else 0))
    result = {f"{name}_s": round(statistics.median(t), 3) for name, t in times.items()}
    result["repeat"] = args.repeat
    result["target_s"] = TARGET_S
    result["met"] = all(result[f"{name}_s"] < TARGET_S for name in ("help", "version", "nodes", *ERRORS))
    for name in COMMANDS:
        print(f"{name:16s} median {result[f'{name}_s']:.3f} s")
    out = Path(__file__).parent / "results" / "cli.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
