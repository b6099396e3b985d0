"""What the hard scenes allow: oracle mixtures of the scenes' true material spectra.

Run from the repository root::

    .venv/bin/python benchmarks/reconstruction_oracle.py [--size 128]

For every hard scene (single image, seed 0) the truth is rebuilt as a non-negative mixture
of the scene's *true* endmembers (each material's reflectance under the LED, and the LED
itself for highlights), the weights fitted to the captured (noisy) RGB alone by exact
non-negative least squares, then projected onto ``C S = R``:

- ``present``: each pixel mixes only the materials its sub-pixel layout holds (an oracle
  no method has): how far RGB alone goes once the spectra and the choice are known;
- ``nearest-3``: the three endmembers nearest the pixel in chromaticity plus the LED (what
  :mod:`~spectralize.nodes.reconstruction.estimators.endmember_mixture` does, with the
  true instead of learnt spectra): how much the *choice* of materials costs.

Per-pixel nRMSE (RMSE over bands / the image's mean truth): median and p95. The LAST line
is one JSON object, also written to ``benchmarks/results/reconstruction_oracle.json``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "reconstruction_oracle.json"


def _score(spectra: np.ndarray, inputs, truth: np.ndarray) -> dict:
    """Median and p95 nRMSE of pixel spectra ``(pixels, w)`` projected onto ``C S = R``."""
    from spectralize.nodes.reconstruction.baselines.projection import project_onto_rgb

    cube = np.ascontiguousarray(spectra.T).reshape(inputs.cube_shape)
    project_onto_rgb(cube, inputs.camera_matrix, np.moveaxis(inputs.rgb, -1, 0), overwrite=True)
    e = np.sqrt(np.mean((np.moveaxis(cube, 0, 1) - truth) ** 2, axis=1)) / truth.mean()
    return {"median": round(float(np.median(e)), 4), "p95": round(float(np.percentile(e, 95)), 4)}


def main() -> None:
    from scipy.optimize import nnls

    from spectralize.nodes.reconstruction import inputs_from_xarray
    from spectralize.nodes.reconstruction.estimators.endmember_mixture import (
        Endmembers,
        chromaticity,
        rgb_abundances,
    )
    from spectralize.nodes.simulation.ground_truth import WAVELENGTHS
    from spectralize.nodes.simulation.scenes import SCENES, get_scene
    from spectralize.nodes.simulation.scenes.layout import box_average
    from spectralize.nodes.simulation.scenes.materials import sharp_led

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128)
    args = parser.parse_args()
    started = time.perf_counter()
    led = sharp_led(np.asarray(WAVELENGTHS, dtype=np.float64))
    rows = {}
    for name in SCENES:
        capture = get_scene(name, size=args.size, seed=0, n_images=1)
        inputs = inputs_from_xarray(capture.rgb, capture.bands, capture.camera_matrix)
        layout, truth = capture.layout, capture.truth.values
        atoms = np.vstack([layout.reflectance * led[None], led[None]])  # (n_materials + 1, w)
        rgb = inputs.rgb_pixels().T.astype(np.float64)
        c = inputs.camera_matrix
        projected = atoms @ c.T
        n_material = layout.reflectance.shape[0]
        present = np.stack(
            [
                box_average((layout.label == j).astype(float), layout.supersample).ravel() > 0
                for j in range(n_material)
            ]
        ).T  # (pixels, materials)

        oracle = np.empty((rgb.shape[0], atoms.shape[1]))
        for p in range(rgb.shape[0]):
            use = np.append(np.flatnonzero(present[p]), n_material)
            weights, _ = nnls(projected[use].T, rgb[p])
            oracle[p] = weights @ atoms[use]
        _, chroma = chromaticity(rgb)
        _, centres = chromaticity(projected[:n_material], scale=np.abs(rgb.mean(axis=0)))
        endmembers = Endmembers(atoms, centres)
        near = endmembers.candidates(chroma, 3)
        weights = rgb_abundances(endmembers, near, c, rgb)
        nearest = np.einsum("pk,pkw->pw", weights, atoms[near])
        rows[name] = {
            "materials": int(n_material),
            "materials_per_pixel_median": float(np.median(present.sum(axis=1))),
            "present": _score(oracle, inputs, truth),
            "nearest-3": _score(nearest, inputs, truth),
        }
        print(f"{name:16s} {rows[name]}", flush=True)
    report = {
        "benchmark": "oracle mixtures of the true endmembers",
        "size": args.size,
        "scenes": rows,
        "total_seconds": round(time.perf_counter() - started, 1),
    }
    RESULTS.write_text(json.dumps(report, indent=1) + "\n")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
