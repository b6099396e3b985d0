"""The default's set model 'evidence-blend' on a foreign lab's store, against 'material-pooled'
and 'independent', oracle and calibrated, each with the run's endmember library as ``run btf``
passes it:  python evidence_blend_labs.py ROOT LAB [--store-library-oracle] [--no-library]

ROOT holds run.zarr (ingest + run btf done, endmember_library written). The calibrated groups
get the store's ``endmember_library`` (the flow's: learnt from ``hdr``, ``bands`` and
``calibration/spectral``); it is also learnt again here from those groups and compared. The
oracle groups (true OECF, C, band radiance and LED powers, true falloff out: as
benchmarks/calibration_oracle.py measure_lab builds them) get the library learnt from the
oracle groups by the same node with its defaults (what ``run btf`` would pass, had the
calibration been the truth); ``--store-library-oracle`` also runs the oracle with the store's
(calibrated) library; ``--no-library`` runs the default without a library too (as
benchmarks/calibration_oracle.py's ``reconstruct`` does: the set model then falls back to
'material-pooled' and the solve mixes each set's own endmembers). Prints, per variant,
median / p95 / shape median per camera with and without bands, the seed group's
``endmembers`` attr and the set model the seed set applied (its solve's attrs), and writes
RESULT json as its last line.
"""

import json
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import xarray as xr

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
import calibration_oracle as c  # noqa: E402

import spectralize  # noqa: E402
from spectralize.nodes.calibration.declarations import merge_hdr_node  # noqa: E402
from spectralize.nodes.calibration.registration import register_frames  # noqa: E402
from spectralize.nodes.calibration.rgb_transform import rgb_transform  # noqa: E402
from spectralize.nodes.reconstruction.endmember_library import endmember_library  # noqa: E402
from spectralize.nodes.reconstruction.set_reconstruction import (  # noqa: E402
    reconstruct_image_sets,
    reconstruct_seed_set,
)
from spectralize.store import RunStore  # noqa: E402

SET_MODELS = {
    "independent": {"set_model": "independent"},
    "material-pooled": {"set_model": "material-pooled"},
    "default": {},
}


def oracle_groups(lab: SimpleNamespace):
    """The oracle's hdr, bands and calibration, as calibration_oracle.measure_lab builds them."""
    base, store, read, rgb, raw = lab.base, lab.store, lab.read, lab.rgb, lab.raw
    hdr = merge_hdr_node(rgb, c.oracle_oecf(base, store.read("calibration/oecf_rgb"), lab.cameras))
    if base.LAB.get("falloff"):
        hdr["radiance"] = hdr["radiance"] / xr.DataArray(base.rgb_falloff(), dims=("y", "x")).astype(
            np.float32
        )
    hdr = hdr.assign_coords({k: read["hdr"][k] for k in read["hdr"].coords})
    registration = store.read("registration").load()
    image_leds = rgb["led"].sel(image=raw["image"].values).values
    shots = xr.DataArray(c.oracle_band_radiance(base, raw.load(), image_leds), dims=("shot", "y", "x"))
    registered = register_frames(shots.astype(np.float32), registration["shift"]).compute()
    bands = read["bands"].copy()
    bands["radiance"] = (("shot", "y", "x"), np.asarray(registered.values, np.float32))
    c_true = {k: c.true_c(base, name) for k, name in enumerate(lab.cameras)}
    spectra_fit = np.asarray(
        (
            store.read("raw/colour_checker")["patch_reflectance"] * base.illuminant(base.WAVELENGTHS)
        ).values
    )
    calibration, paired = lab.calibration, lab.paired
    cal = calibration.copy()
    cal["camera_matrix"] = (("channel", "wavelength"), c_true[paired])
    if "camera" in calibration.dims:
        ks = [int(k) for k in calibration["camera"].values]
        cal["camera_matrices"] = (("camera", "channel", "wavelength"), np.stack([c_true[k] for k in ks]))
        cal["rgb_transform"] = (
            ("camera", "channel", "channel_in"),
            np.stack([rgb_transform(c_true[k], c_true[paired], spectra_fit) for k in ks]),
        )
    return hdr, bands, cal


