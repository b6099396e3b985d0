"""Where the default's evidence blend moves a lab's spectra: python evidence_blend_diag.py ROOT
LAB GROUPS [CAMERA...]

GROUPS: 'oracle' or 'cal' (as evidence_blend_labs.py builds them, with the run's library).
Runs the default (set model 'evidence-blend') with the set step recorded: per set the pooled
refit ``a``, the material choice ``b`` (sparse_choice with the run's library, as
material_choice_blend makes it), the posterior log-odds ``Lambda - c`` (own shots and the
appearance bin's pooled part apart) and the blended result. Per camera (with / without
bands; CAMERA filters, e.g. 'cam-45 without'), over the images each set owns and the inner
frame: nRMSE of ``a`` and of the blend (median, p95), the texels by weight ``1 - pi`` of the
choice, and per true material (truth.npz beside ROOT's run.zarr; pixels whose 3 x 3
neighbourhood holds one material) the choice's and the default's nRMSE and the mean weight;
the library's quality: per true material the angle [degree] of its true radiance shape
(reflectance x illuminant) to the nearest library atom and to the best nonnegative pair.
"""

import sys
from pathlib import Path

import numpy as np
from scipy.optimize import nnls

sys.path.insert(0, str(Path(__file__).resolve().parent))
import evidence_blend_labs as labs  # noqa: E402

import spectralize.nodes.reconstruction.api as api  # noqa: E402
from spectralize.nodes.reconstruction.estimators import evidence_blend as eb  # noqa: E402
from spectralize.nodes.reconstruction.estimators.sparse_choice import sparse_choice  # noqa: E402
from spectralize.nodes.reconstruction.set_reconstruction import _prepared, set_members  # noqa: E402

c = labs.c
ROOT, GROUPS, CAMERAS = Path(sys.argv[1]), sys.argv[3], sys.argv[4:]
lab = labs.load(ROOT, sys.argv[2])
base, rgb, image_sets, cameras = lab.base, lab.rgb, lab.image_sets, lab.cameras
records = []
original = api.material_choice_blend


def recorded(inputs, cube, endmembers, **kw):
    a = np.array(cube, dtype=np.float64)
    choice = sparse_choice(inputs, endmembers=endmembers, candidates=eb.CHOICE_CANDIDATES)
    log_odds = eb.choice_log_odds(inputs, a, choice)
    out = original(inputs, cube, endmembers, **kw)
    weight = 1.0 - 1.0 / (1.0 + np.exp(np.clip(log_odds, -50, 50)))
    check = a + weight * (choice - a)
    records.append(
        {
            "rgb": np.array(inputs.rgb),
            "a": a,
            "b": choice,
            "out": np.array(out, dtype=np.float64),
            "log_odds": log_odds,
            "weight": weight,
            "same": float(np.abs(check - out).max() / np.abs(out).max()),
        }
    )
    return out


api.material_choice_blend = recorded
groups, library = (
    (lab.oracle, lab.oracle_library) if GROUPS == "oracle" else (lab.calibrated, lab.store_library)
)
labs.run(lab, {}, groups, library)
_, pooled_run = labs.run(lab, {"set_model": "material-pooled"}, groups, library)
print(f"{len(records)} set steps recorded; blend reproduced to {max(r['same'] for r in records):.1e}")

# each record's images: the labels whose RGB it holds (as the set's inputs carry it)
hdr_rgb = _prepared(*groups)[0]["radiance"].transpose("image", "y", "x", "channel")
labels_all = [int(v) for v in hdr_rgb["image"].values]
hdr_values = np.asarray(hdr_rgb.values, np.float64)
owner = {}
for k in range(image_sets.sizes["set"]):
    members, owned = set_members(image_sets, k)
    for label in np.asarray(members)[np.asarray(owned, bool)]:
        owner[int(label)] = sorted(int(v) for v in members)
for r in records:
    r["labels"] = []
    for m in range(r["rgb"].shape[0]):
        d = [np.abs(hdr_values[i] - r["rgb"][m]).mean() for i in range(len(labels_all))]
        r["labels"].append(labels_all[int(np.argmin(d))])
truth = np.load(ROOT / "truth.npz")
material = truth["material"]
pure = np.ones(material.shape, bool)
for dy in (-1, 0, 1):
    for dx in (-1, 0, 1):
        pure &= np.roll(np.roll(material, dy, 0), dx, 1) == material
inner = (slice(c.BORDER, -c.BORDER), slice(c.BORDER, -c.BORDER))


def nrmse(got, true):
    return np.linalg.norm(got - true, axis=0) / np.linalg.norm(true, axis=0)


