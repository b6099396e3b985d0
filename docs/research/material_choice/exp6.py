"""Final side by side: default, present oracle, sparse choice (true atoms = library ceiling),
sparse choice + 2 dictionary rounds on the default's library (the best without oracles);
nRMSE and CIEDE2000 under A, FL11, D65 (reflectance S / LED relit); cost on one thread."""
import json, time, warnings
import numpy as np
from harness import load_case, score, fmt, SCENE_NAMES, project_rgb, oracle_present, nrmse, stats
import choice as ch

warnings.simplefilter("ignore")
import colour

me, pen, ncand = 0.03, 30, 6


def lab_under(spectra, case, ill_name, norm=None):
    wl = case["wl"]
    shape = colour.SpectralShape(float(wl[0]), float(wl[-1]), float(wl[1] - wl[0]))
    cmf = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape).values
    ill = colour.SDS_ILLUMINANTS[ill_name].copy().align(shape).values
    refl = spectra / np.maximum(case["led"], 1e-6 * case["led"].max())
    xyz = (refl * ill) @ cmf
    white = ill @ cmf
    if norm is None:  # per image: the truth's 99th-percentile Y is white
        norm = np.percentile(xyz[..., 1], 99, axis=1) / white[1]
    xyz = xyz / norm[:, None, None]
    return colour.XYZ_to_Lab(xyz, colour.XYZ_to_xy(white)), norm


def de_stats(est, case):
    out = {}
    for ill in ("A", "FL11", "D65"):
        lt, norm = lab_under(case["truth"], case, ill)
        le, _ = lab_under(est, case, ill, norm)
        de = colour.delta_E(lt, le, method="CIE 2000")
        out[ill] = (round(float(np.median(de)), 2), round(float(np.percentile(de, 95)), 2))
    return out


def sparse(case, atoms, rounds=0):
    for r in range(rounds + 1):
        cand = ch.dichromatic_candidates(case, atoms, ncand, model_error=me)
        rc, bc, subs = ch.subset_costs(case, atoms, cand, model_error=me, band_model_error=0.1)
        sup = ch.support_of(cand, subs, ch.choose(rc + bc, subs, pen))
        if r < rounds:
            atoms = ch.update_atoms(case, atoms, sup)
    return project_rgb(ch.spectra(case, atoms, sup), case["rgb"], case["C"])


rows = {}
for name in SCENE_NAMES:
    c = load_case(name, 48)
    learnt = c["learnt"].copy(); learnt[-1] = c["led"] * (learnt[-1] @ c["led"]) / (c["led"] @ c["led"])
    ests = {
        "present": project_rgb(oracle_present(c), c["rgb"], c["C"]),
        "default": c["default"],
        "sparse, true atoms": sparse(c, c["atoms"]),
        "sparse+2 dict rounds, default library": sparse(c, learnt, rounds=2),
    }
    rows[name] = {}
    for k, e in ests.items():
        s = stats(nrmse(e, c["truth"])); d = de_stats(e, c)
        rows[name][k] = {"nrmse": s, "de2000": d}
        print(f"{name:16s} {k:38s} {fmt(s)}  dE00 med/p95 A {d['A']} FL11 {d['FL11']} D65 {d['D65']}", flush=True)

# cost, one thread, side by side in one process (glossy, 20 x 48^2)
from harness import simulate
from spectralize.nodes.reconstruction import reconstruct
cap = simulate("glossy-mosaic", 48, 0)
c = load_case("glossy-mosaic", 48)
t0 = time.process_time(); reconstruct(cap.rgb, cap.bands, cap.camera_matrix, illuminant=c["led"]); t_def = time.process_time() - t0
learnt = c["learnt"].copy(); learnt[-1] = c["led"]
t0 = time.process_time(); sparse(c, learnt, rounds=0); t_sp0 = time.process_time() - t0
t0 = time.process_time(); sparse(c, learnt, rounds=2); t_sp2 = time.process_time() - t0
mpx = 20 * 48 * 48 / 1e6
cost = {"default_cpu_s_per_mpx_image": round(t_def / mpx, 1), "sparse_choice_cpu_s_per_mpx_image": round(t_sp0 / mpx, 1),
        "sparse+2rounds_cpu_s_per_mpx_image": round(t_sp2 / mpx, 1)}
print(cost)
json.dump({"rows": rows, "cost": cost}, open("results_exp6.json", "w"), indent=1)
