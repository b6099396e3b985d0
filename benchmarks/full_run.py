"""Benchmark of a full BTF run's geometry with tiny frames: what grows with the image count.

Run from the repository root::

    .venv/bin/python benchmarks/full_run.py                       # 52,272 images, 32 x 32 px
    .venv/bin/python benchmarks/full_run.py --images 5227         # a tenth of the run

The full run is 24 rotations x 198 LEDs x 11 cameras = 52,272 images (paper, sec. 4);
``--images N`` keeps all rotations and cameras and as many whole LEDs as give at least
``N`` images (264 images per LED). The simulated run is written as a capture folder
(:func:`~spectralize.datasets.capture.sample.write_capture_folder`), ingested
(``spectralize ingest``) and processed by the whole ``btf`` flow (``spectralize run btf``),
each a fresh process on this machine. Progress goes to stdout; the LAST line is one JSON
object, also kept in ``benchmarks/results/full_run.json`` (one entry per image count):

``images``                          images of the run store (``raw/rgb``)
``files_per_image``                 files under the store directory per image
``largest_group_metadata_bytes``    the largest group's metadata (every ``zarr.json`` of it
                                    and its integrity manifest)
``ingest_s``, ``flow_s``            wall time of the ingest and of the ``btf`` flow
``seconds_per_1000_images``         (ingest + flow) per 1,000 images
``peak_rss_gb``                     the largest resident set of the ingest and flow processes
``node_s``, ``node_peak_rss_gb``    per node of the flow: its seconds, and the flow process's
                                    peak resident set while it ran (GB; threads included,
                                    dask workers of other processes not)
``*_cpu_s``, ``load_average``       CPU seconds of capture, ingest and flow, and the machine's
                                    1-minute load at the end (a shared machine's wall times
                                    count the other work too)
``open_and_read_coordinates_s``     a fresh process: ``open_run(store).read("spectra")`` and
                                    its per-image coordinates in memory (imports excluded)
``report_s``, ``report_cpu_s``      a fresh process: ``write_run_report`` of the store (wall
                                    and CPU seconds, imports excluded; the flow writes the
                                    same report at its end, timed to the second in its log)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
RESULTS = HERE / "results"
BIN = Path(sys.executable).parent

ROTATIONS, LEDS, CAMERAS = 24, 198, 11
FULL_RUN_IMAGES = ROTATIONS * LEDS * CAMERAS


def log(message: str) -> None:
    print(f"[full-run {time.strftime('%H:%M:%S')}] {message}", flush=True)


def led_subset(images: int) -> list[int]:
    """As many LEDs as give at least ``images`` images with 24 rotations and 11 cameras.

    Neighbours on a ring first (the 24-LED rings from 10 deg polar angle outwards, then the
    ring of 6 at the zenith): the spectral camera's sparse sets pair LEDs 15 deg apart.
    """
    count = min(LEDS, max(1, math.ceil(images / (ROTATIONS * CAMERAS))))
    return [*range(6, LEDS), *range(6)][:count]


def recipe_overrides(images: int, frame: int) -> dict:
    """The ``paper`` recipe's gantry (24 rotations, 11 cameras) at ``frame`` px on a subset of LEDs."""
    return {
        "size": frame,
        "chunk_size": None,
        "leds": led_subset(images),
        "n_dark_frames": 4,
        "frames_per_chunk": 64,
    }


def cpu_seconds(who: int = resource.RUSAGE_CHILDREN) -> float:
    """User + system CPU seconds so far (of the finished children, or of this process)."""
    usage = resource.getrusage(who)
    return usage.ru_utime + usage.ru_stime


def run(command: list[str], env: dict[str, str], log_file: Path) -> tuple[float, str]:
    """Run ``command`` (a fresh process), echo its last lines; its wall time and stdout."""
    start = time.perf_counter()
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    log_file.write_text(done.stdout + done.stderr)
    tail = (done.stdout + done.stderr).strip().splitlines()[-6:]
    for line in tail:
        log(f"  | {line}")
    if done.returncode:
        raise SystemExit(f"{' '.join(command[:3])} failed with exit status {done.returncode}")
    return seconds, done.stdout


