"""Oracle (and calibrated) reconstruction of nikon-paired from an existing run store, with
reconstruction variants: python oracle_variants.py ROOT BENCHDIR VARIANT...

ROOT holds run.zarr (ingest + run btf done); BENCHDIR the calibration_oracle.py to take the
oracle helpers from. VARIANT: name=json kwargs for reconstruct_seed_set/reconstruct_image_sets,
e.g. 'default={}' 'indep={"set_model":"independent"}'. Prefix 'cal:' to use the calibrated groups.
Prints the median/p95 per camera (without bands) and cam-45 with bands.
"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import xarray as xr

root, bench = Path(sys.argv[1]), sys.argv[2]
sys.path.insert(0, bench)
import calibration_oracle as c  # noqa: E402
import spectralize  # noqa: E402

print("spectralize from", spectralize.__file__, flush=True)
from spectralize.nodes.calibration.declarations import merge_hdr_node  # noqa: E402
from spectralize.nodes.calibration.registration import register_frames  # noqa: E402
from spectralize.nodes.calibration.rgb_transform import rgb_transform  # noqa: E402
from spectralize.nodes.reconstruction.set_reconstruction import (  # noqa: E402
    reconstruct_image_sets,
    reconstruct_seed_set,
)
from spectralize.store import RunStore  # noqa: E402

import os
lab = os.environ.get("LAB", "nikon-paired")
base = c._lab(lab)
store = RunStore.open(root / "run.zarr")
cameras = list(base.LAB["rgb_cameras"])
read = {g: store.read(g) for g in ("raw/rgb", "raw/spectral", "hdr", "bands", "image_sets")}
rgb, raw, image_sets = read["raw/rgb"], read["raw/spectral"], read["image_sets"].load()
calibration = store.read("calibration/spectral").load()
paired = int(calibration.attrs.get("rgb_camera", 1))
hdr_oracle = merge_hdr_node(rgb, c.oracle_oecf(base, store.read("calibration/oecf_rgb"), cameras))
hdr_oracle = hdr_oracle.assign_coords({k: read["hdr"][k] for k in read["hdr"].coords})
registration = store.read("registration").load()
image_leds = rgb["led"].sel(image=raw["image"].values).values
shots = xr.DataArray(c.oracle_band_radiance(base, raw.load(), image_leds), dims=("shot", "y", "x"))
registered = register_frames(shots.astype(np.float32), registration["shift"]).compute()
bands_oracle = read["bands"].copy()
bands_oracle["radiance"] = (("shot", "y", "x"), np.asarray(registered.values, np.float32))
c_true = {k: c.true_c(base, name) for k, name in enumerate(cameras)}
spectra_fit = np.asarray(
    (store.read("raw/colour_checker")["patch_reflectance"] * base.illuminant(base.WAVELENGTHS)).values
)
oracle_cal = calibration.copy()
oracle_cal["camera_matrix"] = (("channel", "wavelength"), c_true[paired])
if "camera" in calibration.dims:
    ks = [int(k) for k in calibration["camera"].values]
    if "camera_matrices" in calibration:
        oracle_cal["camera_matrices"] = (
            ("camera", "channel", "wavelength"), np.stack([c_true[k] for k in ks]))
    if "rgb_transform" in calibration:
        oracle_cal["rgb_transform"] = (
            ("camera", "channel", "channel_in"),
            np.stack([rgb_transform(c_true[k], c_true[paired], spectra_fit) for k in ks]))
if "--true-light" in sys.argv:
    from spectralize.nodes.reconstruction.set_reconstruction import illuminant_on_bands  # noqa
    wl = calibration["illuminant"]["wavelength"].values
    oracle_cal["illuminant"] = (calibration["illuminant"].dims, base.illuminant(np.asarray(wl, float)))
print("calibration vars:", sorted(calibration.data_vars), flush=True)
has = image_sets["has_bands"]
if not hasattr(c, "camera_images"):  # older trees (before a93c72c)
    def _camera_images(has, rgb, camera, with_bands):
        return [int(v) for v in has["image"].values[has.values == with_bands]
                if int(rgb["camera"].sel(image=int(v))) == camera]
    c.camera_images = _camera_images


def run(kw, groups):
    seed = reconstruct_seed_set(*groups[:3], image_sets, **kw).compute()
    return reconstruct_image_sets(*groups[:3], image_sets, seed, **kw)["radiance"].compute()


out = {}
for arg in sys.argv[3:]:
    if arg.startswith("--"):
        continue
    name, kw = arg.split("=", 1)
    kw = json.loads(kw)
    groups = (read["hdr"], read["bands"], calibration) if name.startswith("cal:") else (
        hdr_oracle, bands_oracle, oracle_cal)
    t = time.perf_counter()
    try:
        spectra = run(kw, groups)
    except Exception as error:  # noqa: BLE001
        print(f"{name}: failed: {error!r}"[:300], flush=True)
        continue
    row = {}
    for k, cam in enumerate(cameras):
        for flag in (True, False):
            labels = c.camera_images(has, rgb, k, flag)
            if labels:
                e = c.errors(spectra, base, rgb, labels)
                row[f"{cam} {'with' if flag else 'without'}"] = (
                    round(e["median"], 4), round(e["p95"], 4), round(e["shape_median"], 4))
    out[name] = row
    print(f"{name:14s} {time.perf_counter() - t:6.1f}s  attrs set_model={spectra.attrs.get('set_model')}",
          json.dumps(row), flush=True)
print("RESULT", json.dumps(out))
