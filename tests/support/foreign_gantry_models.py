"""A harder foreign gantry: RGB cameras of two real sensor models (issue 25, item 5).

The gantry of ``foreign_gantry.py`` (its folders, files, manifest, spectral camera, dark
frames with hot pixels, misregistration and exposure plan) with what makes another lab's
calibration hard, each from published data rather than from this project's simulator:

- three RGB cameras of two models with measured sensitivities (colour-science's
  ``Nikon 5100 (NPL)`` and ``Sigma SDMerill (NPL)``, zero where they were not measured), each
  model with its own S-shaped response and black offset (60 and 48 DN);
- a white LED with a sharp blue peak that leaves the 410 nm band below 1 % of its maximum;
- a 2 % spread of LED power (the LEDs of the band shots differ from those of the RGB images
  they pair with);
- a textured sample of six reflectances from colour-science's collections (CIE 1995 test
  colour samples or NIST CQS samples), and the ColorChecker as the chart.

Two labs: ``nikon-paired`` (the paired camera and one more are Nikon, one Sigma) and
``sigma-paired`` (the paired camera is Sigma, with other samples and another LED), which is
kept out of every choice of the calibration's settings and reported on its own; and
``sigma-paired-falloff``, the same capture through lenses that lose light towards the corners
(:data:`FALLOFF`, ``foreign_gantry.lens_falloff``), held out as well, beside its clean twin,
and ``gaussian-falloff``, ``foreign_gantry``'s own lab through the same lenses;
``sigma-paired-white``, the same capture again with every RGB camera clipping at a white level
under the top code (:data:`WHITE_LEVEL`) that capture.toml does not declare, held out as well;
and ``toe-camera``, ``nikon-paired`` with its Sigma camera replaced by a consumer camera of the
same sensitivity whose response has a strong toe (:func:`toe_curve`).

Usage: ``python foreign_gantry_models.py OUT --lab nikon-paired [--truth truth.npz]``.
Deterministic. It imports numpy, tifffile and colour-science, never spectralize.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import colour
import numpy as np
from colour.quality.datasets import SDS_TCS, SDS_VS

try:  # imported as tests/support's module or run as a script beside foreign_gantry.py
    from support import foreign_gantry as base
except ImportError:
    import foreign_gantry as base

NIKON, SIGMA = "Nikon 5100 (NPL)", "Sigma SDMerill (NPL)"


def measured_sensitivity(name: str):
    """(3, wavelength) R, G, B of a measured camera, peak 1, zero outside its measured range."""
    msds = colour.MSDS_CAMERA_SENSITIVITIES[name]

    def sensitivity(wl: np.ndarray) -> np.ndarray:
        values = np.stack(
            [np.interp(wl, msds.wavelengths, msds.values[:, k], left=0.0, right=0.0) for k in range(3)]
        )
        full = np.clip(msds.values, 0.0, None).max()
        return np.clip(values, 0.0, None) / full

    return sensitivity


def s_curve(exponent: float, knee: float):
    """An S-shaped response: a toe ``y ** exponent``, a shoulder towards ``1 + knee ** exponent``;
    1 at full scale."""

    def response(y: np.ndarray) -> np.ndarray:
        p = np.power(y, exponent)
        return p / (p + knee**exponent) * (1.0 + knee**exponent)

    return response


def toe_curve(toe: float, knee: float):
    """A consumer camera's response with a strong toe: ``h(y) = sqrt(y^2 + toe^2) - toe``
    rises as ``y^2 / (2 toe)`` just above black, then steeper, almost linearly (``y - toe``),
    through a shoulder ``p / (p + knee) (1 + knee)``; 1 at full scale."""

    def response(y: np.ndarray) -> np.ndarray:
        p = (np.sqrt(y * y + toe * toe) - toe) / (np.sqrt(1.0 + toe * toe) - toe)
        return p / (p + knee) * (1.0 + knee)

    return response


def sharp_led(wl: np.ndarray) -> np.ndarray:
    """Phosphor white with a sharp 450 nm peak: the 410 nm band below 1 % of the maximum."""
    return 0.95 * base.gauss(wl, 450.0, 8.0) + 0.6 * base.gauss(wl, 570.0, 50.0) + 0.004


def cool_led(wl: np.ndarray) -> np.ndarray:
    """A cooler phosphor white: stronger, slightly broader blue peak at 445 nm."""
    return 1.0 * base.gauss(wl, 445.0, 9.0) + 0.45 * base.gauss(wl, 550.0, 45.0) + 0.006


def collection(sds, names: list[str]):
    """Reflectances of a colour-science collection, sampled at ``wl``."""

    def reflectances(wl: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(wl, sds[n].wavelengths, sds[n].values) for n in names])

    return reflectances


def colour_checker(wl: np.ndarray) -> np.ndarray:
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    return np.stack([np.interp(wl, sd.wavelengths, sd.values) for sd in sds.values()])


def led_power(seed: int) -> dict[int, float]:
    """A fixed 2 % spread of the six LEDs' power."""
    spread = np.random.default_rng(seed).normal(0.0, 0.02, 6)
    return {100 + k: float(1.0 + s) for k, s in enumerate(spread)}