def report(camera_key, labels):
    err = {"a": [], "out": [], "b": []}
    weights, mats, purity, odds = [], [], [], []
    for label in labels:
        r = next(r for r in records if sorted(r["labels"]) == owner[label])
        m = r["labels"].index(label)
        true = np.moveaxis(c.truth_radiance(base, rgb, label), -1, 0)  # (wl, y, x)
        for key in err:
            err[key].append(nrmse(r[key][:, m], true)[inner].ravel())
        weights.append(r["weight"][inner].ravel())
        odds.append(r["log_odds"][inner].ravel())
        mats.append(material[inner].ravel())
        purity.append(pure[inner].ravel())
    e = {k: np.concatenate(v) for k, v in err.items()}
    w, mat, p, lo = map(np.concatenate, (weights, mats, purity, odds))
    print(f"\n== {camera_key}: {len(labels)} images, {e['a'].size} pixels")
    for k in ("a", "out", "b"):
        print(f"  {k:4s} median {np.median(e[k]):.4f} p95 {np.percentile(e[k], 95):.4f}")
    print(
        f"  weight of the choice: mean {w.mean():.3f}; share > 0.5 {np.mean(w > 0.5):.3f}; > 0.05 "
        f"{np.mean(w > 0.05):.3f}; log-odds quantiles 5/50/95 "
        f"{np.percentile(lo, 5):.1f} / {np.median(lo):.1f} / {np.percentile(lo, 95):.1f}"
    )
    for lo_w, hi_w in ((0.0, 0.05), (0.05, 0.5), (0.5, 1.01)):
        s = (w >= lo_w) & (w < hi_w)
        if s.any():
            print(
                f"  weight [{lo_w}, {hi_w}): {s.mean():.3f} of pixels; a {np.median(e['a'][s]):.4f} "
                f"-> blend {np.median(e['out'][s]):.4f} (choice {np.median(e['b'][s]):.4f}); "
                f"blend worse on {np.mean(e['out'][s] > e['a'][s] * 1.02):.2f}, better on "
                f"{np.mean(e['out'][s] < e['a'][s] / 1.02):.2f}"
            )
    # the tail: pixels over the blend's p95 and over a's p95
    for key in ("a", "out"):
        tail = e[key] > np.percentile(e[key], 95)
        print(
            f"  {key}'s p95 tail: materials {np.bincount(mat[tail], minlength=6).tolist()}, "
            f"mean weight {w[tail].mean():.3f}, pure {p[tail].mean():.2f}"
        )
    print("  per material (pure pixels): n, a, blend, choice medians, mean weight, share w>0.5")
    for k in range(int(material.max()) + 1):
        s = (mat == k) & p
        if s.any():
            print(
                f"   {k}: {s.sum():5d} {np.median(e['a'][s]):.4f} {np.median(e['out'][s]):.4f} "
                f"{np.median(e['b'][s]):.4f} {w[s].mean():.3f} {np.mean(w[s] > 0.5):.3f}"
            )
    s = ~p
    print(
        f"   mixed: {s.sum():5d} {np.median(e['a'][s]):.4f} {np.median(e['out'][s]):.4f} "
        f"{np.median(e['b'][s]):.4f} {w[s].mean():.3f} {np.mean(w[s] > 0.5):.3f}"
    )


def library_quality(lib, name):
    wl = np.asarray(lib["wavelength"].values, float)
    atoms = np.asarray(lib["atoms"].transpose("endmember", "wavelength").values, float)
    reflect = truth["reflectance"]
    light = base.illuminant(wl)
    unit = atoms / np.linalg.norm(atoms, axis=1, keepdims=True)
    out = []
    for k in range(reflect.shape[0]):
        shape = np.interp(wl, truth["wavelength"], reflect[k]) * light
        shape /= np.linalg.norm(shape)
        one = np.degrees(np.arccos(np.clip(unit @ shape, -1, 1))).min()
        best = 90.0
        for i in range(len(atoms)):
            for j in range(i + 1, len(atoms)):
                x, res = nnls(np.stack([unit[i], unit[j]], 1), shape)
                fit = np.stack([unit[i], unit[j]], 1) @ x
                best = min(
                    best, np.degrees(np.arccos(np.clip(fit @ shape / np.linalg.norm(fit), -1, 1)))
                )
        out.append(f"{k}: {one:.1f} / {best:.1f}")
    print(
        f"library ({name}, {len(atoms)} atoms): per material nearest atom / best pair [degree]: "
        + ", ".join(out)
    )


library_quality(library, GROUPS)
print("per set, owned images, all cameras: median / p95 of the material-pooled run, the default's")
print("pooled refit a (before its blend) and the default's blend")
for k in range(image_sets.sizes["set"]):
    members, owned = set_members(image_sets, k)
    mine = [int(v) for v in np.asarray(members)[np.asarray(owned, bool)]]
    r = next(r for r in records if sorted(r["labels"]) == sorted(int(v) for v in members))
    got = {"pooled run": [], "a": [], "blend": []}
    for label in mine:
        true = np.moveaxis(c.truth_radiance(base, rgb, label), -1, 0)
        m = r["labels"].index(label)
        run_cube = pooled_run.sel(image=label).transpose("wavelength", "y", "x").values
        for key, cube in (("pooled run", run_cube), ("a", r["a"][:, m]), ("blend", r["out"][:, m])):
            got[key].append(nrmse(cube, true)[inner].ravel())
    print(
        f"  set {k} ({len(mine)} owned):",
        "; ".join(
            f"{key} {np.median(np.concatenate(v)):.4f} / {np.percentile(np.concatenate(v), 95):.4f}"
            for key, v in got.items()
        ),
    )
has = image_sets["has_bands"]
for k, cam in enumerate(cameras):
    for flag in (True, False):
        key = f"{cam} {'with' if flag else 'without'}"
        labels = c.camera_images(has, rgb, k, flag)
        if labels and (not CAMERAS or key in CAMERAS):
            report(key, labels)
