"""What calibration costs: the foreign gantries' captures through the chain, calibrated and oracle.

Issue 25, item 6. Each foreign lab (``tests/support/foreign_gantry*.py``; ``sigma-paired`` was
kept out of every choice of the calibration's settings and is reported on its own, as are its
twins through falloffing lenses and clipping at an undeclared white level; ``toe-camera`` has a
consumer camera whose response has a strong toe) is written, ingested and calibrated by
``spectralize run btf``. The reconstruction is then run
twice in this process, on one machine, with the same settings:

- *calibrated*: the run store's ``hdr``, ``bands`` and ``calibration/spectral``;
- *oracle*: the writer's truth injected in their place: each camera's true OECF and black
  offset (HDR merged with :func:`merge_hdr_node` through them), each camera's true
  sensitivity as ``C`` (and the 3 x 3 maps onto the paired camera from them, as the chain
  computes its own), the spectral camera's true response, dark pattern and QE, and the true
  LED powers (band radiance on the scale of the RGB image it pairs with). The registration
  is the estimated one in both (it is not calibration of the response).

Each reconstruction gets the run's endmember library as ``run btf`` passes it (the
``endmember_library`` node): the calibrated one the store's, the oracle (and each ablation)
one learnt by the same node, with its defaults, from its own groups: what ``run btf`` would
pass had the calibration been the truth. Without it the default's set model falls back to
``material-pooled`` and each set mixes its own endmembers, which the chain does not do.

Reported per lab, per RGB camera, for images with and without band shots: per-pixel nRMSE
``|S - T| / |T|`` against the writer's radiance of that image (median, p95, share below
0.03), the same after one scale per pixel (spectral shape), the ratio calibrated / oracle;
and the calibration's own errors: C per channel (RMS over wavelength of ``s C - C_true``
relative to the channel's peak), the chart cross-check per camera, band radiance bias per
band against the writer's radiance, the LED scale error left with and without the LED power
table, and the second camera model's images against the paired model's (each image through
its own camera's C, and, side by side, through the paired camera's C after the 3 x 3 map,
as before issue 25's per-image C); where the cost is
(the truth injected on the band side only, and on the RGB side only) and how far the 3 x 3
map of each camera onto the paired one is from exact on the scene's own spectra.

Usage::

    python benchmarks/calibration_oracle.py            # all labs, writes results/calibration_oracle.json
    python benchmarks/calibration_oracle.py --quick    # one lab, nothing written
    python benchmarks/calibration_oracle.py --lab sigma-paired --lab sigma-paired-falloff
        # those labs only, merged into results/calibration_oracle.json

References
----------
Fast Capture of Spectral Image Series, sec. 4 (calibration) and 5 (evaluation).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

RESULTS = Path(__file__).resolve().parent / "results" / "calibration_oracle.json"
SUPPORT = Path(__file__).resolve().parents[1] / "tests" / "support"
LABS = {  # lab: (script, arguments); sigma-paired was kept out of every choice
    "nikon-paired": ("foreign_gantry_models.py", ["--lab", "nikon-paired"]),
    "foreign-gaussian": ("foreign_gantry.py", []),
    "sigma-paired (held out)": ("foreign_gantry_models.py", ["--lab", "sigma-paired"]),
    # the held-out capture written again through lenses with falloff (its clean twin above)
    "sigma-paired-falloff (held out)": ("foreign_gantry_models.py", ["--lab", "sigma-paired-falloff"]),
    # foreign-gaussian through the same lenses (its clean twin above)
    "gaussian-falloff (held out)": ("foreign_gantry_models.py", ["--lab", "gaussian-falloff"]),
    # the held-out capture again, every RGB camera clipping at an undeclared white level
    "sigma-paired-white (held out)": ("foreign_gantry_models.py", ["--lab", "sigma-paired-white"]),
    # nikon-paired with a consumer camera whose response has a strong toe as its third camera
    "toe-camera": ("foreign_gantry_models.py", ["--lab", "toe-camera"]),
}
WHITE_TWINS = {"sigma-paired-white (held out)": "sigma-paired (held out)"}
LOW_LEVELS = ((0.0, 0.01), (0.01, 0.05), (0.05, 0.25))
"""Quantile ranges of the oracle's HDR radiance (per camera and channel) whose calibrated
radiance error :func:`low_level_error` reports: the lowest levels, where a toe shows."""
FALLOFF_TWINS = {
    "sigma-paired-falloff (held out)": "sigma-paired (held out)",
    "gaussian-falloff (held out)": "foreign-gaussian",
}
BORDER = 3  # px left out at the frame's edge (registration resampling)


def _cli(*args: str, cwd: Path) -> float:
    start = time.perf_counter()
    out = subprocess.run(
        [sys.executable, "-m", "spectralize.flows.cli", *args], cwd=cwd, capture_output=True, text=True
    )
    if out.returncode:
        raise RuntimeError(f"spectralize {' '.join(args)} failed:\n{out.stdout}\n{out.stderr}")
    return time.perf_counter() - start


def _lab(name: str):
    """The writer's modules with ``name``'s gantry loaded (its truth)."""
    sys.path.insert(0, str(SUPPORT))
    import foreign_gantry as base
    import foreign_gantry_models as models

    base.LAB.clear()
    base.LAB.update(base.default_lab() if name == "foreign-gaussian" else models.lab(name.split()[0]))
    return base


# -- the writer's truth in the chain's groups ------------------------------------------------------
def true_c(base, camera: str) -> np.ndarray:
    """(channel, wavelength) C in HDR units per band radiance unit: the writer's ``y / t``."""
    model = base.LAB["models"][base.LAB["rgb_cameras"][camera][2]]
    return base.RGB_SCALE * model["sensitivity"](base.WAVELENGTHS) / base.WAVELENGTHS.size


