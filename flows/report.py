"""Figures and an HTML report of an evaluation (paper Figures 5-8 and sec. 5).

:func:`write_report` writes a self-contained folder: ``index.html`` with relative links to
PNG figures made with matplotlib's Agg canvas (no pyplot state, no display needed):

- ``error_map_NNN.png`` per image (Figures 5 and 6): the ground truth and the reconstruction
  rendered to sRGB (:func:`spectralize.nodes.evaluation.colorimetry.render_srgb`, one exposure for both)
  next to the normalised RMSE map in the cubehelix colour map (Green, 2011, as in the paper),
  with the representative pixels numbered;
- ``spectra_NNN.png`` per image: those pixels' spectra, truth solid, reconstruction dotted;
- ``histogram.png`` (Figure 7): nRMSE histograms over all pixels of the images with and
  without band shots, logarithmic count axis, the 0.03 level marked;
- ``capture_time.png`` (sec. 5 "Real Data", Figure 8): total exposure of the reference and
  the fast capture, stacked spectral + RGB, with the speed-up and the accuracy reached;

and tables of the numbers: summary per subset of images, per image, capture time and, when
baselines were run, the comparison of methods.

References
----------
Fast Capture of Spectral Image Series, sec. 5, Figures 5, 6, 7 and 8. Green, D. A. (2011).
A colour scheme for the display of astronomical intensity images. Bull. Astr. Soc. India 39.
"""

from __future__ import annotations

import html
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from matplotlib.figure import Figure

from spectralize.nodes.evaluation.capture_time import (
    capture_time,
    capture_time_from_run,
    run_capture_time,
)
from spectralize.nodes.evaluation.colorimetry import render_srgb
from spectralize.nodes.evaluation.metrics import METHOD_DIM, STATISTICS, compare_methods, evaluate
from spectralize.schemas import Problem, RunStore, SchemaError

__all__ = [
    "ERROR_COLORMAP",
    "plot_error_map",
    "plot_spectra",
    "plot_histograms",
    "plot_capture_time",
    "write_report",
    "write_run_report",
    "BASELINES_GROUP",
]

#: Run-store groups ``baselines/<method>`` (spectra layout) are compared by
#: :func:`write_run_report`.
BASELINES_GROUP: str = "baselines"
#: Colour map of the error maps: cubehelix (Green, 2011), the paper's choice.
ERROR_COLORMAP: str = "cubehelix"
_DPI = 100
_REQUIRED = ("nrmse", "nrmse_statistics", "nrmse_histogram", "nrmse_bin_lower",
             "nrmse_bin_upper", "nrmse_subset_statistics", "nrmse_subset_fraction_below",
             "sample_y", "sample_x", "sample_truth", "sample_reconstruction")


def _check_evaluation(evaluation: xr.Dataset) -> None:
    missing = [name for name in _REQUIRED if name not in evaluation.variables]
    if missing:
        raise SchemaError("cannot report this evaluation:", [
            Problem(f"evaluation:{name}", "a variable made by spectralize.nodes.evaluation.metrics."
                    "evaluate", "nothing") for name in missing])


# -- figures -------------------------------------------------------------------------------
def _image_label(evaluation: xr.Dataset, image: int) -> str:
    parts = [f"image {image}"]
    coords = evaluation.coords
    if "theta_o" in coords and "phi_o" in coords:
        parts.append(f"view ({float(coords['theta_o'][image]):.0f}°, "
                     f"{float(coords['phi_o'][image]):.0f}°)")
    if "theta_i" in coords and "phi_i" in coords:
        parts.append(f"light ({float(coords['theta_i'][image]):.0f}°, "
                     f"{float(coords['phi_i'][image]):.0f}°)")
    if "has_band_shots" in evaluation:
        parts.append("with band shots" if bool(evaluation["has_band_shots"][image])
                     else "without band shots")
    return ", ".join(parts)