def node_seconds(summary: str) -> dict[str, float]:
    """Per node, the seconds of the flow's summary lines (``  node  ran  8.1 s  -> group``)."""
    found = re.findall(r"^  (\w+)\s+ran\s+([0-9.]+) s", summary, flags=re.MULTILINE)
    return {name: float(seconds) for name, seconds in found}


def node_peak_rss_gb(summary: str) -> dict[str, float]:
    """Per node, the peak resident set of the flow's process while it ran, from the summary
    lines (``  node  ran  8.1 s  1.23 GB  -> group``; flows/memory.py)."""
    found = re.findall(r"^  (\w+)\s+ran\s+[0-9.]+ s\s+([0-9.]+) GB", summary, flags=re.MULTILINE)
    return {name: float(gb) for name, gb in found}


def process_peak_rss_gb(summary: str) -> float | None:
    """The flow process's own peak resident set (its summary's last lines), resets included."""
    found = re.search(
        r"^peak resident memory of this process: ([0-9.]+) GB", summary, flags=re.MULTILINE
    )
    return float(found[1]) if found else None


def group_metadata_bytes(store: Path) -> dict[str, int]:
    """Per group: bytes of its ``zarr.json`` files and integrity manifest (not nested groups)."""
    from spectralize.store import open_run
    from spectralize.store.integrity import metadata_files

    run = open_run(store)
    return {
        group: sum(p.stat().st_size for p in metadata_files(run.path / group)) for group in run.groups()
    }


OPEN_AND_READ = """
import sys, time, json
from spectralize.store import open_run
start = time.perf_counter()
ds = open_run(sys.argv[1]).read("spectra")
coords = {name: c.values for name, c in ds.coords.items() if "image" in c.dims}
print(json.dumps({"seconds": time.perf_counter() - start, "coords": sorted(coords)}))
"""


REPORT = """
import sys, time, json, tempfile
from spectralize.flows.report import write_run_report
start, cpu = time.perf_counter(), time.process_time()
with tempfile.TemporaryDirectory() as directory:
    write_run_report(sys.argv[1], directory=directory)
print(json.dumps({"seconds": time.perf_counter() - start, "cpu_s": time.process_time() - cpu}))
"""


def fresh_process(code: str, store: Path) -> dict:
    """The last line (JSON) of ``code`` run on ``store`` in a fresh Python process."""
    done = subprocess.run(
        [sys.executable, "-c", code, str(store)], cwd=ROOT, capture_output=True, text=True
    )
    if done.returncode:
        raise SystemExit(done.stderr)
    return json.loads(done.stdout.strip().splitlines()[-1])


