"""Benchmark of a resumable write (``RunStore.write(resumable_along=...)``), side by side.

Run from the repository root::

    .venv/bin/python benchmarks/staged_write.py --baseline-commit REV [--images 4800]

A dataset shaped like a full run's ``spectra`` (32 bands of 32 x 32 px per image, confidence
and iterations per image, image labels in image-set order, not label order) in regions of
200-280 images, unequal as the batches of image sets are, is written region by region
(two at a time) and packed into the finished layout: once with the ``spectralize`` of
``--baseline-commit`` (a git worktree), once with this checkout, each in a fresh process,
on the same data (drawn from a seed by dask as the regions are computed, so the timed write
includes the same generation on both sides). Each side's values read back are compared
with the data, sorted into label order. The LAST line is one JSON
object, also written to ``benchmarks/results/staged_write.json``:

``images``, ``regions``           the write's size
``write_s``, ``write_cpu_s``      wall and CPU seconds of ``RunStore.write``, per side
``peak_rss_gb``                   the side's process's peak resident set
``identical``                     the side read back exactly the data written
``speedup``                       baseline ``write_s`` / this checkout's
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results" / "staged_write.json"


def case(images: int, package: str | None) -> dict:
    """One side: build the data, time the write, read it back (in this process)."""
    if package:
        from paper_scale import use_package

        use_package(package)
    import dask.array as da
    import numpy as np
    import xarray as xr

    from spectralize.store import RunStore

    rng = np.random.default_rng(0)
    sizes: list[int] = []
    while sum(sizes) < images:
        sizes.append(int(rng.integers(200, 281)))
    sizes[-1] -= sum(sizes) - images
    labels = rng.permutation(images)
    gen = da.random.default_rng(1)
    radiance = gen.random((images, 32, 32, 32), dtype=np.float32, chunks=(tuple(sizes), 32, 32, 32))
    confidence = gen.random((images, 32, 32), dtype=np.float32, chunks=(tuple(sizes), 32, 32))
    iterations = da.from_array(np.arange(images, dtype=np.int32), chunks=(tuple(sizes),))
    ds = xr.Dataset(
        {
            "radiance": (("image", "wavelength", "y", "x"), radiance, {"units": "1"}),
            "confidence": (("image", "y", "x"), confidence, {"units": "1"}),
            "iterations": (("image",), iterations, {"units": "1"}),
        },
        coords={"image": labels, "camera": ("image", labels % 11)},
    )
    with tempfile.TemporaryDirectory(dir=HERE.parent) as tmp:
        store = RunStore.create(Path(tmp) / "run.zarr")
        cpu, wall = time.process_time(), time.perf_counter()
        store.write("cube", ds, fingerprint="bench", resumable_along="image", concurrent_regions=2)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6
        back = store.read("cube", friendly=False)
        order = np.argsort(labels)
        identical = all(
            np.array_equal(back[name].values, ds[name].values[order])
            for name in ("radiance", "confidence", "iterations")
        ) and np.array_equal(back.image.values, labels[order])
    return {
        "images": images,
        "regions": len(sizes),
        "write_s": round(wall, 2),
        "write_cpu_s": round(cpu, 2),
        "peak_rss_gb": round(peak, 2),
        "identical": bool(identical),
    }


def side(images: int, package: Path | None) -> dict:
    command = [sys.executable, str(Path(__file__).resolve()), "--case", str(images)]
    if package is not None:
        command += ["--package", str(package)]
    out = subprocess.run(command, capture_output=True, text=True, check=False, cwd=HERE)
    if out.returncode != 0:
        raise RuntimeError(f"staged_write case failed:\n{out.stderr[-4000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=4800)
    parser.add_argument("--baseline-commit")
    parser.add_argument("--case", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--package", help=argparse.SUPPRESS)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    if args.case:
        result = case(args.case, args.package)
        print(json.dumps(result))
        return result
    if not args.baseline_commit:
        parser.error("--baseline-commit is required")
    sys.path.insert(0, str(HERE))
    from paper_scale import baseline_package, head_commit

    head = head_commit()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        package = baseline_package(args.baseline_commit, work)
        try:
            before = side(args.images, package)
            after = side(args.images, None)
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(work / "baseline")], check=False)
    result = {
        "benchmark": "staged_write",
        "command": " ".join(sys.argv),
        "commit": head,
        "baseline_commit": args.baseline_commit,
        "date": time.strftime("%Y-%m-%d"),
        "machine": {"cpu_count": os.cpu_count(), "python": sys.version.split()[0]},
        "load_average": round(os.getloadavg()[0], 2),
        "before": before,
        "after": after,
        "speedup": round(before["write_s"] / after["write_s"], 2),
    }
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps(result, indent=2) + "\n")
    print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
