"""The HTML report of an evaluation: composition and file I/O (paper sec. 5, Figures 4-8).

:func:`write_report` writes a self-contained folder: ``index.html``, rendered from the Jinja2
template ``templates/report.html.j2`` (autoescaped), with relative links to PNG figures:

- ``error_map_NNN.png`` and ``spectra_NNN.png`` per image (Figures 5 and 6),
- ``histogram.png`` (Figure 7),
- ``capture_time.png`` (sec. 5 "Real Data", Figure 8) when a capture time is given,
- ``cross_validation.png`` (Figure 4) when the spectral calibration is given,

and tables of the numbers: what run it describes, a summary per subset of images, per image,
capture time and, when baselines were run, the comparison of methods. The figures are drawn
by :mod:`spectralize.nodes.evaluation.figures` and
:mod:`spectralize.nodes.evaluation.figures_calibration`; this module only composes and
writes. :func:`write_run_report` reads all of it from a run store.

References
----------
Fast Capture of Spectral Image Series, sec. 5, Figures 4, 5, 6, 7 and 8.
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import jinja2
import numpy as np
import xarray as xr
from matplotlib.figure import Figure

from spectralize.nodes.evaluation.capture_time import (
    capture_time,
    capture_time_from_run,
    run_capture_time,
)
from spectralize.nodes.evaluation.colorimetry import render_srgb
from spectralize.nodes.evaluation.figures import (
    image_label,
    plot_capture_time,
    plot_error_map,
    plot_histograms,
    plot_spectra,
)
from spectralize.nodes.evaluation.figures_calibration import plot_cross_validation
from spectralize.nodes.evaluation.metrics import (
    DEFAULT_THRESHOLD,
    METHOD_DIM,
    STATISTICS,
    compare_methods,
    evaluate,
)
from spectralize.schemas import ParameterError, Problem, RunStore, SchemaError
from spectralize.schemas.run import EVALUATION

__all__ = [
    "BASELINES_GROUP",
    "TEMPLATE",
    "write_report",
    "write_run_report",
]

#: Run-store groups ``baselines/<method>`` (spectra layout) are compared by
#: :func:`write_run_report`.
BASELINES_GROUP: str = "baselines"
#: The page's Jinja2 template, in this package's ``templates`` folder.
TEMPLATE: str = "report.html.j2"
_DPI = 100
_METRIC_LABELS = (("nrmse", "nRMSE"), ("spectral_angle", "spectral angle [°]"), ("delta_e", "CIEDE2000"))


@lru_cache(maxsize=1)
def _environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.PackageLoader("spectralize.flows", "templates"),
        autoescape=True,
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )


def _check_evaluation(evaluation: xr.Dataset) -> None:
    """Every variable and coordinate of the ``evaluation`` schema is drawn or tabulated."""
    missing = [
        spec.name for spec in EVALUATION.variables + EVALUATION.coords if spec.name not in evaluation
    ]
    if missing:
        raise SchemaError(
            "cannot report this evaluation:",
            [
                Problem(
                    f"evaluation:{name}",
                    "a variable made by spectralize.nodes.evaluation.metrics.evaluate",
                    "nothing",
                )
                for name in missing
            ],
        )


# -- tables --------------------------------------------------------------------------------
def _fmt(value: Any, digits: int = 4) -> str:
    value = float(value)
    return "—" if not np.isfinite(value) else f"{value:.{digits}g}"


def _table(
    table_id: str, caption: str, header: Sequence[str], rows: Sequence[Sequence[str]]
) -> dict[str, Any]:
    return {
        "id": table_id,
        "caption": caption,
        "header": list(header),
        "rows": [list(row) for row in rows],
    }


def _summary_rows(table: xr.Dataset, subsets: Sequence[str]) -> list[list[str]]:
    rows = []
    for subset in subsets:
        row = [subset.replace("_", " "), str(int(table["subset_pixel_count"].sel(subset=subset)))]
        for metric, _ in _METRIC_LABELS:
            stats = table[f"{metric}_subset_statistics"].sel(subset=subset)
            row += [_fmt(stats.sel(statistic=s)) for s in ("median", "p95", "p99")]
        row.append(_fmt(table["nrmse_subset_fraction_below"].sel(subset=subset)))
        rows.append(row)
    return rows


def _summary_header(threshold: float) -> list[str]:
    header = ["subset", "pixels"]
    for _, label in _METRIC_LABELS:
        header += [f"{label} median", f"{label} p95", f"{label} p99"]
    return header + [f"fraction nRMSE < {threshold:g}"]


def _per_image_table(evaluation: xr.Dataset) -> dict[str, Any]:
    coords = [
        c
        for c in ("camera", "rotation", "led", "theta_i", "phi_i", "theta_o", "phi_o")
        if c in evaluation.coords
    ]
    header = ["image", *coords]
    if "has_band_shots" in evaluation:
        header.append("band shots")
    header += [f"nRMSE {s}" for s in STATISTICS]
    header += ["fraction below", "angle median [°]", "ΔE00 median", "ΔE00 p95", "NaN px"]
    rows = []
    for image in range(evaluation.sizes["image"]):
        row = [str(image)] + [_fmt(evaluation.coords[c][image], 5) for c in coords]
        if "has_band_shots" in evaluation:
            row.append("yes" if bool(evaluation["has_band_shots"][image]) else "no")
        row += [_fmt(evaluation["nrmse_statistics"][image].sel(statistic=s)) for s in STATISTICS]
        row.append(_fmt(evaluation["nrmse_fraction_below"][image]))
        for name, stat in (("spectral_angle", "median"), ("delta_e", "median"), ("delta_e", "p95")):
            row.append(_fmt(evaluation[f"{name}_statistics"][image].sel(statistic=stat)))
        row.append(str(int(evaluation["invalid_count"][image])))
        rows.append(row)
    return _table("per-image", "Statistics per image", header, rows)


def _run_table(
    evaluation: xr.Dataset, spectra: xr.Dataset, truth: xr.Dataset, run: str | os.PathLike[str] | None
) -> dict[str, Any]:
    rows = [["run store", str(run) if run is not None else "(not given)"]]
    for role, ds in (("spectra", spectra), ("truth/spectra", truth), ("evaluation", evaluation)):
        fingerprint = ds.attrs.get("spectralize_fingerprint") or evaluation.attrs.get(
            f"{role.split('/')[0]}_fingerprint"
        )
        provenance = ds.attrs.get("spectralize_provenance") or {}
        made_by = (
            f"{provenance.get('node', '?')} v{provenance.get('version', '?')}"
            if provenance
            else "(no provenance)"
        )
        rows.append([f"{role} fingerprint", str(fingerprint) if fingerprint else "(none)"])
        rows.append([f"{role} made by", made_by])
    sizes = spectra["radiance"].sizes
    wavelength = np.asarray(truth["wavelength"].values, dtype=np.float64)
    rows += [
        ["images", str(sizes["image"])],
        ["image size", f"{sizes['y']} x {sizes['x']} px"],
        ["wavelengths", f"{wavelength.size} bands, {wavelength[0]:g}..{wavelength[-1]:g} nm"],
        [
            "colour difference",
            f"CIEDE2000 under {evaluation.attrs.get('illuminant', '?')}, "
            f"{evaluation.attrs.get('observer', 'CIE 1931 2°')}",
        ],
    ]
    return _table("run", "What this report describes", ["item", "value"], rows)


def _capture_table(capture: xr.Dataset) -> dict[str, Any]:
    rows = [
        [
            str(c),
            _fmt(capture["spectral_time"].sel(capture=c)),
            _fmt(capture["rgb_time"].sel(capture=c)),
            _fmt(capture["total_time"].sel(capture=c)),
            str(int(capture["band_shots"].sel(capture=c))),
        ]
        for c in capture["capture"].values
    ]
    return _table(
        "capture-time",
        "Total exposure of the captures [s]; "
        f"speed-up {float(capture['speedup']):.1f}x. " + str(capture.attrs.get("summary", "")),
        ["capture", "band shots [s]", "RGB [s]", "total [s]", "band shots"],
        rows,
    )


def _baselines_table(evaluation: xr.Dataset, table: xr.Dataset, threshold: float) -> dict[str, Any]:
    header = ["method"] + _summary_header(threshold)[2:]
    rows = [["this run (spectra)"] + _summary_rows(evaluation, ["all"])[0][2:]]
    for method in table[METHOD_DIM].values:
        rows.append([str(method)] + _summary_rows(table.sel({METHOD_DIM: method}), ["all"])[0][2:])
    return _table("baselines", "Comparison of methods on all images of the run", header, rows)


# -- figures -------------------------------------------------------------------------------
def _save(figure: Figure, directory: Path, name: str, caption: str) -> dict[str, str]:
    """Write ``figure`` as ``directory / name``; what the template needs to show it."""
    figure.savefig(directory / name, dpi=_DPI)
    return {"id": Path(name).stem, "src": name, "caption": caption}


def _cross_validation(calibration: xr.Dataset, directory: Path) -> dict[str, Any]:
    checked = calibration[["measured_rgb", "predicted_rgb", "relative_error"]].compute()
    error = np.asarray(checked["relative_error"].values, dtype=float)
    rows = [
        [str(patch), _fmt(float(e))] for patch, e in zip(checked["patch"].values, error, strict=True)
    ]
    table = _table(
        "cross-validation",
        "RGB of the colour-checker patches predicted through C "
        "from the spectral camera's capture vs measured: relative error per patch "
        f"(mean {_fmt(float(np.nanmean(error)))})",
        ["patch", "relative error"],
        rows,
    )
    figure = _save(
        plot_cross_validation(checked.rename(measured_rgb="measured", predicted_rgb="predicted")),
        directory,
        "cross_validation.png",
        "(a) measured RGB, (b) RGB predicted "
        "through C from the spectral capture, (c) their difference scaled 10x.",
    )
    return {"table": table, "figure": figure}


# -- the report ----------------------------------------------------------------------------
def write_report(
    evaluation: xr.Dataset,
    *,
    spectra: xr.Dataset,
    truth: xr.Dataset,
    directory: str | os.PathLike[str],
    baselines: xr.Dataset | Mapping[str, xr.DataArray | xr.Dataset] | None = None,
    capture: xr.Dataset | None = None,
    title: str = "spectralize: reconstruction accuracy",
    run: str | os.PathLike[str] | None = None,
    shots: xr.Dataset | None = None,
    max_images: int = 24,
    exposure_percentile: float = 99.0,
    calibration: xr.Dataset | None = None,
) -> Path:
    """Write an HTML report with PNG figures of an evaluation into ``directory``.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.metrics.evaluate` (the ``evaluation``
        group); it is computed here.
    spectra, truth
        Groups ``spectra`` and ``truth/spectra`` the evaluation was made from (for the sRGB
        renders and the description of the run).
    directory
        Folder to write ``index.html`` and the figures into (created; files are replaced).
    baselines
        Comparison of methods: the output of
        :func:`~spectralize.nodes.evaluation.metrics.compare_methods` (dim
        ``reconstruction``), or what it accepts (method name -> cube, or ``radiance`` with a
        ``reconstruction`` dim), which is then evaluated here against ``truth`` (with
        ``shots``). Table left out when ``None``.
    capture
        Output of :func:`~spectralize.nodes.evaluation.capture_time.capture_time`; the
        capture-time figure and table are left out when ``None``.
    title
        Title of the page.
    run
        Path of the run store, shown as what the report describes.
    shots
        Group ``raw/spectral``, only used when ``baselines`` are cubes.
    max_images
        At most this many images get an error-map and a spectra figure (all are tabulated).
    exposure_percentile
        Percentile of the truth's luminance mapped to sRGB white (one exposure for truth and
        reconstruction, over the images shown).
    calibration
        Group ``calibration/spectral``; its colour-checker cross-validation (Figure 4) is
        tabulated and drawn.

    Returns
    -------
    pathlib.Path
        The path of ``index.html``.

    Raises
    ------
    SchemaError
        If ``evaluation`` lacks variables that
        :func:`~spectralize.nodes.evaluation.metrics.evaluate` makes.
    ParameterError
        If ``max_images`` is below 1.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5, Figures 4-8.
    """
    _check_evaluation(evaluation)
    if int(max_images) < 1:
        raise ParameterError(
            "cannot write the report:",
            [Problem("max_images", "at least 1 image with figures", repr(max_images))],
        )
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    evaluation = evaluation.compute()
    n_images = evaluation.sizes["image"]
    shown = list(range(min(n_images, int(max_images))))
    threshold = float(evaluation.attrs.get("threshold", DEFAULT_THRESHOLD))

    truth_srgb = render_srgb(
        truth["radiance"].isel(image=shown), percentile=exposure_percentile
    ).compute()
    scale = float(truth_srgb.attrs["exposure_scale"])
    recon_srgb = render_srgb(spectra["radiance"].isel(image=shown), exposure=scale).compute()
    finite = np.asarray(evaluation["nrmse"].isel(image=shown).values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    vmax = vmax if vmax > 0 else 1.0

    context: dict[str, Any] = {
        "title": title,
        "written": time.strftime("%Y-%m-%d %H:%M:%S"),
        "run": _run_table(evaluation, spectra, truth, run),
        "summary": _table(
            "summary",
            "Statistics over all pixels of each subset of images",
            _summary_header(threshold),
            _summary_rows(evaluation, [str(s) for s in evaluation["subset"].values]),
        ),
        "per_image": _per_image_table(evaluation),
        "histogram": _save(
            plot_histograms(evaluation),
            directory,
            "histogram.png",
            "Histogram of the per-pixel normalised RMSE over all pixels of the "
            "images with and without band shots; logarithmic count axis.",
        ),
        "capture": None,
        "cross_validation": None,
        "baselines": None,
        "exposure_normalisation": truth_srgb.attrs["exposure_normalisation"],
        "vmax": _fmt(vmax),
        "images_shown": len(shown),
        "images_total": n_images,
    }
    if capture is not None:
        context["capture"] = {
            "table": _capture_table(capture),
            "figure": _save(
                plot_capture_time(capture),
                directory,
                "capture_time.png",
                "Total exposure of the reference and the fast capture.",
            ),
        }
    if calibration is not None and "measured_rgb" in calibration:
        context["cross_validation"] = _cross_validation(calibration, directory)
    if baselines is not None:
        table = baselines
        if not (isinstance(table, xr.Dataset) and "nrmse_subset_statistics" in table):
            table = compare_methods(
                baselines,
                truth,
                shots=shots,
                illuminant=str(evaluation.attrs.get("illuminant", "D65")),
                threshold=threshold,
            )
        context["baselines"] = _baselines_table(evaluation, table.compute(), threshold)
    context["images"] = [
        {
            "label": image_label(evaluation, image),
            "error_map": _save(
                plot_error_map(
                    evaluation, image, truth_srgb=truth_srgb, reconstruction_srgb=recon_srgb, vmax=vmax
                ),
                directory,
                f"error_map_{image:03d}.png",
                f"Image {image}: ground truth and reconstruction (sRGB) and the "
                "normalised RMSE map; numbered pixels are the representative "
                "spectra.",
            ),
            "spectra": _save(
                plot_spectra(evaluation, image),
                directory,
                f"spectra_{image:03d}.png",
                f"Image {image}: representative spectra, ground truth solid, reconstruction dotted.",
            ),
        }
        for image in shown
    ]

    index = directory / "index.html"
    index.write_text(_environment().get_template(TEMPLATE).render(context), encoding="utf-8")
    return index


def write_run_report(
    store: RunStore | str | os.PathLike[str],
    *,
    directory: str | os.PathLike[str] | None = None,
    reference: xr.Dataset | float | None = None,
    title: str | None = None,
    max_images: int = 24,
) -> Path:
    """Write the report of a run store: what :func:`write_report` needs, read from the run.

    Reads ``spectra`` and ``truth/spectra``; ``raw/spectral`` (which images have band shots)
    if present; the stored ``evaluation`` group if present, else evaluates now with the
    defaults of :func:`~spectralize.nodes.evaluation.metrics.evaluate`; the capture time from
    ``raw/spectral``, ``raw/rgb`` and ``raw/exposure_plan`` if present
    (:func:`~spectralize.nodes.evaluation.capture_time.run_capture_time`); the
    ``calibration/spectral`` group if present; and every ``baselines/<method>`` group (the
    spectra layout) as the baseline table.

    Parameters
    ----------
    store
        The run store or its path.
    directory
        Where to write (default: the folder ``report`` inside the run store).
    reference
        The long-exposure reference capture: a plan or its total [s] (default: one
        reference set of bands per image from ``raw/exposure_plan``, else the paper's
        226.212 s; the report says which).
    title, max_images
        As for :func:`write_report` (default title: the store's name).

    Returns
    -------
    pathlib.Path
        The path of ``index.html``.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5, Figures 4-8.
    """
    run = store if isinstance(store, RunStore) else RunStore.open(store)
    spectra = run.read("spectra")
    truth = run.read("truth/spectra")
    shots = run.read("raw/spectral") if run.has("raw/spectral") else None
    if run.has("evaluation"):
        evaluation = run.read("evaluation")
    else:
        evaluation = evaluate(spectra, truth, shots=shots)
    evaluation = evaluation.compute()
    capture = None
    if shots is not None:
        raw_rgb = run.read("raw/rgb") if run.has("raw/rgb") else None
        if reference is None:
            plan = run.read("raw/exposure_plan") if run.has("raw/exposure_plan") else None
            capture = run_capture_time(shots, raw_rgb, plan, evaluation=evaluation)
        else:
            capture = capture_time(
                capture_time_from_run(shots, raw_rgb), reference, evaluation=evaluation
            )
    prefix = BASELINES_GROUP + "/"
    baselines = {
        group[len(prefix) :]: run.read(group) for group in run.groups() if group.startswith(prefix)
    }
    return write_report(
        evaluation,
        spectra=spectra,
        truth=truth,
        directory=run.path / "report" if directory is None else directory,
        baselines=baselines or None,
        capture=capture,
        shots=shots,
        run=str(run.path),
        calibration=run.read("calibration/spectral") if run.has("calibration/spectral") else None,
        title=title or f"spectralize: {run.path.name}",
        max_images=max_images,
    )