def oracle_oecf(base, oecf: xr.Dataset, cameras: list[str]) -> xr.Dataset:
    """``calibration/oecf_rgb`` with each camera's true response: code -> exposure ``y``."""
    out = oecf.copy(deep=True).load()
    codes = np.asarray(out["code"].values, float)
    fine = np.linspace(0.0, 1.3, 200_001)
    for k in out["camera"].values:
        model = base.LAB["models"][base.LAB["rgb_cameras"][cameras[int(k)]][2]]
        level = (codes - model["black"]) / (base.RGB_MAX - model["black"])
        y = np.interp(level, model["oecf"](fine), fine)
        y[codes <= model["black"]] = 0.0
        out["response"].loc[{"camera": k}] = np.broadcast_to(y, out["response"].sel(camera=k).shape)
    blacks = [base.LAB["models"][m[2]]["black"] for m in base.LAB["rgb_cameras"].values()]
    out.attrs["black_level"] = int(min(blacks) + 3)
    return out


def oracle_band_radiance(base, raw: xr.Dataset, image_leds: np.ndarray) -> np.ndarray:
    """(shot, y, x) band radiance from the writer's spectral camera model, on the scale of
    the RGB image each shot pairs with (true LED powers), not yet registered."""
    offset, current = base.dark_pattern()
    a = 0.06 / base.MONO_MAX  # response(e) = e (1 - a e)
    counts = np.asarray(raw["counts"].values, float)
    times = np.asarray(raw["exposure_time"].values, float)[:, None, None]
    q = base.mono_efficiency(np.asarray(raw["wavelength"].values, float))[:, None, None]
    level = np.clip(counts - offset, None, 1.0 / (4 * a))
    electrons = (1.0 - np.sqrt(1.0 - 4 * a * level)) / (2 * a)
    radiance = (electrons - current * times) / (base.MONO_GAIN * times * q)
    falloff = np.stack([base.mono_falloff(float(w)) for w in raw["wavelength"].values])
    radiance = radiance / falloff
    power = base.LAB["led_power"]
    gain = np.array(
        [
            power.get(int(image_led), 1.0) / power.get(int(led), 1.0)
            for image_led, led in zip(image_leds, raw["led"].values, strict=True)
        ]
    )
    return radiance * gain[:, None, None]


def truth_radiance(base, rgb: xr.Dataset, image: int) -> np.ndarray:
    """(y, x, wavelength) the writer's radiance of RGB image ``image``."""
    c = rgb.sel(image=image)
    power = base.LAB["led_power"].get(int(c["led"]), 1.0)
    return np.moveaxis(power * base.radiance(float(c["theta_i"]), float(c["phi_i"])), 0, -1)


# -- the reconstruction, twice -------------------------------------------------------------------
def reconstruct(hdr, bands, calibration, image_sets, library=None) -> xr.DataArray:
    """The chain's reconstruction (the run's library and both set nodes, their defaults) in
    this process; ``library`` (the store's ``endmember_library``) or, without it, the library
    the ``endmember_library`` node learns from these groups, passed as ``run btf`` passes it."""
    from spectralize.nodes.reconstruction.endmember_library import endmember_library
    from spectralize.nodes.reconstruction.set_reconstruction import (
        reconstruct_image_sets,
        reconstruct_seed_set,
    )

    if library is None:
        library = endmember_library(hdr, bands, calibration, image_sets)
    seed = reconstruct_seed_set(hdr, bands, calibration, image_sets, library).compute()
    spectra = reconstruct_image_sets(hdr, bands, calibration, image_sets, seed, library)
    return spectra["radiance"].compute()


