"""Peak resident memory of the calibration nodes per frame size, and its extrapolation to 2048^2.

Run from the repository root::

    .venv/bin/python benchmarks/node_memory.py                       # 256, 512, 1024 px
    .venv/bin/python benchmarks/node_memory.py --sizes 256 --quick   # a smoke run

Issue 27 (item 4) asks that no node of a paper-scale run needs more than 8 GB at 2048^2.
Per ``--sizes`` frame size the paper-scale slice (``benchmarks/paper_slice.py``'s recipe:
one RGB camera, 11 LEDs, two rotations, 32 bands, ``--dark-frames`` dark frames per exposure
time) is simulated once with the nodes the calibration nodes read (``dark_average``,
``recover_rgb_oecf``, ``estimate_registration``); then each of :data:`NODES` runs, in order,
in a fresh process as the flow runs it (``spectralize.flows.runtime.run_node``: reading its
input groups from the run store, computing, writing its output groups), once with the code
of ``--baseline-commit`` (a git worktree) and once with this checkout's, on the same store.

``peak_gb``: per node the process's peak resident set while the node ran (GB of 1e9 bytes;
the flow's own measurement, ``flows/memory.py``: VmHWM reset before the node), the fresh
process's imports included.

``extrapolated_2048_gb``: per node and code, the least-squares line of peak against pixel
count through the measured sizes, ``peak = a + b * pixels``, evaluated at 2048^2 (the large
arrays of these nodes grow with the pixel count; the line's intercept holds the imports and
the per-run constants). ``--direct`` measures :data:`DIRECT_NODES` of the current code at
2048^2 too, on the largest size's store mirrored to 2048^2 (every pixel repeated; a simulated
2048^2 slice takes 40 min and its raw groups 15 GB here). ``--direct-baseline COMMIT`` measures
``--direct-baseline-nodes`` there with that commit's code as well, first (``direct_2048_before``).

The LAST line of output is one JSON object, also written to
``benchmarks/results/node_memory.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results" / "node_memory.json"
NODES = ("recover_spectral_oecf", "calibrate_spectral", "calibrate_bands")
"""The calibration nodes measured, in the flow's order (each reads the one before)."""
PREREQUISITES = ("dark_average", "recover_rgb_oecf", "estimate_registration")
TARGET_GB = 8.0
PAPER_SIZE = 2048