MODELS = {
    "nikon": {"sensitivity": measured_sensitivity(NIKON), "black": 60.0, "oecf": s_curve(1.3, 0.5)},
    "sigma": {"sensitivity": measured_sensitivity(SIGMA), "black": 48.0, "oecf": s_curve(1.15, 0.35)},
    # a consumer camera: the Sigma's sensitivity, a strong toe over its lowest ~150 DN
    "consumer": {
        "sensitivity": measured_sensitivity(SIGMA),
        "black": 64.0,
        "oecf": toe_curve(0.03, 0.5),
    },
}

WHITE_LEVEL = 3900
"""The white level of ``sigma-paired-white``'s cameras [DN]: 12-bit raw values clip there, under
the top code 4095, and capture.toml says nothing of it."""


FALLOFF = {"rgb": 0.2, "spectral": 0.3, "spectral_slope": 0.05}
"""Lens falloff of ``sigma-paired-falloff``: 20 % less light in the RGB cameras' corners,
25..35 % (blue to red) in the spectral camera's."""


def lab(name: str) -> dict:
    """The gantry of lab ``name`` (see the module docstring)."""
    if name == "gaussian-falloff":  # foreign_gantry's own lab through falloffing lenses
        return base.default_lab() | {
            "name": "bumpy stripes, night of 2026-11-20, lens falloff",
            "falloff": FALLOFF,
        }
    if name == "sigma-paired-falloff":  # sigma-paired written again through falloffing lenses
        return lab("sigma-paired") | {
            "name": "NIST CQS samples on a bumpy sample, Sigma paired, lens falloff",
            "falloff": FALLOFF,
        }
    if name == "sigma-paired-white":  # sigma-paired, every RGB camera clipping at WHITE_LEVEL
        return lab("sigma-paired") | {
            "name": "NIST CQS samples on a bumpy sample, Sigma paired, white level 3900",
            "models": {k: v | {"white": WHITE_LEVEL} for k, v in MODELS.items()},
        }
    if name == "toe-camera":  # nikon-paired with its third camera a consumer camera with a toe
        return lab("nikon-paired") | {
            "name": "CIE test colours on a bumpy sample, Nikon paired, a consumer camera's toe",
            "rgb_cameras": {
                "cam-top": (10.0, 0.0, "nikon"),
                "cam-45": (45.0, 0.0, "nikon"),
                "cam-side": (30.0, 90.0, "consumer"),
            },
        }
    if name == "nikon-paired":
        return {
            "name": "CIE test colours on a bumpy sample, Nikon paired",
            "illuminant": sharp_led,
            "materials": collection(
                SDS_TCS["CIE 1995"], ["TCS09", "TCS10", "TCS12", "TCS11", "TCS03", "TCS13"]
            ),
            "chart": colour_checker,
            "rgb_cameras": {
                "cam-top": (10.0, 0.0, "nikon"),
                "cam-45": (45.0, 0.0, "nikon"),
                "cam-side": (30.0, 90.0, "sigma"),
            },
            "models": MODELS,
            "led_power": led_power(7),
        }
    if name == "sigma-paired":
        return {
            "name": "NIST CQS samples on a bumpy sample, Sigma paired",
            "illuminant": cool_led,
            "materials": collection(
                SDS_VS["NIST CQS 9.0"], ["VS1", "VS4", "VS6", "VS8", "VS10", "VS13"]
            ),
            "chart": colour_checker,
            "rgb_cameras": {
                "cam-top": (10.0, 0.0, "nikon"),
                "cam-45": (45.0, 0.0, "sigma"),
            },
            "models": MODELS,
            "led_power": led_power(11),
        }
    raise ValueError(f"unknown lab {name!r}: one of {', '.join(LABS)}")


LABS = (
    "nikon-paired",
    "sigma-paired",
    "sigma-paired-falloff",
    "gaussian-falloff",
    "sigma-paired-white",
    "toe-camera",
)
HELD_OUT = "sigma-paired"  # never used to choose a setting of the calibration


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--lab", choices=LABS, default="nikon-paired")
    parser.add_argument("--truth", type=Path, default=None)
    args = parser.parse_args(argv)
    base.write_capture(args.out, args.truth, lab(args.lab))
    leaked = sorted(name for name in sys.modules if name.split(".")[0] == "spectralize")
    print(f"wrote {args.out} ({args.lab}); spectralize modules imported: {leaked}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