def _mark_samples(ax: Any, evaluation: xr.Dataset, image: int) -> None:
    ys = np.asarray(evaluation["sample_y"][image].values)
    xs = np.asarray(evaluation["sample_x"][image].values)
    for number, (y, x) in enumerate(zip(ys, xs, strict=True), start=1):
        if y < 0:
            continue
        ax.plot([x], [y], marker="o", markersize=7, markerfacecolor="none",
                markeredgecolor="white", markeredgewidth=1.5)
        ax.annotate(str(number), (x, y), xytext=(4, 4), textcoords="offset points",
                    color="white", fontsize=9, fontweight="bold")


def plot_error_map(
    evaluation: xr.Dataset,
    image: int,
    *,
    truth_srgb: xr.DataArray,
    reconstruction_srgb: xr.DataArray | None = None,
    vmax: float | None = None,
) -> Figure:
    """Ground truth (sRGB) next to the normalised RMSE map of one image (Figures 5 and 6).

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.metrics.evaluate` (computed).
    image
        Position of the image along ``image``.
    truth_srgb, reconstruction_srgb
        Renders (image, y, x, channel) from :func:`~spectralize.nodes.evaluation.colorimetry.render_srgb`;
        the reconstruction panel is left out when ``None``.
    vmax
        Upper end of the colour scale (default: the image's largest nRMSE).

    Returns
    -------
    matplotlib.figure.Figure
        An Agg figure (not registered with pyplot).
    """
    nrmse = np.asarray(evaluation["nrmse"][image].values, dtype=np.float64)
    top = float(np.nanmax(nrmse)) if vmax is None and np.isfinite(nrmse).any() else (vmax or 1.0)
    panels = 3 if reconstruction_srgb is not None else 2
    figure = Figure(figsize=(4.2 * panels, 4.2), layout="constrained")
    axes = figure.subplots(1, panels)
    axes[0].imshow(np.asarray(truth_srgb[image].values), interpolation="nearest")
    axes[0].set_title("ground truth (sRGB)")
    _mark_samples(axes[0], evaluation, image)
    if reconstruction_srgb is not None:
        axes[1].imshow(np.asarray(reconstruction_srgb[image].values), interpolation="nearest")
        axes[1].set_title("reconstruction (sRGB)")
    shown = axes[-1].imshow(nrmse, cmap=ERROR_COLORMAP, vmin=0.0, vmax=top,
                            interpolation="nearest")
    axes[-1].set_title("normalised RMSE")
    _mark_samples(axes[-1], evaluation, image)
    figure.colorbar(shown, ax=axes[-1], shrink=0.85, label="nRMSE")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    figure.suptitle(_image_label(evaluation, image))
    return figure


def plot_spectra(evaluation: xr.Dataset, image: int) -> Figure:
    """Representative spectra of one image: truth solid, reconstruction dotted (Fig. 5, 6).

    The curves are numbered like the markers of :func:`plot_error_map`; the legend gives
    each pixel's position, nRMSE and the quantile of the nRMSE map it was picked at.
    """
    wavelength = np.asarray(evaluation["wavelength"].values, dtype=np.float64)
    truth = np.asarray(evaluation["sample_truth"][image].values, dtype=np.float64)
    recon = np.asarray(evaluation["sample_reconstruction"][image].values, dtype=np.float64)
    ys = np.asarray(evaluation["sample_y"][image].values)
    xs = np.asarray(evaluation["sample_x"][image].values)
    errors = np.asarray(evaluation["sample_nrmse"][image].values, dtype=np.float64)
    quantiles = np.asarray(evaluation["sample_quantile"].values, dtype=np.float64)
    figure = Figure(figsize=(8.0, 4.0), layout="constrained")
    ax = figure.subplots()
    colours = [f"C{i % 10}" for i in range(truth.shape[0])]
    for number in range(truth.shape[0]):
        if ys[number] < 0:
            continue
        label = (f"{number + 1}: (y={ys[number]}, x={xs[number]}) nRMSE {errors[number]:.4f} "
                 f"(q={quantiles[number]:g})")
        ax.plot(wavelength, truth[number], "-", color=colours[number], label=label)
        ax.plot(wavelength, recon[number], ":", color=colours[number], linewidth=2.0)
    ax.set_xlabel("wavelength [nm]")
    ax.set_ylabel("relative radiance")
    ax.set_title(f"{_image_label(evaluation, image)}\ntruth (solid), reconstruction (dotted)",
                 fontsize=10)
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    return figure


