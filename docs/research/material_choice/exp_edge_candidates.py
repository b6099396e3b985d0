"""Helper F (issue 38): candidates from dichromatic costs pooled over RGB-similar neighbours.

The candidate step ranks each atom by its dichromatic chi^2 summed over the set's images. Here
that cost (one per atom: a label space shared by all texels) is also summed over the texel's
3 x 3 neighbours, weighted by the similarity of their stacked per-image chromaticity
(exp(-d^2 / h^2), h the median neighbour distance; RGB edges cut the pooling). Then the same
supports, costs and choice as sparse_choice. Set 0 (20 x 48^2, seed 0), run library of sets
1..8. Tuning scenes first; dark-still-life held out.
"""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "run_library"))
warnings.simplefilter("ignore")
from refine import pooled_inputs  # noqa: E402
from runlib import score, simulate  # noqa: E402

from spectralize.nodes.reconstruction import inputs_from_xarray  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import (  # noqa: E402
    Endmembers,
    _project,
    rgb_abundances,
    set_endmembers,
)
import spectralize.nodes.reconstruction.estimators.sparse_choice  # noqa: E402,F401

sc = sys.modules["spectralize.nodes.reconstruction.estimators.sparse_choice"]


def dichromatic_cost(atoms_rgb, rgb, variance):
    n_atoms = atoms_rgb.shape[1]
    cost = np.zeros((n_atoms - 1, rgb.shape[1]))
    for m in range(rgb.shape[0]):
        light = atoms_rgb[m, -1]; r = rgb[m]
        one = np.maximum(r @ light / (light @ light), 0.0); lo = ((r - one[:, None] * light) ** 2).sum(-1)
        for j in range(n_atoms - 1):
            e = atoms_rgb[m, j]; pair = np.stack([e, light]); g = pair @ pair.T
            g += (1e-12 * np.trace(g) + 1e-300) * np.eye(2)
            w = (r @ pair.T) @ np.linalg.inv(g); both = ((r - w @ pair) ** 2).sum(-1)
            a = np.maximum(r @ e / max(e @ e, 1e-300), 0); mo = ((r - a[:, None] * e) ** 2).sum(-1)
            cost[j] += np.where((w >= 0).all(-1), both, np.minimum(mo, lo)) / variance[m]
    return cost


def pooled_cost(cost, rgb, size, strength):
    scale = np.abs(rgb.reshape(-1, 3).mean(0)); bal = rgb / scale; b = bal.sum(-1, keepdims=True)
    f = np.moveaxis(bal[..., :2] / np.maximum(b, 1e-9 * b.mean()), 0, 1).reshape(size, size, -1)
    c = cost.reshape(-1, size, size)
    out = c.copy(); wsum = np.ones((size, size)); dists = []
    shifts = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]
    for dy, dx in shifts:
        g = np.roll(f, (dy, dx), (0, 1)); dists.append(((f - g) ** 2).sum(-1))
    h2 = np.median(np.stack(dists)) + 1e-30
    for (dy, dx), d in zip(shifts, dists):
        w = strength * np.exp(-d / h2)
        valid = np.ones((size, size), bool)
        if dy == 1: valid[0] = False
        if dy == -1: valid[-1] = False
        if dx == 1: valid[:, 0] = False
        if dx == -1: valid[:, -1] = False
        w = w * valid
        out += w[None] * np.roll(c, (dy, dx), (1, 2)); wsum += w
    return (out / wsum[None]).reshape(cost.shape[0], -1)


def choice_with(inputs, lib, strength):
    atoms = sc._library(inputs, lib)
    rgb = inputs.rgb.reshape(inputs.n_image, -1, 3).astype(np.float64)
    cams = sc._cameras(inputs)
    atoms_rgb = np.einsum("aw,mcw->mac", atoms, cams)
    cost = dichromatic_cost(atoms_rgb, rgb, sc._rgb_variance(rgb, 0.03))
    if strength:
        cost = pooled_cost(cost, rgb, inputs.height, strength)
    near = np.argsort(cost, axis=0, kind="stable")[:6].T
    near = np.hstack([near, np.full((near.shape[0], 1), atoms.shape[0] - 1)])
    total, subsets = sc.support_costs(inputs, atoms, near)
    size = np.array([len(s) for s in subsets], dtype=np.float64)
    support = sc._chosen_support(near, subsets, np.argmin(total + 30.0 * size[:, None], 0), 3)
    library = Endmembers(atoms, np.zeros((atoms.shape[0] - 1, 2)), np.ones(3))
    per = np.tile(support, (inputs.n_image, 1))
    w = rgb_abundances(library, per, inputs.camera_matrix, rgb.reshape(-1, 3))
    from spectralize.nodes.reconstruction.kernels import mix_atoms
    cube = np.empty((inputs.n_wavelength, per.shape[0]))
    mix_atoms(w, per, np.ascontiguousarray(atoms), cube)
    return _project(cube.reshape(inputs.cube_shape), inputs)


for name in sys.argv[1].split(","):
    sets = [simulate(name, 48, k) for k in range(9)]
    held = sets[0]
    lib = set_endmembers(pooled_inputs(sets[1:9]))
    inputs = inputs_from_xarray(held["rgb"], held["bands"], held["C"], illuminant=held["led"])
    for strength in (0.0, 0.5, 1.0):
        cube = choice_with(inputs, lib, strength)
        s = score(held["truth"].copy(data=np.moveaxis(cube, 0, 1).astype(np.float32)), held["truth"])
        print(f"{name:16s} pooled candidates, strength {strength}: med {s['median']:.4f} p95 {s['p95']:.3f} "
              f"<.03 {100 * s['frac<0.03']:.1f}%", flush=True)
