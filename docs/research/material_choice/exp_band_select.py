"""Helper F (issue 38): per texel, the choice or the default by the evidence of the set's band
shots. For each texel the chi^2 of each estimate's spectra against the texel's band shots
(every shot of the set, sigma_i from band_noise_sigma) is summed; the weight of the choice is
w = w0 * [chi_choice < chi_default] (hard) or a blend w0 everywhere (w0 = 0.25, the benchmark's
blend), with the run library of sets 1..8 for both. Set 0 (20 x 48^2, seed 0). Tuning scenes
first, dark-still-life held out.
"""
import sys
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "run_library"))
warnings.simplefilter("ignore")
from refine import pooled_inputs  # noqa: E402
from runlib import default, score, simulate  # noqa: E402

from spectralize.nodes.reconstruction import inputs_from_xarray  # noqa: E402
from spectralize.nodes.reconstruction.estimators.endmember_mixture import band_noise_sigma, set_endmembers  # noqa: E402
import spectralize.nodes.reconstruction.estimators.sparse_choice  # noqa: E402,F401

sc = sys.modules["spectralize.nodes.reconstruction.estimators.sparse_choice"]


def band_chi2(cube, inputs, sigma):
    """(texels,) chi^2 of cube (image, wavelength, y, x) against every band shot."""
    out = np.zeros(inputs.height * inputs.width)
    for i, (b, m) in enumerate(zip(inputs.band, inputs.image)):
        out += ((cube[m, b].ravel() - inputs.band_data[i].ravel()) ** 2) / sigma[i] ** 2
    return out


for name in sys.argv[1].split(","):
    sets = [simulate(name, 48, k) for k in range(9)]
    held = sets[0]
    lib = set_endmembers(pooled_inputs(sets[1:9]))
    inputs = inputs_from_xarray(held["rgb"], held["bands"], held["C"], illuminant=held["led"])
    base, _ = default(held, lib)
    b = base.transpose("image", "wavelength", "y", "x").values.astype(np.float64)
    c = np.moveaxis(sc.sparse_choice(inputs, endmembers=lib), 0, 1)
    sigma = band_noise_sigma(inputs)
    chi_b, chi_c = band_chi2(b, inputs, sigma), band_chi2(c, inputs, sigma)
    better = (chi_c < chi_b).reshape(48, 48)
    print(f"{name}: choice fits the shots better at {100 * better.mean():.1f}% of texels", flush=True)
    for label, w in (("blend 0.25", np.full((48, 48), 0.25)), ("hard select", better * 1.0),
                     ("0.25 where better", better * 0.25), ("0.5 where better", better * 0.5),
                     ("0.5 better / 0.1 else", np.where(better, 0.5, 0.1))):
        est = w[None, None] * c + (1 - w[None, None]) * b
        s = score(held["truth"].copy(data=est.astype(np.float32)), held["truth"])
        print(f"{name:16s} {label:22s} med {s['median']:.4f} p95 {s['p95']:.3f} <.03 {100 * s['frac<0.03']:.1f}%", flush=True)