def _subset_histograms(evaluation: xr.Dataset) -> dict[str, np.ndarray]:
    counts = np.asarray(evaluation["nrmse_histogram"].values, dtype=np.int64)
    if "has_band_shots" in evaluation:
        has = np.asarray(evaluation["has_band_shots"].values, dtype=bool)
        return {"with band shots": counts[has].sum(axis=0),
                "without band shots": counts[~has].sum(axis=0)}
    return {"all images": counts.sum(axis=0)}


def plot_histograms(evaluation: xr.Dataset) -> Figure:
    """nRMSE histograms of the images with and without band shots, log count axis (Fig. 7).

    Pixels above the histogram range are stated in the legend (``nrmse_above_range``).
    """
    lower = np.asarray(evaluation["nrmse_bin_lower"].values, dtype=np.float64)
    upper = np.asarray(evaluation["nrmse_bin_upper"].values, dtype=np.float64)
    edges = np.append(lower, upper[-1])
    above = np.asarray(evaluation.get("nrmse_above_range", xr.DataArray(
        np.zeros(evaluation.sizes["image"], dtype=np.int64))).values)
    has = (np.asarray(evaluation["has_band_shots"].values, dtype=bool)
           if "has_band_shots" in evaluation else np.ones(evaluation.sizes["image"], bool))
    figure = Figure(figsize=(7.5, 4.2), layout="constrained")
    ax = figure.subplots()
    for index, (label, counts) in enumerate(_subset_histograms(evaluation).items()):
        outside = int(above[has].sum() if label != "without band shots" else above[~has].sum())
        ax.stairs(np.where(counts > 0, counts, np.nan), edges, color=f"C{index}",
                  linewidth=1.8, label=f"{label} ({int(counts.sum())} px, {outside} above range)")
    threshold = float(evaluation.attrs.get("threshold", 0.03))
    ax.axvline(threshold, color="0.4", linestyle="--", linewidth=1.0,
               label=f"nRMSE = {threshold:g}")
    ax.set_yscale("log")
    ax.set_xlim(edges[0], edges[-1])
    ax.set_xlabel("normalised RMSE")
    ax.set_ylabel("pixel count (log)")
    ax.set_title("nRMSE histogram over all pixels")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return figure


def plot_capture_time(capture: xr.Dataset) -> Figure:
    """Total exposure of the reference and the fast capture, spectral + RGB stacked.

    ``capture`` is the output of :func:`spectralize.nodes.evaluation.capture_time.capture_time`.
    """
    names = [str(c) for c in capture["capture"].values]
    spectral = np.asarray(capture["spectral_time"].values, dtype=np.float64)
    rgb = np.asarray(capture["rgb_time"].values, dtype=np.float64)
    figure = Figure(figsize=(6.0, 4.0), layout="constrained")
    ax = figure.subplots()
    positions = np.arange(len(names))
    given = set(str(capture.attrs.get("given_as_total", "")).split(","))
    as_total = np.array([name in given for name in names])
    measured = np.where(as_total, 0.0, spectral)
    ax.bar(positions, measured, color="C0", label="band shots")
    ax.bar(positions, rgb, bottom=measured, color="C1", label="RGB images")
    if as_total.any():
        ax.bar(positions, np.where(as_total, spectral, 0.0), color="0.6",
               label="total (given as a number)")
    totals = spectral + rgb
    for position, total in zip(positions, totals, strict=True):
        ax.annotate(f"{total:.3g} s", (position, total), ha="center", va="bottom")
    positive = totals[totals > 0]
    if positive.size and positive.max() > 20 * positive.min():  # a 30x bar would be invisible
        ax.set_yscale("log")
        ax.set_ylim(positive.min() / 3, positive.max() * 3)
        ax.set_ylabel("total exposure [s] (log)")
    else:
        ax.set_ylim(0, 1.15 * float(np.max(totals)) if np.max(totals) > 0 else 1.0)
        ax.set_ylabel("total exposure [s]")
    ax.set_xticks(positions, names)
    title = f"speed-up {float(capture['speedup']):.1f}x"
    if "nrmse_median" in capture:
        title += (f" at nRMSE median {float(capture['nrmse_median']):.4f}, "
                  f"p95 {float(capture['nrmse_p95']):.4f}")
    ax.set_title(title)
    ax.legend()
    return figure