def log(message: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {message}", flush=True)


def case_prepare(size: int, dark_frames: int, store: str) -> dict:
    """Simulate the slice at ``size`` and run the nodes the calibration nodes read."""
    sys.path.insert(0, str(HERE))
    import paper_scale

    import spectralize.flows  # noqa: F401  (Prefect environment defaults)
    from spectralize.flows.runtime import run_steps

    steps = [
        s for s in paper_scale.slice_steps(size, dark_frames) if s.node in ("simulate", *PREREQUISITES)
    ]
    begin = time.perf_counter()
    report = run_steps(store, steps, flow_name="node-memory")
    return {
        "seconds": round(time.perf_counter() - begin, 1),
        "node_peak_rss_gb": {s.node: s.peak_rss_gb for s in report.steps},
    }


def case_node(store: str, node: str) -> dict:
    """Run ``node`` on the store as the flow runs it, forced; its seconds and peak [GB]."""
    import spectralize.flows  # noqa: F401
    from spectralize.engine import Step
    from spectralize.flows.runtime import plan, run_node
    from spectralize.store import RunStore

    (item,) = plan(store, [Step(node)])
    run_store = RunStore.open(store)
    fingerprints = {group: run_store.fingerprint(group) for group in item.inputs.values()}
    report = run_node.fn(
        str(store),
        node,
        item.parameters.model_dump(mode="json"),
        item.inputs,
        item.outputs,
        fingerprints,
        None,
        "node_memory benchmark",
    )
    return {"seconds": round(report.seconds, 1), "peak_gb": report.peak_rss_gb}


MIRRORED = (
    "raw/white_reference",
    "raw/colour_checker",
    "raw/spectral",
    "dark",
    "calibration/oecf_rgb",
    "calibration/oecf_spectral",
    "calibration/spectral",
    "registration",
)
"""The groups :data:`DIRECT_NODES` read besides each other's outputs (the responses do not
depend on the frame size)."""


def case_mirror(source: str, target: str, factor: int) -> dict:
    """The groups of :data:`MIRRORED` at ``factor`` times the frame size: every pixel of
    ``source``'s frames repeated ``factor`` x ``factor`` times (lazy, written chunk by chunk).
    The same series, bands, exposure times and chunks of frames, only larger: what the nodes
    hold per frame grows as at a simulated size (the noise is not new, which memory ignores).
    The chunks on disk are those this checkout's store writes (``shard_layout``), whatever
    ``source`` has: a store of an older layout (one chunk of a target's 32 x 13 frames,
    3.5 GB at 2048^2, decoded whole by every band's read) gave ``calibrate_spectral`` 8.02 GB
    where the current layout gives 1.46 GB."""
    import numpy as np

    from spectralize.store import SCHEMA_ATTR, RunStore

    begin = time.perf_counter()
    small = RunStore.open(source)
    large = RunStore.create(target, attrs=small.attrs)
    for group in MIRRORED:
        ds = small.read(group, friendly=False)
        grow = {d: np.arange(ds.sizes[d] * factor) // factor for d in ("y", "x") if d in ds.dims}
        grown = ds.isel(grow) if grow else ds
        grown = grown.drop_vars([d for d in grow if d in grown.coords])
        for name, variable in ds.data_vars.items():
            if variable.chunks is None or not {"y", "x"} <= set(variable.dims):
                continue
            # the layout a simulated store of that size has: tiles stay tiles, whole frames whole
            chunk = dict(zip(variable.dims, variable.data.chunksize, strict=True))
            tiles = {d: -1 if chunk[d] == variable.sizes[d] else chunk[d] for d in ("y", "x")}
            grown[name] = grown[name].chunk(tiles)
        attrs = small.group_attrs(group)
        large.write(
            group,
            grown,
            schema=attrs.get(SCHEMA_ATTR),
            fingerprint=small.fingerprint(group),
        )
    return {"seconds": round(time.perf_counter() - begin, 1)}


CASES = {"prepare": case_prepare, "node": case_node, "mirror": case_mirror}


def run_case(name: str, *args, package: Path | None = None) -> dict:
    """One case in a fresh process (its own peak), with ``package``'s ``spectralize``."""
    command = [sys.executable, str(Path(__file__).resolve())]
    if package is not None:
        command += ["--package", str(package)]
    out = subprocess.run(
        [*command, "--case", name, json.dumps([str(a) if isinstance(a, Path) else a for a in args])],
        cwd=ROOT,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        raise RuntimeError(f"case {name}{args} failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def extrapolate(peaks: dict[str, float], size: int = PAPER_SIZE) -> float | None:
    """Least-squares line of peak [GB] against pixel count, at ``size``^2."""
    import numpy as np

    known = [(int(s) ** 2, v) for s, v in peaks.items() if v is not None]
    if len(known) < 2:
        return None
    pixels, values = np.asarray(known, dtype=float).T
    slope, intercept = np.polyfit(pixels, values, 1)
    return round(float(intercept + slope * size**2), 2)


DIRECT_NODES = NODES
"""The nodes measured directly at 2048^2 (on a mirrored store), in the flow's order: all three
(``recover_spectral_oecf`` was extrapolated only while its full-range fit held every band's
bins at once, about 9.3 GB)."""


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024])
    parser.add_argument("--dark-frames", type=int, default=16, help="as benchmarks/paper_slice.py")
    parser.add_argument(
        "--baseline-commit", default="cd7de66", help="the nodes before streaming (git commit)"
    )
    parser.add_argument("--no-baseline", action="store_true", help="measure this checkout only")
    parser.add_argument(
        "--before-from",
        type=Path,
        default=None,
        help="take the baseline's figures from this earlier results file (same sizes and stores)",
    )
    parser.add_argument(
        "--direct",
        action="store_true",
        help=f"also measure {', '.join(DIRECT_NODES)} at {PAPER_SIZE}^2 on the largest size's "
        "store mirrored to it (case_mirror)",
    )
    parser.add_argument(
        "--reuse",
        type=Path,
        default=None,
        help="take every figure at --sizes from this earlier results file; measure --direct only",
    )
    parser.add_argument(
        "--direct-nodes",
        nargs="+",
        default=list(DIRECT_NODES),
        choices=DIRECT_NODES,
        help="with --direct: measure only these at 2048^2 (with --reuse the others keep their figures)",
    )
    parser.add_argument(
        "--direct-baseline",
        default=None,
        help="with --direct: also measure --direct-baseline-nodes at 2048^2 with this git commit's "
        "code (before the current code's)",
    )
    parser.add_argument(
        "--direct-baseline-nodes", nargs="+", default=list(DIRECT_NODES), choices=DIRECT_NODES
    )
    parser.add_argument("--quick", action="store_true", help="do not write the results file")
    parser.add_argument(
        "--stores",
        type=Path,
        default=None,
        help="keep the simulated and mirrored stores here (and reuse them; delete them after a "
        "change of the store layout, store/layout.py: the nodes' peaks depend on the chunks)",
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    sys.path.insert(0, str(HERE))
    import paper_scale

    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=False
    ).stdout.strip()
    dirty = bool(
        subprocess.run(
            ["git", "status", "--porcelain", "--", "nodes/calibration"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            check=False,
        ).stdout.strip()
    )
    earlier = json.loads(args.before_from.read_text()) if args.before_from else None
    measure_before = not args.no_baseline and earlier is None
    codes = ("after",) if args.no_baseline else ("before", "after")
    peaks: dict[str, dict[str, dict[str, float]]] = {c: {n: {} for n in NODES} for c in codes}
    seconds: dict[str, dict[str, dict[str, float]]] = {c: {n: {} for n in NODES} for c in codes}
    if earlier is not None:
        peaks["before"], seconds["before"] = earlier["peak_gb"]["before"], earlier["seconds"]["before"]
    direct_before: dict[str, dict[str, float]] = {"peak_gb": {}, "seconds": {}}
    reused = json.loads(args.reuse.read_text()) if args.reuse else None
    if reused is not None:  # the same run's figures, written node by node
        peaks, seconds = reused["peak_gb"], reused["seconds"]
        earlier = {"date": reused["date"]} if reused.get("before_measured") != "in this run" else None
        measure_before = False
    with tempfile.TemporaryDirectory(prefix="node-memory-") as tmp:
        work = Path(tmp)
        package = paper_scale.baseline_package(args.baseline_commit, work) if measure_before else None
        direct_package = None
        if args.direct and args.direct_baseline:
            (work / "direct").mkdir()
            direct_package = paper_scale.baseline_package(args.direct_baseline, work / "direct")
        try:
            for size in args.sizes:
                store = (args.stores or work) / f"slice{size}-{args.dark_frames}.zarr"
                if args.stores is None or not store.exists():
                    log(f"{size}^2: simulating the slice and its prerequisites")
                    prepared = run_case("prepare", size, args.dark_frames, store)
                    log(f"{size}^2: prepared in {prepared['seconds']} s")
                for code in () if reused else codes if measure_before else ("after",):
                    for node in NODES:
                        row = run_case(
                            "node", store, node, package=package if code == "before" else None
                        )
                        peaks[code][node][str(size)] = row["peak_gb"]
                        seconds[code][node][str(size)] = row["seconds"]
                        log(f"{size}^2 {code} {node}: peak {row['peak_gb']} GB, {row['seconds']} s")
                        report(args, commit, dirty, earlier, codes, peaks, seconds)
                if args.direct and size == max(args.sizes):
                    large = (args.stores or work) / f"mirrored{PAPER_SIZE}-from{size}.zarr"
                    factor = PAPER_SIZE // size
                    if args.stores is None or not large.exists():
                        log(f"{PAPER_SIZE}^2: mirroring the {size}^2 store {factor} x {factor}")
                        run_case("mirror", store, large, factor)
                    for node in args.direct_baseline_nodes if direct_package else ():
                        row = run_case("node", large, node, package=direct_package)
                        direct_before["peak_gb"][node] = row["peak_gb"]
                        direct_before["seconds"][node] = row["seconds"]
                        log(f"{PAPER_SIZE}^2 {args.direct_baseline} {node}: peak {row['peak_gb']} GB")
                        report(args, commit, dirty, earlier, codes, peaks, seconds, direct_before)
                    for node in (n for n in DIRECT_NODES if n in args.direct_nodes):
                        row = run_case("node", large, node)
                        peaks["after"][node][str(PAPER_SIZE)] = row["peak_gb"]
                        seconds["after"][node][str(PAPER_SIZE)] = row["seconds"]
                        log(f"{PAPER_SIZE}^2 after {node}: peak {row['peak_gb']} GB, {row['seconds']} s")
                        report(args, commit, dirty, earlier, codes, peaks, seconds, direct_before)
                    if args.stores is None:
                        shutil.rmtree(large, ignore_errors=True)
                if args.stores is None:
                    shutil.rmtree(store, ignore_errors=True)
        finally:
            for used, folder in ((package, work), (direct_package, work / "direct")):
                if used is not None:
                    subprocess.run(
                        ["git", "worktree", "remove", "--force", str(folder / "baseline")],
                        cwd=ROOT,
                        capture_output=True,
                        check=False,
                    )
    result = report(args, commit, dirty, earlier, codes, peaks, seconds, direct_before)
    print(json.dumps(result))
    return result


def report(args, commit, dirty, earlier, codes, peaks, seconds, direct_before=None) -> dict:
    """The results so far; written to ``--output`` (unless ``--quick``) after every node."""
    measured = {str(s) for s in args.sizes}
    extrapolated = {
        code: {
            node: extrapolate({s: v for s, v in peaks[code][node].items() if s in measured})
            for node in NODES
        }
        for code in codes
    }

    def at_paper_size(node: str) -> float:
        value = peaks["after"][node].get(str(PAPER_SIZE), extrapolated["after"][node])
        return 99.0 if value is None else value

    result = {
        "benchmark": "node_memory",
        "commit": commit + ("+changes" if dirty else ""),
        "baseline_commit": None if args.no_baseline else args.baseline_commit,
        "before_measured": (
            None
            if args.no_baseline
            else f"an earlier run of this script on the same stores ({earlier['date']})"
            if earlier is not None
            else "in this run"
        ),
        "date": time.strftime("%Y-%m-%d"),
        "cores_measured": os.cpu_count(),
        "recipe": f"paper slice (benchmarks/paper_slice.py), {args.dark_frames} dark frames "
        "per exposure time",
        "sizes": list(args.sizes),
        "peak_gb": peaks,
        "seconds": seconds,
        "extrapolated_2048_gb": extrapolated,
        "extrapolation": "least-squares line of peak against pixel count through the measured sizes",
        "direct_2048": (
            f"{', '.join(DIRECT_NODES)} on the {max(args.sizes)}^2 store mirrored to 2048^2"
            if args.direct
            else None
        ),
        "direct_2048_before": (
            {"commit": args.direct_baseline, **direct_before}
            if args.direct and args.direct_baseline
            else None
        ),
        "target_gb": TARGET_GB,
        "met_at_2048": {node: at_paper_size(node) <= TARGET_GB for node in NODES},
    }
    if not args.quick:
        args.output.parent.mkdir(parents=True, exist_ok=True)
        args.output.write_text(json.dumps(result, indent=1) + "\n")
    return result


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--package":
        sys.path.insert(0, str(HERE))
        import paper_scale

        paper_scale.use_package(sys.argv[2])
        del sys.argv[1:3]
    if len(sys.argv) == 4 and sys.argv[1] == "--case":
        print(json.dumps(CASES[sys.argv[2]](*json.loads(sys.argv[3]))))
    else:
        main()