def errors(spectra: xr.DataArray, base, rgb: xr.Dataset, labels: list[int]) -> dict:
    """nRMSE and shape error per pixel (inner frame) over ``labels``; per-band bias."""
    nrmse, shape, num, den = [], [], 0.0, 0.0
    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    for label in labels:
        got = spectra.sel(image=label).transpose("y", "x", "wavelength").values[inner]
        true = truth_radiance(base, rgb, label)[inner]
        norm = np.linalg.norm(true, axis=-1)
        nrmse.append(np.linalg.norm(got - true, axis=-1) / norm)
        scale = (got * true).sum(-1) / (true * true).sum(-1)
        shape.append(np.linalg.norm(got - scale[..., None] * true, axis=-1) / (np.abs(scale) * norm))
        num, den = num + got.sum((0, 1)), den + true.sum((0, 1))
    e, s = np.concatenate([x.ravel() for x in nrmse]), np.concatenate([x.ravel() for x in shape])
    bias = num / den - 1
    return {
        "images": len(labels),
        "median": float(np.median(e)),
        "p95": float(np.percentile(e, 95)),
        "share_below_0.03": float(np.mean(e < 0.03)),
        "shape_median": float(np.median(s)),
        "shape_p95": float(np.percentile(s, 95)),
        "band_bias": bias.round(4).tolist(),
        "max_abs_band_bias": float(np.abs(bias).max()),
    }


def camera_images(has: xr.DataArray, rgb: xr.Dataset, camera: int, with_bands: bool) -> list[int]:
    """The labels of RGB camera ``camera``'s images with (or without) band shots."""
    return [
        int(v)
        for v in has["image"].values[has.values == with_bands]
        if int(rgb["camera"].sel(image=int(v))) == camera
    ]


def c_error(c: np.ndarray, truth: np.ndarray) -> list[float]:
    """Per channel RMS over wavelength of ``s C - truth`` relative to the truth's peak."""
    scale = (c * truth).sum(1) / np.maximum((c * c).sum(1), 1e-30)
    rms = np.sqrt(np.mean((scale[:, None] * c - truth) ** 2, axis=1))
    return (rms / truth.max(1)).round(4).tolist()