# -- HTML ----------------------------------------------------------------------------------
def _e(value: object) -> str:
    return html.escape(str(value), quote=True)


def _fmt(value: float, digits: int = 4) -> str:
    value = float(value)
    return "—" if not np.isfinite(value) else f"{value:.{digits}g}"


def _table(table_id: str, caption: str, header: Sequence[str], rows: Sequence[Sequence[str]]
           ) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "\n".join("<tr>" + "".join(f"<td>{_e(c)}</td>" for c in row) + "</tr>"
                     for row in rows)
    return (f'<table id="{_e(table_id)}">\n<caption>{_e(caption)}</caption>\n'
            f"<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody>\n</table>")


def _figure(figure: Figure, directory: Path, name: str, caption: str) -> str:
    figure.savefig(directory / name, dpi=_DPI)
    stem = Path(name).stem
    return (f'<figure id="{_e(stem)}"><img src="{_e(name)}" alt="{_e(caption)}">'
            f"<figcaption>{_e(caption)}</figcaption></figure>")


_METRIC_LABELS = (("nrmse", "nRMSE"), ("spectral_angle", "spectral angle [°]"),
                  ("delta_e", "CIEDE2000"))


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


def _per_image_rows(evaluation: xr.Dataset) -> tuple[list[str], list[list[str]]]:
    coords = [c for c in ("camera", "rotation", "led", "theta_i", "phi_i", "theta_o", "phi_o")
              if c in evaluation.coords]
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
        for name, stat in (("spectral_angle", "median"), ("delta_e", "median"),
                           ("delta_e", "p95")):
            variable = f"{name}_statistics"
            row.append(_fmt(evaluation[variable][image].sel(statistic=stat))
                       if variable in evaluation else "—")
        row.append(str(int(evaluation["invalid_count"][image]))
                   if "invalid_count" in evaluation else "—")
        rows.append(row)
    return header, rows


def _run_rows(evaluation: xr.Dataset, spectra: xr.Dataset, truth: xr.Dataset,
              run: str | os.PathLike[str] | None) -> list[list[str]]:
    rows = [["run store", str(run) if run is not None else "(not given)"]]
    for role, ds in (("spectra", spectra), ("truth/spectra", truth), ("evaluation", evaluation)):
        fingerprint = ds.attrs.get("spectralize_fingerprint") or evaluation.attrs.get(
            f"{role.split('/')[0]}_fingerprint")
        provenance = ds.attrs.get("spectralize_provenance") or {}
        made_by = (f"{provenance.get('node', '?')} v{provenance.get('version', '?')}"
                   if provenance else "(no provenance)")
        rows.append([f"{role} fingerprint", str(fingerprint) if fingerprint else "(none)"])
        rows.append([f"{role} made by", made_by])
    sizes = spectra["radiance"].sizes
    wavelength = np.asarray(truth["wavelength"].values, dtype=np.float64)
    rows += [
        ["images", str(sizes["image"])],
        ["image size", f"{sizes['y']} x {sizes['x']} px"],
        ["wavelengths", f"{wavelength.size} bands, {wavelength[0]:g}..{wavelength[-1]:g} nm"],
        ["colour difference", f"CIEDE2000 under {evaluation.attrs.get('illuminant', '?')}, "
                              f"{evaluation.attrs.get('observer', 'CIE 1931 2°')}"],
    ]
    return rows