def record(output: Path, result: dict) -> None:
    """Keep ``result`` in ``output`` beside the runs of other image counts (one per count)."""
    try:
        runs = json.loads(output.read_text()).get("runs", [])
    except (OSError, ValueError):
        runs = []
    runs = sorted(
        [r for r in runs if r["images"] != result["images"]] + [result], key=lambda r: r["images"]
    )
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    page = {
        "benchmark": "full_run",
        "commit": commit,
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cpu_count": os.cpu_count(), "python": sys.version.split()[0]},
        "full_run_images": FULL_RUN_IMAGES,
        "targets": result["targets"],
        "runs": runs,
    }
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(json.dumps(page, indent=2) + "\n")


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--images", type=int, default=FULL_RUN_IMAGES)
    parser.add_argument(
        "--frame",
        type=int,
        default=32,
        help="frame height = width [px] (the spectral OECF filters need >= 27)",
    )
    parser.add_argument("--workdir", type=Path, default=None, help="keep capture and store here")
    parser.add_argument("--output", type=Path, default=None)
    args = parser.parse_args(argv)

    from spectralize.datasets.capture.sample import write_capture_folder

    root = args.workdir or Path(tempfile.mkdtemp(prefix="full-run-"))
    root.mkdir(parents=True, exist_ok=True)
    capture, store = root / "capture", root / "run.zarr"
    overrides = recipe_overrides(args.images, args.frame)
    log(f"capture folder: {len(overrides['leds'])} LED(s) x {ROTATIONS} rotations x {CAMERAS} cameras")
    start, start_cpu = time.perf_counter(), cpu_seconds(resource.RUSAGE_SELF)
    if not (capture / "capture.toml").is_file():  # a --workdir of an earlier run keeps it
        write_capture_folder(capture, recipe="paper", overrides=overrides)
    capture_s = time.perf_counter() - start
    capture_cpu_s = cpu_seconds(resource.RUSAGE_SELF) - start_cpu
    log(f"capture folder written in {capture_s:.1f} s")
    shutil.rmtree(store, ignore_errors=True)
    shutil.rmtree(store.parent / f".{store.name}.spectralize", ignore_errors=True)

    env = {**os.environ, "PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS": "90"}
    ingest_s, _ = run(
        [str(BIN / "spectralize"), "ingest", str(capture), str(store)], env, root / "ingest.log"
    )
    ingest_cpu_s = cpu_seconds()
    log(f"ingested in {ingest_s:.1f} s")
    flow_s, summary = run([str(BIN / "spectralize"), "run", "btf", str(store)], env, root / "flow.log")
    flow_cpu_s = cpu_seconds() - ingest_cpu_s
    log(f"btf flow in {flow_s:.1f} s")
    # kB -> GB; the flow resets its high-water mark per node (flows/memory.py), which getrusage
    # does not see past, so the flow's own peak (resets included) counts too
    peak = max(
        resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1e6, process_peak_rss_gb(summary) or 0.0
    )

    opened = fresh_process(OPEN_AND_READ, store)
    report = fresh_process(REPORT, store)
    log(f"report in {report['seconds']:.1f} s (CPU {report['cpu_s']:.1f} s)")

    from spectralize.store import open_run

    images = int(open_run(store).read("raw/rgb", verify=False).sizes["image"])
    files = sum(len(names) for _, _, names in os.walk(store))
    metadata = group_metadata_bytes(store)
    largest = max(metadata, key=metadata.__getitem__)
    result = {
        "benchmark": "full_run",
        "images": images,
        "frame_px": args.frame,
        "full_run_images": FULL_RUN_IMAGES,
        "files": files,
        "files_per_image": round(files / images, 3),
        "largest_group_metadata_bytes": metadata[largest],
        "largest_metadata_group": largest,
        "capture_s": round(capture_s, 1),
        "ingest_s": round(ingest_s, 1),
        "flow_s": round(flow_s, 1),
        "seconds_per_1000_images": round((ingest_s + flow_s) / images * 1000, 1),
        # CPU seconds (user + system): on a shared machine, wall time also counts the others
        "capture_cpu_s": round(capture_cpu_s, 1),
        "ingest_cpu_s": round(ingest_cpu_s, 1),
        "flow_cpu_s": round(flow_cpu_s, 1),
        "load_average": round(os.getloadavg()[0], 1),
        "node_s": node_seconds(summary),
        "node_peak_rss_gb": node_peak_rss_gb(summary),
        "peak_rss_gb": round(peak, 2),
        "open_and_read_coordinates_s": round(opened["seconds"], 2),
        "report_s": round(report["seconds"], 1),
        "report_cpu_s": round(report["cpu_s"], 1),
        "cpu_count": os.cpu_count(),
        "targets": {
            "files_per_image": 3,
            "largest_group_metadata_bytes": 1_000_000,
            "seconds_per_1000_images": 60,
            "peak_rss_gb": 4,
            "open_and_read_coordinates_s": 2,
            "report_s": 10,
        },
    }
    output = args.output or RESULTS / "full_run.json"
    record(output, result)
    print(json.dumps(result), flush=True)
    return result


if __name__ == "__main__":
    main()
