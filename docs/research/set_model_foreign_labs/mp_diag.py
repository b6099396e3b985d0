"""material-pooled variants on nikon-paired's oracle groups (HEAD): the api's refine patched.
python mp_diag.py ROOT VARIANT... ; VARIANT: name=json kwargs for material_pooled_refine,
special key "true_labels": true -> the writer's material map at pixel centres."""
import json
import sys
import time

import numpy as np

sys.argv = [sys.argv[0], sys.argv[1], "/work/main/benchmarks"] + sys.argv[2:]
variants = [a for a in sys.argv[3:]]
sys.argv = sys.argv[:3]
exec(open("/work/notes/H/oracle_variants.py").read())  # builds groups, runs nothing (no variants)

import spectralize.nodes.reconstruction.api as api  # noqa: E402
from spectralize.nodes.reconstruction.estimators import material_pooled as mpm  # noqa: E402

orig = mpm.material_pooled_refine
yy, xx = np.meshgrid(np.arange(base.HEIGHT, dtype=float), np.arange(base.WIDTH, dtype=float), indexing="ij")
true_labels = base.material_at(yy, xx).astype(np.int64)
log = []
orig_clusters = mpm.material_clusters


def make(kw):
    kw = dict(kw)
    use_true = kw.pop("true_labels", False)
    light = kw.pop("light", None)
    sigma_scale = kw.pop("sigma_scale", None)
    rgb_sigma = kw.pop("rgb_sigma", None)

    def refine(inputs, initial, highlight, **k):
        k = {**k, **kw}
        if use_true:
            k["labels"] = true_labels
        if light == "delta720":
            highlight = np.zeros_like(highlight); highlight[-1] = 1.0
        elif light == "flat":
            highlight = np.ones_like(highlight)
        elif light == "true":
            highlight = base.illuminant(base.WAVELENGTHS)
        if sigma_scale:
            from spectralize.nodes.reconstruction.estimators.endmember_mixture import band_noise_sigma
            k["band_sigma"] = sigma_scale * band_noise_sigma(inputs)
        from spectralize.nodes.reconstruction.estimators import shared_texel as st
        keep = st.RGB_RELATIVE_SIGMA
        if rgb_sigma:
            st.RGB_RELATIVE_SIGMA = rgb_sigma
        try:
            out = orig(inputs, initial, highlight, **k)
        finally:
            st.RGB_RELATIVE_SIGMA = keep
        log.append((inputs.cube_shape, float(np.linalg.norm(out - initial) / np.linalg.norm(initial))))
        return out

    return refine


def clusters_spy(shapes, clusters, features, seed):
    lab = orig_clusters(shapes, clusters, features, seed)
    print("   clusters used:", len(np.unique(lab)), "of", clusters, flush=True)
    return lab


mpm.material_clusters = clusters_spy
for arg in variants:
    name, kw = arg.split("=", 1)
    api.material_pooled_refine = make(json.loads(kw))
    log.clear()
    t = time.perf_counter()
    spectra = run({}, (hdr_oracle, bands_oracle, oracle_cal))
    row = {}
    for k, cam in enumerate(cameras):
        labels = c.camera_images(has, rgb, k, False)
        e = c.errors(spectra, base, rgb, labels)
        row[cam] = (round(e["median"], 4), round(e["p95"], 4), round(e["shape_median"], 4))
    e = c.errors(spectra, base, rgb, c.camera_images(has, rgb, 1, False))
    print(f"{name:14s} {time.perf_counter() - t:5.1f}s", json.dumps(row), "refine calls (shape, |S-S0|/|S0|):", log, flush=True)
    print("   cam-45 band_bias", e["band_bias"], flush=True)
api.material_pooled_refine = orig
spectra = run({"set_model": "independent"}, (hdr_oracle, bands_oracle, oracle_cal))
e = c.errors(spectra, base, rgb, c.camera_images(has, rgb, 1, False))
print("independent cam-45", round(e["median"], 4), "band_bias", e["band_bias"], flush=True)
