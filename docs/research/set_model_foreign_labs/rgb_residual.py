"""The oracle HDR's RGB against C_true S_true per camera (inner frame): what the set model's
RGB_RELATIVE_SIGMA (0.5 % of the image's mean RGB) assumes of it. LAB=... python rgb_residual.py ROOT"""
import sys

import numpy as np

sys.argv = [sys.argv[0], sys.argv[1], "/work/main/benchmarks"]
exec(open("/work/notes/H/oracle_variants.py").read())
hdr = hdr_oracle["radiance"].transpose("image", "y", "x", "channel").values
for k, cam in enumerate(cameras):
    rel, rel_mean = [], []
    for lab_ in [int(v) for v in rgb["image"].values if int(rgb["camera"].sel(image=int(v))) == k]:
        t = c.truth_radiance(base, rgb, lab_)[3:-3, 3:-3]  # y, x, w
        pred = t @ c_true[k].T
        got = hdr[list(hdr_oracle["image"].values).index(lab_)][3:-3, 3:-3]
        rel.append(np.linalg.norm(pred - got, axis=-1) / np.linalg.norm(pred, axis=-1))
        rel_mean.append(np.abs(pred - got) / np.abs(pred).reshape(-1, 3).mean(0))  # per channel, / image mean
    rel, rel_mean = np.concatenate([r.ravel() for r in rel]), np.concatenate([r.reshape(-1, 3) for r in rel_mean])
    print(f"{lab} {cam} ({base.LAB['rgb_cameras'][cam][2]}): |C S_true - R| / |R| median {np.median(rel):.4f} p95 {np.percentile(rel, 95):.4f};"
          f" per channel |err| / image-mean RGB median {np.round(np.median(rel_mean, 0), 4).tolist()} p95 {np.round(np.percentile(rel_mean, 95, axis=0), 4).tolist()}")