def load(root: Path, name: str) -> SimpleNamespace:
    """A lab's store, its calibrated and oracle groups and both libraries."""
    lab = SimpleNamespace(root=root, name=name, base=c._lab(name))
    lab.store = RunStore.open(root / "run.zarr")
    lab.cameras = list(lab.base.LAB["rgb_cameras"])
    lab.read = {g: lab.store.read(g) for g in ("raw/rgb", "raw/spectral", "hdr", "bands", "image_sets")}
    lab.rgb, lab.raw = lab.read["raw/rgb"], lab.read["raw/spectral"]
    lab.image_sets = lab.read["image_sets"].load()
    lab.calibration = lab.store.read("calibration/spectral").load()
    lab.paired = int(lab.calibration.attrs.get("rgb_camera", 1))
    t = time.perf_counter()
    lab.oracle = oracle_groups(lab)
    lab.calibrated = (lab.read["hdr"], lab.read["bands"], lab.calibration)
    lab.store_library = lab.store.read("endmember_library").load()
    again = endmember_library(*lab.calibrated, lab.image_sets)
    lab.library_reproduced = all(
        np.array_equal(np.asarray(lab.store_library[v].values), np.asarray(again[v].values))
        for v in ("atoms", "centre", "channel_scale")
    )
    print(f"store library reproduced by today's node: {lab.library_reproduced}", flush=True)
    lab.oracle_library = endmember_library(*lab.oracle, lab.image_sets)
    print(
        f"groups and libraries {time.perf_counter() - t:.1f}s; split angle median store "
        f"{lab.store_library.attrs['split_angle_median']:.2f} "
        f"oracle {lab.oracle_library.attrs['split_angle_median']:.2f}",
        flush=True,
    )
    return lab


def run(lab: SimpleNamespace, kw: dict, groups: tuple, library: xr.Dataset | None):
    """The chain's two reconstruction nodes in this process: the seed group and the spectra."""
    seed = reconstruct_seed_set(*groups, lab.image_sets, library, **kw).compute()
    spectra = reconstruct_image_sets(*groups, lab.image_sets, seed, library, **kw)["radiance"].compute()
    return seed, spectra


def main(argv: list[str]) -> None:
    root, name = Path(argv[0]), argv[1]
    print(
        "spectralize from",
        spectralize.__file__,
        "lab",
        name,
        "threads",
        os.environ.get("OMP_NUM_THREADS"),
        flush=True,
    )
    lab = load(root, name)
    variants = []
    for model, kw in SET_MODELS.items():
        variants.append((f"oracle {model}", kw, lab.oracle, lab.oracle_library))
        variants.append((f"cal {model}", kw, lab.calibrated, lab.store_library))
    if "--no-library" in argv:  # what benchmarks/calibration_oracle.py's reconstruct() runs
        variants.append(("oracle nolib default", {}, lab.oracle, None))
        variants.append(("cal nolib default", {}, lab.calibrated, None))
    if "--store-library-oracle" in argv:
        for model in ("material-pooled", "default"):
            variants.append(
                (f"oracle+storelib {model}", SET_MODELS[model], lab.oracle, lab.store_library)
            )
    has = lab.image_sets["has_bands"]
    out: dict = {"library_reproduced": lab.library_reproduced}
    for variant, kw, groups, library in variants:
        t = time.perf_counter()
        seed, spectra = run(lab, kw, groups, library)
        row = {}
        for k, cam in enumerate(lab.cameras):
            for flag in (True, False):
                labels = c.camera_images(has, lab.rgb, k, flag)
                if labels:
                    e = c.errors(spectra, lab.base, lab.rgb, labels)
                    row[f"{cam} {'with' if flag else 'without'}"] = [
                        round(e["median"], 4),
                        round(e["p95"], 4),
                        round(e["shape_median"], 4),
                    ]
        applied = seed["radiance"].attrs.get("set_model")
        out[variant] = {
            "row": row,
            "seed_endmembers": seed.attrs.get("endmembers"),
            "seed_set_model": applied,
        }
        print(
            f"{variant:28s} {time.perf_counter() - t:6.1f}s endmembers={seed.attrs.get('endmembers')} "
            f"seed set_model={applied}",
            json.dumps(row),
            flush=True,
        )
    print("RESULT", json.dumps(out))


if __name__ == "__main__":
    main(sys.argv[1:])