_STYLE = """
body { font-family: sans-serif; margin: 2em; max-width: 1400px; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
caption { text-align: left; font-weight: bold; padding: 0.3em 0; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th { background: #eee; }
td:first-child { text-align: left; }
figure { margin: 1em 0; }
figure img { max-width: 100%; }
figcaption { font-size: 0.9em; color: #444; }
"""


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
        Output of :func:`~spectralize.nodes.evaluation.metrics.evaluate` (the ``evaluation`` group);
        it is computed here.
    spectra, truth
        Groups ``spectra`` and ``truth/spectra`` the evaluation was made from (for the sRGB
        renders and the description of the run).
    directory
        Folder to write ``index.html`` and the figures into (created; files are replaced).
    baselines
        Comparison of methods: the output of
        :func:`~spectralize.nodes.evaluation.metrics.compare_methods` (dim ``reconstruction``), or
        what it accepts (method name -> cube, or ``radiance`` with a ``reconstruction``
        dim), which is then
        evaluated here against ``truth`` (with ``shots``). Table left out when ``None``.
    capture
        Output of :func:`~spectralize.nodes.evaluation.capture_time.capture_time`; the capture-time
        figure and table are left out when ``None``.
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
        Group ``calibration/spectral``; its colour-checker cross-validation (paper Fig. 4) is
        tabulated and drawn.

    Returns
    -------
    pathlib.Path
        The path of ``index.html``.

    Raises
    ------
    SchemaError
        If ``evaluation`` lacks variables that :func:`evaluate` makes.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5, Figures 5-8.
    """
    _check_evaluation(evaluation)
    if int(max_images) < 1:
        raise ValueError(f"max_images: expected >= 1, found {max_images!r}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    evaluation = evaluation.compute()
    n_images = evaluation.sizes["image"]
    shown = list(range(min(n_images, int(max_images))))

    truth_shown = truth["radiance"].isel(image=shown)
    truth_srgb = render_srgb(truth_shown, percentile=exposure_percentile).compute()
    scale = float(truth_srgb.attrs["exposure_scale"])
    recon_srgb = render_srgb(spectra["radiance"].isel(image=shown), exposure=scale).compute()

    finite = np.asarray(evaluation["nrmse"].isel(image=shown).values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    vmax = vmax if vmax > 0 else 1.0

    parts: list[str] = []
    parts.append("<h2>Run</h2>")
    parts.append(_table("run", "What this report describes", ["item", "value"],
                        _run_rows(evaluation, spectra, truth, run)))

    subsets = [str(s) for s in evaluation["subset"].values]
    threshold = float(evaluation.attrs.get("threshold", 0.03))
    parts.append("<h2>Accuracy</h2>")
    parts.append(_table("summary", "Statistics over all pixels of each subset of images",
                        _summary_header(threshold), _summary_rows(evaluation, subsets)))
    header, rows = _per_image_rows(evaluation)
    parts.append(_table("per-image", "Statistics per image", header, rows))

    parts.append("<h2>nRMSE histograms (Figure 7)</h2>")
    parts.append(_figure(plot_histograms(evaluation), directory, "histogram.png",
                         "Histogram of the per-pixel normalised RMSE over all pixels of the "
                         "images with and without band shots; logarithmic count axis."))

    if capture is not None:
        parts.append("<h2>Capture time</h2>")
        rows = [[str(c), _fmt(capture["spectral_time"].sel(capture=c)),
                 _fmt(capture["rgb_time"].sel(capture=c)),
                 _fmt(capture["total_time"].sel(capture=c)),
                 str(int(capture["band_shots"].sel(capture=c)))]
                for c in capture["capture"].values]
        parts.append(_table("capture-time", "Total exposure of the captures [s]; "
                            f"speed-up {float(capture['speedup']):.1f}x. "
                            + str(capture.attrs.get("summary", "")),
                            ["capture", "band shots [s]", "RGB [s]", "total [s]",
                             "band shots"], rows))
        parts.append(_figure(plot_capture_time(capture), directory, "capture_time.png",
                             "Total exposure of the reference and the fast capture."))

    if calibration is not None and "measured_rgb" in calibration:
        from spectralize.nodes.calibration.spectral import plot_cross_validation

        checked = calibration[["measured_rgb", "predicted_rgb", "relative_error"]].compute()
        error = np.asarray(checked["relative_error"].values, dtype=float)
        parts.append("<h2>Calibration cross-validation (Figure 4)</h2>")
        rows = [[str(patch), _fmt(float(e))] for patch, e in
                zip(checked["patch"].values, error, strict=True)]
        parts.append(_table("cross-validation", "RGB of the colour-checker patches predicted "
                            "through C from the spectral camera's capture vs measured: "
                            f"relative error per patch (mean {_fmt(float(np.nanmean(error)))})",
                            ["patch", "relative error"], rows))
        parts.append(_figure(plot_cross_validation(checked.rename(
            measured_rgb="measured", predicted_rgb="predicted")), directory,
            "cross_validation.png", "(a) measured RGB, (b) RGB predicted through C from the "
            "spectral capture, (c) their difference scaled 10x."))

    if baselines is not None:
        table = baselines
        if not (isinstance(table, xr.Dataset) and "nrmse_subset_statistics" in table):
            table = compare_methods(baselines, truth, shots=shots,
                                    illuminant=str(evaluation.attrs.get("illuminant", "D65")),
                                    threshold=threshold)
        table = table.compute()
        header = ["method"] + _summary_header(threshold)[2:]
        rows = [["this run (spectra)"] + _summary_rows(evaluation, ["all"])[0][2:]]
        for method in table[METHOD_DIM].values:
            rows.append([str(method)]
                        + _summary_rows(table.sel({METHOD_DIM: method}), ["all"])[0][2:])
        parts.append("<h2>Baselines</h2>")
        parts.append(_table("baselines", "Comparison of methods on all images of the run",
                            header, rows))

    parts.append("<h2>Error maps and representative spectra (Figures 5 and 6)</h2>")
    parts.append(f"<p>sRGB renders: {_e(truth_srgb.attrs['exposure_normalisation'])} (the "
                 "reconstruction with the same factor). Error maps on a common scale 0.."
                 f"{_fmt(vmax)} (99.5th percentile of the nRMSE of the images shown).</p>")
    if len(shown) < n_images:
        parts.append(f"<p>Figures for the first {len(shown)} of {n_images} images.</p>")
    for image in shown:
        parts.append(f"<h3>{_e(_image_label(evaluation, image))}</h3>")
        parts.append(_figure(
            plot_error_map(evaluation, image,
                           truth_srgb=truth_srgb, reconstruction_srgb=recon_srgb, vmax=vmax),
            directory, f"error_map_{image:03d}.png",
            f"Image {image}: ground truth and reconstruction (sRGB) and the normalised RMSE "
            "map; numbered pixels are the representative spectra."))
        parts.append(_figure(plot_spectra(evaluation, image), directory,
                             f"spectra_{image:03d}.png",
                             f"Image {image}: representative spectra, ground truth solid, "
                             "reconstruction dotted."))

    stamp = time.strftime("%Y-%m-%d %H:%M:%S")
    page = (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<title>{_e(title)}</title>\n<meta name=\"generator\" content=\"spectralize\">\n"
        f"<style>{_STYLE}</style>\n</head>\n<body>\n<h1>{_e(title)}</h1>\n"
        f"<p>Written {stamp}. Method: <em>Fast Capture of Spectral Image Series</em>, "
        "evaluation as in sec. 5 (Figures 5-8).</p>\n" + "\n".join(parts) + "\n</body>\n</html>\n"
    )
    index = directory / "index.html"
    index.write_text(page, encoding="utf-8")
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
    (:func:`~spectralize.nodes.evaluation.capture_time.run_capture_time`); and every
    ``baselines/<method>`` group (the spectra layout) as the baseline table.

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
            capture = capture_time(capture_time_from_run(shots, raw_rgb), reference,
                                   evaluation=evaluation)
    prefix = BASELINES_GROUP + "/"
    baselines = {group[len(prefix):]: run.read(group) for group in run.groups()
                 if group.startswith(prefix)}
    return write_report(
        evaluation, spectra=spectra, truth=truth,
        directory=run.path / "report" if directory is None else directory,
        baselines=baselines or None, capture=capture, shots=shots, run=str(run.path),
        calibration=run.read("calibration/spectral") if run.has("calibration/spectral") else None,
        title=title or f"spectralize: {run.path.name}", max_images=max_images)
