"""Capture-time accounting: a long-exposure reference capture against the fast capture.

The paper's point is speed. Its reference spectral capture of a colour checker took a total
exposure of 226 212 ms (the paper, sec. 5); its fast capture (RGB images plus very short, very
noisy band shots) took 7 463 ms in the paper, "about 1.5 orders of magnitude" less, at nearly
the same accuracy.
:func:`capture_time` sums the exposure of any two plans the same way and states the speed-up
next to the accuracy the reconstruction reached.

A *plan* is an :class:`xarray.Dataset` over ``wavelength`` with ``exposure_time`` [s] per band,
as :func:`spectralize.nodes.simulation.exposure_plan.exposure_plan` (eq. 2) and
:func:`~spectralize.nodes.simulation.exposure_plan.reference_exposure_plan` produce; its attr
``spectral_sets`` (default 1) says how often the full set of bands is shot, and its optional
``rgb_exposure_time`` (rgb_exposure) with attr ``rgb_images`` gives the RGB exposure series.
A capture can also be given as a plain total in seconds, or made from what a run shot, its
``raw/spectral`` and ``raw/rgb`` groups (:func:`capture_time_from_run`).

References
----------
Fast Capture of Spectral Image Series, sec. 3 eq. 2 (exposure times), sec. 4 ("32 noisy
band-filtered images within the time needed for 10 high quality HDR RGB images"), sec. 5
"Real Data" and Figure 8 (226 212 ms against 7 463 ms).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import Problem, SchemaError

__all__ = [
    "PAPER_REFERENCE_TIME",
    "PAPER_FAST_TIME",
    "plan_exposure",
    "capture_time",
    "capture_time_from_run",
    "run_capture_time",
]

#: Total exposure of the paper's long-exposure reference capture [s] (sec. 5, Figure 8).
PAPER_REFERENCE_TIME: float = 226.212
#: Total exposure of the paper's fast capture, RGB plus noisy bands [s] (sec. 5, Figure 8).
PAPER_FAST_TIME: float = 7.463


def _positive_times(values: object, where: str) -> np.ndarray:
    times = np.asarray(values, dtype=np.float64).reshape(-1)
    if times.size and (not np.all(np.isfinite(times)) or np.any(times < 0)):
        raise SchemaError(
            "cannot account the capture time:",
            [
                Problem(
                    where,
                    "finite exposure times >= 0 [s]",
                    np.array2string(times, precision=4, threshold=8),
                )
            ],
        )
    return times


def plan_exposure(
    plan: xr.Dataset,
    *,
    rgb_exposure_times: Sequence[float] | None = None,
    rgb_images: int | None = None,
    name: str = "plan",
) -> tuple[float, float, int]:
    """(spectral seconds, RGB seconds, band shots) of one exposure plan.

    Parameters
    ----------
    plan
        ``exposure_time`` (wavelength) [s]; attr ``spectral_sets`` (default 1); optional
        ``rgb_exposure_time`` (rgb_exposure) [s] and attr ``rgb_images`` (default 0); attr
        ``band_shots`` (default: bands times sets).
    rgb_exposure_times, rgb_images
        Override the plan's RGB exposure series and number of RGB images.
    name
        Used in error messages.

    Raises
    ------
    SchemaError
        If the plan has no ``exposure_time`` over ``wavelength`` in seconds, for negative or
        non-finite times, or a negative number of images or sets.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 3 eq. 2 (exposure times of the band shots).
    """
    times = plan.get("exposure_time") if isinstance(plan, xr.Dataset) else None
    if (
        times is None
        or "wavelength" not in times.dims
        or times.ndim != 1
        or times.attrs.get("units", "s") != "s"
    ):
        found = "nothing" if times is None else f"dims {times.dims}, units {times.attrs.get('units')!r}"
        raise SchemaError(
            f"cannot account the capture time of the {name}:",
            [Problem(f"{name}:exposure_time", "a variable exposure_time (wavelength) in s", found)],
        )
    sets = int(plan.attrs.get("spectral_sets", 1))
    if sets < 0:
        raise SchemaError(
            f"cannot account the capture time of the {name}:",
            [Problem(f"{name}.attrs['spectral_sets']", ">= 0 sets of bands", str(sets))],
        )
    spectral = float(_positive_times(times.values, f"{name}:exposure_time").sum() * sets)
    shots = int(plan.attrs.get("band_shots", times.size * sets))
    if rgb_exposure_times is None:
        rgb_series = plan["rgb_exposure_time"].values if "rgb_exposure_time" in plan else []
    else:
        rgb_series = rgb_exposure_times
    rgb_series = _positive_times(rgb_series, f"{name}: rgb exposure times")
    images = int(plan.attrs.get("rgb_images", 0)) if rgb_images is None else int(rgb_images)
    if images < 0:
        raise SchemaError(
            f"cannot account the capture time of the {name}:",
            [Problem(f"{name}: rgb_images", ">= 0 RGB images", str(images))],
        )
    return spectral, float(images * rgb_series.sum()), shots


def _capture(
    value: xr.Dataset | float,
    name: str,
    rgb_exposure_times: Sequence[float] | None,
    rgb_images: int | None,
) -> tuple[float, float, int]:
    if isinstance(value, xr.Dataset):
        return plan_exposure(
            value, rgb_exposure_times=rgb_exposure_times, rgb_images=rgb_images, name=name
        )
    total = float(value)
    if not np.isfinite(total) or total < 0:
        raise SchemaError(
            f"cannot account the capture time of the {name}:",
            [Problem(name, "a plan Dataset or a total exposure >= 0 [s]", repr(value))],
        )
    return total, 0.0, 0


def capture_time(
    fast: xr.Dataset | float,
    reference: xr.Dataset | float = PAPER_REFERENCE_TIME,
    *,
    rgb_exposure_times: Sequence[float] | None = None,
    rgb_images: int | None = None,
    reference_includes_rgb: bool = False,
    evaluation: xr.Dataset | None = None,
) -> xr.Dataset:
    """Total exposure of the reference and the fast capture, and the speed-up.

    Parameters
    ----------
    fast
        The fast capture: a plan (noisy band shots, eq. 2) or its total exposure [s].
    reference
        The long-exposure reference capture: a plan or its total exposure [s] (default: the
        paper's 226.212 s).
    rgb_exposure_times, rgb_images
        The RGB exposure series [s] and the number of RGB images of the fast capture (by
        default taken from the fast plan's ``rgb_exposure_time`` and ``rgb_images``).
    reference_includes_rgb
        Whether the reference capture also takes the RGB images (the paper's reference is
        spectral only).
    evaluation
        The ``evaluation`` group of the reconstruction from the fast capture: its nRMSE
        median, 95th percentile and fraction below the threshold over all images are added,
        so that the speed-up is shown next to the accuracy reached.

    Returns
    -------
    xarray.Dataset
        Over ``capture = ['reference', 'fast']``: ``spectral_time``, ``rgb_time``,
        ``total_time`` [s] and ``band_shots``; scalar ``speedup`` [1] (reference total /
        fast total) and, with ``evaluation``, ``nrmse_median``, ``nrmse_p95``,
        ``nrmse_fraction_below`` [1]. Attr ``summary`` is one readable line; attr
        ``given_as_total`` names the captures given as a number of seconds (their time is
        all under ``spectral_time``).

    Raises
    ------
    SchemaError
        If the fast capture takes no time at all, or for invalid plans.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 "Real Data" and Figure 8: 226 212 ms
    against 7 463 ms in the paper, "about 1.5 orders of magnitude".

    Examples
    --------
    >>> round(float(capture_time(7.463).speedup), 1)
    30.3
    """
    f_spec, f_rgb, f_shots = _capture(fast, "fast capture", rgb_exposure_times, rgb_images)
    r_spec, r_rgb, r_shots = _capture(reference, "reference capture", None, None)
    if reference_includes_rgb:
        r_rgb = r_rgb or f_rgb
    else:
        r_rgb = 0.0
    f_total, r_total = f_spec + f_rgb, r_spec + r_rgb
    if f_total <= 0:
        raise SchemaError(
            "fast capture: its total exposure is 0 s, so no speed-up can be stated:",
            [Problem("fast capture", "a plan with exposure_time > 0 or its total in seconds", "0 s")],
        )
    speedup = r_total / f_total

    def seconds(values: list[float], long_name: str) -> tuple[str, np.ndarray, dict[str, str]]:
        return ("capture", np.asarray(values, dtype=np.float64), {"units": "s", "long_name": long_name})

    out = xr.Dataset(
        {
            "spectral_time": seconds([r_spec, f_spec], "total exposure of the band shots"),
            "rgb_time": seconds([r_rgb, f_rgb], "total exposure of the RGB images"),
            "total_time": seconds([r_total, f_total], "total exposure of the capture"),
            "band_shots": (
                "capture",
                np.asarray([r_shots, f_shots], dtype=np.int64),
                {"units": "1", "long_name": "number of band shots"},
            ),
            "speedup": (
                (),
                float(speedup),
                {"units": "1", "long_name": "reference total exposure / fast total exposure"},
            ),
        },
        coords={"capture": ("capture", ["reference", "fast"], {"long_name": "capture"})},
    )
    summary = (
        f"reference {r_total:.3f} s vs fast {f_total:.3f} s (spectral {f_spec:.3f} s + "
        f"RGB {f_rgb:.3f} s): {speedup:.1f}x faster ({np.log10(speedup):.2f} orders of "
        "magnitude)"
    )
    if evaluation is not None:
        accuracy = _accuracy(evaluation)
        for key, value in accuracy.items():
            out[key] = (
                (),
                value,
                {
                    "units": "1",
                    "long_name": f"{key.replace('_', ' ')} of the "
                    "reconstruction from the fast capture (all images)",
                },
            )
        summary += f"; nRMSE median {accuracy['nrmse_median']:.4f}, p95 {accuracy['nrmse_p95']:.4f}"
    given = [
        name
        for name, value in (("reference", reference), ("fast", fast))
        if not isinstance(value, xr.Dataset)
    ]
    out.attrs = {
        "summary": summary,
        "given_as_total": ",".join(given),
        "references": "Fast Capture of Spectral Image Series, sec. 5, Figure 8",
    }
    return out


def _accuracy(evaluation: xr.Dataset) -> dict[str, float]:
    needed = ("nrmse_subset_statistics", "nrmse_subset_fraction_below")
    missing = [name for name in needed if name not in evaluation]
    if missing:
        raise SchemaError(
            "cannot show the accuracy next to the capture time:",
            [
                Problem(f"evaluation:{name}", "a variable of the evaluation group", "nothing")
                for name in missing
            ],
        )
    stats = evaluation["nrmse_subset_statistics"].sel(subset="all")
    return {
        "nrmse_median": float(stats.sel(statistic="median")),
        "nrmse_p95": float(stats.sel(statistic="p95")),
        "nrmse_fraction_below": float(evaluation["nrmse_subset_fraction_below"].sel(subset="all")),
    }


def capture_time_from_run(
    raw_spectral: xr.Dataset | None = None, raw_rgb: xr.Dataset | None = None
) -> xr.Dataset:
    """The exposure a run actually shot, as a plan for :func:`capture_time`.

    Parameters
    ----------
    raw_spectral
        Group ``raw/spectral``: per-shot ``exposure_time`` and ``wavelength`` (shot).
    raw_rgb
        Group ``raw/rgb``: ``exposure_time`` (image, exposure) [s].

    Returns
    -------
    xarray.Dataset
        ``exposure_time`` (wavelength) [s]: the exposure of all shots of each band, summed;
        ``rgb_exposure_time`` (rgb_exposure) [s]: every RGB exposure of the run (attr
        ``rgb_images = 1``); attr ``band_shots``: the number of shots. Pass it as ``fast``.

    Raises
    ------
    SchemaError
        If a group lacks the per-shot or per-image exposure times, or one is negative.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 4 ("32 noisy band-filtered images within the
    time needed for 10 high quality HDR RGB images").
    """
    problems = []
    wavelengths = np.zeros(0)
    band_times = np.zeros(0)
    shots = 0
    if raw_spectral is not None:
        times = raw_spectral.get("exposure_time")
        bands = raw_spectral.get("wavelength")
        if times is None or bands is None or times.dims != ("shot",) or bands.dims != ("shot",):
            found = {
                name: (None if v is None else v.dims)
                for name, v in (("exposure_time", times), ("wavelength", bands))
            }
            problems.append(
                Problem("raw/spectral", "exposure_time [s] and wavelength [nm] over shot", f"{found}")
            )
        else:
            per_shot = _positive_times(times.values, "raw/spectral:exposure_time")
            wavelengths, index = np.unique(
                np.asarray(bands.values, dtype=np.float64), return_inverse=True
            )
            band_times = np.bincount(index.reshape(-1), weights=per_shot, minlength=wavelengths.size)
            shots = int(per_shot.size)
    rgb_times = np.zeros(0)
    if raw_rgb is not None:
        times = raw_rgb.get("exposure_time")
        if times is None or tuple(times.dims) != ("image", "exposure"):
            found = "nothing" if times is None else f"dims {times.dims}"
            problems.append(
                Problem("raw/rgb:exposure_time", "exposure_time (image, exposure) in s", found)
            )
        else:
            rgb_times = _positive_times(times.values, "raw/rgb:exposure_time")
    if problems:
        raise SchemaError("cannot sum the exposure of the run:", problems)
    return xr.Dataset(
        {
            "exposure_time": (
                "wavelength",
                band_times,
                {"units": "s", "long_name": "total exposure of the band shots of each band"},
            ),
            "rgb_exposure_time": (
                "rgb_exposure",
                rgb_times,
                {"units": "s", "long_name": "every RGB exposure of the run"},
            ),
        },
        coords={"wavelength": ("wavelength", wavelengths, {"units": "nm"})},
        attrs={"spectral_sets": 1, "rgb_images": 1, "band_shots": shots, "kind": "measured"},
    )


def run_capture_time(
    raw_spectral: xr.Dataset,
    raw_rgb: xr.Dataset | None = None,
    exposure_plan: xr.Dataset | None = None,
    *,
    evaluation: xr.Dataset | None = None,
) -> xr.Dataset:
    """Capture time of a run against a long-exposure reference capture of the same images.

    The fast capture is what the run shot (:func:`capture_time_from_run`). The reference
    takes one long-exposure set of bands per RGB image, each of the plan's
    ``reference_capture_time`` [s] (group ``raw/exposure_plan`` of a simulated run); without
    a plan, the paper's reference capture of one image (226.212 s) is used. Which one is said
    in ``attrs["reference_note"]`` and in the summary.

    Parameters
    ----------
    raw_spectral, raw_rgb
        Groups ``raw/spectral`` and ``raw/rgb`` of the run.
    exposure_plan
        Group ``raw/exposure_plan``, with a scalar ``reference_capture_time`` [s].
    evaluation
        As for :func:`capture_time`.

    Returns
    -------
    xarray.Dataset
        As :func:`capture_time`, with attr ``reference_note``.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 "Real Data" and Figure 8.
    """
    fast = capture_time_from_run(raw_spectral, raw_rgb)
    per_set = exposure_plan.get("reference_capture_time") if exposure_plan is not None else None
    if per_set is not None:
        if raw_rgb is not None:
            images = int(raw_rgb.sizes["image"])
        else:
            images = max(1, int(exposure_plan.attrs.get("rgb_images", 1)))
        seconds = float(per_set)
        reference = images * seconds
        note = (
            f"reference: {images} image(s) x {seconds:.3f} s, one long-exposure set of "
            "bands each (raw/exposure_plan)"
        )
    else:
        reference = PAPER_REFERENCE_TIME
        note = f"reference: the paper's long-exposure capture of one image ({reference:g} s)"
    result = capture_time(fast, reference, evaluation=evaluation)
    result.attrs["reference_note"] = note
    result.attrs["summary"] += f" [{note}]"
    return result