def band_scale(bands: np.ndarray, oracle: np.ndarray, raw: xr.Dataset) -> dict:
    """Calibrated band radiance over the oracle's (inner frame sums), per band and per LED."""
    inner = (slice(None), slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    ratio = bands[inner].sum((1, 2)) / oracle[inner].sum((1, 2))
    wl, leds = np.asarray(raw["wavelength"].values, float), np.asarray(raw["led"].values)
    order = np.argsort(wl)
    per_led = {int(led): float(np.median(ratio[leds == led])) for led in np.unique(leds)}
    mid = np.median(list(per_led.values()))
    return {
        "band_ratio_by_wavelength": dict(
            zip([f"{w:g}" for w in wl[order]], ratio[order].round(4).tolist(), strict=True)
        ),
        "max_abs_band_bias": float(np.abs(ratio / np.median(ratio) - 1).max()),
        "led_scale": {str(k): round(v / mid, 4) for k, v in per_led.items()},
        "led_scale_spread": float(np.std([v / mid for v in per_led.values()])),
    }


def measure_lab(root: Path, lab: str) -> dict:
    from spectralize.nodes.calibration.band_radiance import calibrate_bands
    from spectralize.nodes.calibration.declarations import merge_hdr_node
    from spectralize.nodes.calibration.registration import register_frames
    from spectralize.nodes.calibration.rgb_transform import rgb_transform
    from spectralize.store import RunStore

    base = _lab(lab)
    store = RunStore.open(root / "run.zarr")
    cameras = list(base.LAB["rgb_cameras"])
    read = {g: store.read(g) for g in ("raw/rgb", "raw/spectral", "hdr", "bands", "image_sets")}
    rgb, raw, image_sets = read["raw/rgb"], read["raw/spectral"], read["image_sets"].load()
    calibration = store.read("calibration/spectral").load()
    paired = int(calibration.attrs.get("rgb_camera", 1))

    # oracle groups
    start = time.perf_counter()
    hdr_oracle = merge_hdr_node(rgb, oracle_oecf(base, store.read("calibration/oecf_rgb"), cameras))
    if base.LAB.get("falloff"):  # the true lens falloff out of the oracle's HDR
        hdr_oracle["radiance"] = hdr_oracle["radiance"] / xr.DataArray(
            base.rgb_falloff(), dims=("y", "x")
        ).astype(np.float32)
    hdr_oracle = hdr_oracle.assign_coords({c: read["hdr"][c] for c in read["hdr"].coords})
    registration = store.read("registration").load()
    image_leds = rgb["led"].sel(image=raw["image"].values).values  # each shot's RGB image's LED
    oracle_raw = oracle_band_radiance(base, raw.load(), image_leds)
    shots = xr.DataArray(oracle_raw, dims=("shot", "y", "x")).astype(np.float32)
    registered = register_frames(shots, registration["shift"]).compute()
    bands_oracle = read["bands"].copy()
    bands_oracle["radiance"] = (("shot", "y", "x"), np.asarray(registered.values, np.float32))
    c_true = {k: true_c(base, name) for k, name in enumerate(cameras)}
    spectra_fit = np.asarray(
        (
            store.read("raw/colour_checker")["patch_reflectance"] * base.illuminant(base.WAVELENGTHS)
        ).values
    )
    oracle_cal = calibration.copy()
    oracle_cal["camera_matrix"] = (("channel", "wavelength"), c_true[paired])
    if "camera" in calibration.dims:
        ks = [int(k) for k in calibration["camera"].values]
        oracle_cal["camera_matrices"] = (
            ("camera", "channel", "wavelength"),
            np.stack([c_true[k] for k in ks]),
        )
        oracle_cal["rgb_transform"] = (
            ("camera", "channel", "channel_in"),
            np.stack([rgb_transform(c_true[k], c_true[paired], spectra_fit) for k in ks]),
        )
    oracle_seconds = time.perf_counter() - start

    timings = {}
    start = time.perf_counter()
    library = store.read("endmember_library").load()  # the one run btf passed
    calibrated = reconstruct(read["hdr"], read["bands"], calibration, image_sets, library)
    timings["reconstruct_calibrated_s"] = time.perf_counter() - start
    start = time.perf_counter()
    oracle = reconstruct(hdr_oracle, bands_oracle, oracle_cal, image_sets)
    timings["reconstruct_oracle_s"] = time.perf_counter() - start
    # before one C per image: every image through the paired camera's C, its RGB mapped by
    # the 3 x 3 map (the calibration group without camera_matrices), calibrated and oracle
    one_c = {}
    if "camera_matrices" in calibration:
        one_c = {
            "calibrated": reconstruct(
                read["hdr"], read["bands"], calibration.drop_vars("camera_matrices"), image_sets
            ),  # the library learnt through the paired camera's C, as the set nodes see it
            "oracle": reconstruct(
                hdr_oracle, bands_oracle, oracle_cal.drop_vars("camera_matrices"), image_sets
            ),
        }

    has = image_sets["has_bands"]
    result: dict = {"cameras": cameras, "paired_camera": cameras[paired], "spectra": {}}
    # where the cost is: the truth injected on one side only (band radiance; OECF and C,
    # which share their HDR units), the rest calibrated
    ablation = {
        "true band radiance": reconstruct(read["hdr"], bands_oracle, calibration, image_sets),
        "true OECF and C": reconstruct(hdr_oracle, read["bands"], oracle_cal, image_sets),
    }
    if base.LAB.get("falloff"):  # the measured flat fields replaced by the true falloff
        hdr_true, bands_true = true_flat_field_groups(base, store, rgb, raw, calibration, registration)
        hdr_true = hdr_true.assign_coords({c: read["hdr"][c] for c in read["hdr"].coords})
        ablation["true flat field"] = reconstruct(hdr_true, bands_true, calibration, image_sets)
    result["ablation"] = {}
    for variant, spectra in ablation.items():
        for k, name in enumerate(cameras):
            for flag in (True, False):
                labels = camera_images(has, rgb, k, flag)
                if labels:
                    e = errors(spectra, base, rgb, labels)
                    key = f"{name} {'with' if flag else 'without'} bands"
                    result["ablation"].setdefault(variant, {})[key] = {
                        "median": e["median"],
                        "p95": e["p95"],
                    }
    # the 3 x 3 maps onto the paired camera (true C) on the scene's own spectra
    scene = base.radiance(base.LED_THETA, base.LED_AZIMUTHS[0]).reshape(base.WAVELENGTHS.size, -1).T
    result["map_error_on_scene"] = {}
    for k, name in enumerate(cameras):
        if k == paired:
            continue
        mapped = scene @ c_true[k].T @ rgb_transform(c_true[k], c_true[paired], spectra_fit).T
        want = scene @ c_true[paired].T
        e = np.linalg.norm(mapped - want, axis=1) / np.linalg.norm(want, axis=1)
        result["map_error_on_scene"][name] = {
            "median": float(np.median(e)),
            "p95": float(np.percentile(e, 95)),
        }
    for k, name in enumerate(cameras):
        for flag in (True, False):
            labels = camera_images(has, rgb, k, flag)
            if not labels:
                continue
            cal, orc = errors(calibrated, base, rgb, labels), errors(oracle, base, rgb, labels)
            result["spectra"][f"{name} {'with' if flag else 'without'} bands"] = {
                "calibrated": cal,
                "oracle": orc,
                "ratio_median": cal["median"] / orc["median"],
                "ratio_p95": cal["p95"] / orc["p95"],
            }
    # the calibration's own errors
    model_of = {name: base.LAB["rgb_cameras"][name][2] for name in cameras}
    per_camera = {}
    for k, name in enumerate(cameras):
        entry = {"model": model_of[name]}
        if "camera_matrices" in calibration and k in calibration["camera"].values:
            sel = calibration.sel(camera=k)
            entry |= {
                "c_source": str(sel["c_source"].values),
                "c_error": c_error(sel["camera_matrices"].values, c_true[k]),
                "chart_cross_check_mean": float(sel["camera_mean_relative_error"]),
                "chart_cross_check_max": float(sel["camera_max_relative_error"]),
            }
        elif k == paired:
            entry |= {"c_error": c_error(calibration["camera_matrix"].values, c_true[k])}
        per_camera[name] = entry
    result["calibration"] = per_camera
    bands_cal = np.asarray(read["bands"]["radiance"].values, float)
    result["band_radiance"] = band_scale(bands_cal, np.asarray(registered.values, float), raw)
    no_table = calibrate_bands(
        raw,
        store.read("dark"),
        store.read("calibration/oecf_spectral"),
        calibration,
        registration,
        led_power=False,
    )["radiance"].values
    result["band_radiance_without_led_table"] = {
        k: v
        for k, v in band_scale(
            np.asarray(no_table, float), np.asarray(registered.values, float), raw
        ).items()
        if k in ("led_scale", "led_scale_spread")
    }
    # the second camera model's images (without bands) against the paired model's: with
    # one C per image (the chain), and with one C and the 3 x 3 map (before), side by side
    spectra = result["spectra"]
    paired_key = f"{cameras[paired]} without bands"
    for variant, spectra_of in one_c.items():
        per_key = {}
        for k, name in enumerate(cameras):
            labels = [
                int(v)
                for v in has["image"].values[~has.values.astype(bool)]
                if int(rgb["camera"].sel(image=int(v))) == k
            ]
            if labels:
                e = errors(spectra_of, base, rgb, labels)
                per_key[f"{name} without bands"] = {"median": e["median"], "p95": e["p95"]}
        result.setdefault("one_c_with_3x3_map", {})[variant] = per_key
    for name in cameras:
        key = f"{name} without bands"
        if model_of[name] != model_of[cameras[paired]] and key in spectra and paired_key in spectra:
            for variant, suffix in (("calibrated", ""), ("oracle", "_oracle")):
                result.setdefault(f"second_model_over_paired_model{suffix}", {})[name] = {
                    stat: spectra[key][variant][stat] / spectra[paired_key][variant][stat]
                    for stat in ("median", "p95")
                }
            for variant, per_key in result.get("one_c_with_3x3_map", {}).items():
                if key in per_key and paired_key in per_key:
                    result.setdefault("second_model_over_paired_model_one_c", {}).setdefault(
                        variant, {}
                    )[name] = {
                        stat: per_key[key][stat] / per_key[paired_key][stat]
                        for stat in ("median", "p95")
                    }
    if base.LAB.get("falloff"):
        result["flat_field"] = flat_field_error(base, calibration)
    result["white_level"] = white_level_error(base, store.read("calibration/oecf_rgb"), cameras)
    result["hdr_low_levels"] = low_level_error(read["hdr"], hdr_oracle, rgb, cameras)
    result["seconds"] = timings | {"oracle_groups_s": oracle_seconds}
    return result


def white_level_error(base, oecf: xr.Dataset, cameras: list[str]) -> dict:
    """Each RGB camera's white level as the calibration has it (``calibration/oecf_rgb``)
    against the writer's (the top code where its model has none)."""
    out = {}
    sources = oecf.attrs.get("white_level_source", [])
    for k, name in enumerate(cameras):
        true = int(base.LAB["models"][base.LAB["rgb_cameras"][name][2]].get("white", base.RGB_MAX))
        found = int(oecf["white_level"].sel(camera=k)) if "white_level" in oecf else base.RGB_MAX
        out[name] = {
            "true": true,
            "found": found,
            "source": sources[k] if k < len(sources) else "",
            "relative_error": abs(found - true) / true,
        }
    return out


def low_level_error(hdr: xr.Dataset, oracle: xr.Dataset, rgb: xr.Dataset, cameras: list[str]) -> dict:
    """The calibrated HDR radiance against the oracle's at the lowest levels, per camera.

    Per camera and channel, ``hdr / oracle`` per pixel (``BORDER`` px off) scaled by its median
    over the oracle's levels between the 25th and 75th percentile (the calibrated radiance's
    unit is the response's own); then the median ``|ratio - 1|`` of the pixels in each range
    of :data:`LOW_LEVELS` (quantiles of the oracle's radiance), the channels pooled.
    """
    inner = {"y": slice(BORDER, -BORDER), "x": slice(BORDER, -BORDER)}
    cal = np.asarray(hdr["radiance"].isel(inner).transpose("image", "y", "x", "channel").values, float)
    orc = np.asarray(
        oracle["radiance"].isel(inner).transpose("image", "y", "x", "channel").values, float
    )
    camera_of = np.asarray(rgb["camera"].values)
    out = {}
    for k, name in enumerate(cameras):
        pick = camera_of == k
        if not pick.any():
            continue
        per_range: dict[str, list[np.ndarray]] = {f"{lo:g}-{hi:g}": [] for lo, hi in LOW_LEVELS}
        for ch in range(cal.shape[-1]):
            c, o = cal[pick, ..., ch].ravel(), orc[pick, ..., ch].ravel()
            keep = np.isfinite(c) & np.isfinite(o) & (o > 0)
            c, o = c[keep], o[keep]
            q25, q75 = np.percentile(o, [25, 75])
            ratio = c / o / np.median((c / o)[(o >= q25) & (o <= q75)])
            for lo, hi in LOW_LEVELS:
                a, b = np.percentile(o, [100 * lo, 100 * hi])
                per_range[f"{lo:g}-{hi:g}"].append(np.abs(ratio[(o >= a) & (o <= b)] - 1))
        out[name] = {key: float(np.median(np.concatenate(v))) for key, v in per_range.items()}
    return out


def against_clean_split(results: dict, twins: dict) -> dict:
    """Per lab of ``twins`` and camera key, :func:`falloff_against_clean`'s ratio in two
    factors (median, p95): ``oracle``, the twin's oracle nRMSE over its clean twin's (what the
    capture itself costs with the truth's calibration), and ``calibration``, the twin's
    calibrated / oracle over the clean twin's (what the calibration costs); their product is
    the calibrated ratio."""
    out = {}
    for lab, twin in twins.items():
        if lab not in results or twin not in results:
            continue
        clean = results[twin]["spectra"]
        out[lab] = {
            key: {
                part: {
                    stat: value["oracle"][stat] / clean[key]["oracle"][stat]
                    if part == "oracle"
                    else (value["calibrated"][stat] / value["oracle"][stat])
                    / (clean[key]["calibrated"][stat] / clean[key]["oracle"][stat])
                    for stat in ("median", "p95")
                }
                for part in ("oracle", "calibration")
            }
            for key, value in results[lab]["spectra"].items()
            if key in clean
        }
    return out


def white_level_against_clean(results: dict) -> dict:
    """Per lab of :data:`WHITE_TWINS` and camera key: calibrated nRMSE (median, p95) over its
    twin's without the white level; the target is at most 1.1."""
    return falloff_against_clean(results, WHITE_TWINS)


def true_flat_field_groups(base, store, rgb, raw, calibration, registration):
    """``hdr`` and ``bands`` of the chain with the writer's falloff as the flat field (fitted
    noise-free: the polynomial's own error, under 0.1 %) in place of the measured one; Q and C
    as calibrated (through the measured flat field)."""
    from spectralize.nodes.calibration.band_radiance import calibrate_bands
    from spectralize.nodes.calibration.flat_field import FlatField, fit_flat_field, legendre_powers
    from spectralize.nodes.calibration.hdr import merge_hdr

    rgb_map = fit_flat_field(base.rgb_falloff()).coefficients
    cameras = np.asarray(sorted(set(int(c) for c in rgb["camera"].values)))
    frame = (base.HEIGHT, base.WIDTH)
    channels = rgb.sizes["channel"]
    flat = FlatField(
        np.broadcast_to(rgb_map, (len(cameras), channels, rgb_map.size)).copy(),
        legendre_powers(),
        frame,
        cameras,
    )
    hdr = merge_hdr(rgb, store.read("calibration/oecf_rgb"), flat_field=flat)
    hdr["radiance"] = hdr["radiance"].astype(np.float32)
    wavelengths = np.asarray(calibration["wavelength"].values, float)
    true_bands = np.stack(
        [fit_flat_field(base.mono_falloff(float(w))).coefficients for w in wavelengths]
    )
    with_true = calibration.copy()
    with_true["flat_field"] = (("wavelength", "flat_term"), true_bands)
    bands = calibrate_bands(
        raw, store.read("dark"), store.read("calibration/oecf_spectral"), with_true, registration
    )
    return hdr, bands


def flat_field_error(base, calibration: xr.Dataset) -> dict:
    """The recovered flat fields (``calibration/spectral``) against the writer's falloff:
    ``|F / F_true - 1|`` over the frame less ``BORDER`` px (max, p95) per RGB camera and
    channel and per band, and the same over the whole frame."""
    from spectralize.nodes.calibration.flat_field import from_calibration

    inner = (slice(BORDER, -BORDER), slice(BORDER, -BORDER))
    out: dict = {"rgb": {}, "spectral": {}}
    rgb = from_calibration(calibration, "rgb")
    cameras = list(base.LAB["rgb_cameras"])
    for row, k in enumerate(rgb.keys.tolist()):
        error = np.abs(rgb.maps([row])[0] / base.rgb_falloff()[..., None] - 1)
        out["rgb"][cameras[int(k)]] = {
            "max_inner": float(error[inner].max()),
            "p95_inner": float(np.percentile(error[inner], 95)),
            "max_frame": float(error.max()),
        }
    bands = from_calibration(calibration, "spectral")
    errors = np.stack(
        [
            np.abs(bands.maps([row])[0] / base.mono_falloff(float(w)) - 1)
            for row, w in enumerate(bands.keys.tolist())
        ]
    )
    out["spectral"] = {
        "max_inner": float(errors[:, inner[0], inner[1]].max()),
        "p95_inner": float(np.percentile(errors[:, inner[0], inner[1]], 95)),
        "max_frame": float(errors.max()),
        "worst_band_nm": float(bands.keys[int(errors[:, inner[0], inner[1]].max((1, 2)).argmax())]),
    }
    return out


def falloff_against_clean(results: dict, twins: dict | None = None) -> dict:
    """Per lab with falloff and camera key: calibrated nRMSE (median, p95) over its clean
    twin's (:data:`FALLOFF_TWINS`); the target is at most 1.1."""
    out = {}
    for lab, twin in (FALLOFF_TWINS if twins is None else twins).items():
        if lab not in results or twin not in results:
            continue
        out[lab] = {
            key: {
                stat: value["calibrated"][stat] / results[twin]["spectra"][key]["calibrated"][stat]
                for stat in ("median", "p95")
            }
            for key, value in results[lab]["spectra"].items()
            if key in results[twin]["spectra"]
        }
    return out


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the first lab only, results not saved")
    parser.add_argument(
        "--lab",
        action="append",
        choices=[name.split()[0] for name in LABS],
        help="only this lab (repeatable); its results replace that lab's in the saved file",
    )
    args = parser.parse_args(argv)
    start = time.perf_counter()
    labs = dict(list(LABS.items())[:1]) if args.quick else LABS
    if args.lab:
        labs = {name: value for name, value in LABS.items() if name.split()[0] in args.lab}
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for lab, (script, extra) in labs.items():
            root = Path(tmp) / lab.split()[0]
            subprocess.run(
                [sys.executable, str(SUPPORT / script), str(root / "capture"), *extra]
                + ["--truth", str(root / "truth.npz")],
                check=True,
                capture_output=True,
            )
            seconds = {
                "ingest_s": _cli("ingest", str(root / "capture"), str(root / "run.zarr"), cwd=root)
            }
            seconds["btf_s"] = _cli("run", "btf", str(root / "run.zarr"), cwd=root)
            results[lab] = measure_lab(root, lab)
            results[lab]["seconds"] |= seconds
            _print_lab(lab, results[lab])
            shutil.rmtree(root, ignore_errors=True)
    result = {
        "benchmark": "calibration_oracle",
        "setup": {
            "labs": {k: " ".join([v[0], *v[1]]) for k, v in LABS.items()},
            "held_out": "sigma-paired and its falloff and white-level twins: kept out of every "
            "choice of the calibration's settings (the low end of the RGB response was chosen on "
            "toe-camera)",
            "oracle": "true OECF and black offset per camera, true C per camera (and its maps onto "
            "the paired camera), true spectral response, dark pattern and QE, true LED powers; "
            "estimated registration in both",
            "endmember_library": "each reconstruction gets the run's library as run btf passes it: "
            "the calibrated one the store's, the oracle, ablation and one-C ones the library the "
            "endmember_library node (defaults) learns from their own groups",
            "one_c_with_3x3_map": "the same two reconstructions with one C (the paired camera's) "
            "for every image and each image's RGB mapped by the 3 x 3 map onto the paired camera "
            "(the chain before one C per image), images without bands",
            "nrmse": "per pixel |S - T| / |T| against the writer's radiance of the image "
            f"({BORDER} px border off); shape: the same after one scale per pixel",
            "c_error": "per channel RMS over wavelength of (s C - C_true) / max(C_true)",
            "targets": "calibrated / oracle <= 1.15 (median), <= 1.25 (p95) per camera with and "
            "without bands; C within 0.05; chart cross-check within 0.02 per patch; second model "
            "within 1.25x of the paired model without bands; no band biased > 10 %; a lab with lens "
            "falloff within 1.1x of its clean twin (median and p95, every camera), its recovered "
            "flat field within 1 % of the true falloff away from the border; a lab whose RGB "
            "cameras clip at an undeclared white level within 1.1x of its twin without it "
            "(median and p95, every camera), the white level found within 1 % of the true one",
        },
        "machine": {
            "python": platform.python_version(),
            "cpu_count": os.cpu_count(),
            "numpy": np.__version__,
            "platform": platform.platform(),
        },
        "labs": results,
        "seconds_total": time.perf_counter() - start,
    }
    if args.lab and RESULTS.exists():  # the other labs' results of the last full run kept
        saved = json.loads(RESULTS.read_text())
        result["labs"] = saved.get("labs", {}) | results
        result["seconds_total"] = {
            "last_full_run": (saved.get("seconds_total") or {}).get("last_full_run")
            if isinstance(saved.get("seconds_total"), dict)
            else saved.get("seconds_total"),
            "these_labs": result["seconds_total"],
        }
    result["falloff_against_clean"] = falloff_against_clean(result["labs"])
    print("falloff / clean (calibrated nRMSE):", json.dumps(result["falloff_against_clean"]))
    result["white_level_against_clean"] = white_level_against_clean(result["labs"])
    print("white level / clean (calibrated nRMSE):", json.dumps(result["white_level_against_clean"]))
    for name, twins in (("falloff", FALLOFF_TWINS), ("white_level", WHITE_TWINS)):
        result[f"{name}_against_clean_split"] = against_clean_split(result["labs"], twins)
    if not args.quick:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(json.dumps(result, indent=2) + "\n")
    return result


def _print_lab(lab: str, result: dict) -> None:
    print(f"== {lab}")
    for key, value in result["spectra"].items():
        cal, orc = value["calibrated"], value["oracle"]
        print(
            f"  {key:28s} calibrated {cal['median']:.3f} / {cal['p95']:.3f} "
            f"(<0.03: {cal['share_below_0.03']:.0%})  oracle {orc['median']:.3f} / {orc['p95']:.3f}  "
            f"ratio {value['ratio_median']:.2f} / {value['ratio_p95']:.2f}"
        )
    for name, entry in result["calibration"].items():
        print(f"  {name}: {entry}")
    for name, entry in result.get("white_level", {}).items():
        print(f"  {name} white level: {entry}")
    for name, entry in result.get("hdr_low_levels", {}).items():
        print(f"  {name} HDR radiance error at the lowest levels (oracle quantiles): {entry}")
    print(
        "  bands:", {k: v for k, v in result["band_radiance"].items() if k != "band_ratio_by_wavelength"}
    )
    print("  without LED table:", result["band_radiance_without_led_table"])
    print(
        "  second model (calibrated, oracle; one C + 3x3 map):",
        result.get("second_model_over_paired_model"),
        result.get("second_model_over_paired_model_oracle"),
        result.get("second_model_over_paired_model_one_c"),
    )
    print("  ablation:", json.dumps(result["ablation"]))
    print("  3x3 map on the scene:", result["map_error_on_scene"], flush=True)
    if "flat_field" in result:
        print("  flat field against the true falloff:", json.dumps(result["flat_field"]), flush=True)


if __name__ == "__main__":
    main()
