"""Figures of an evaluation (paper Figures 5-8): data in, matplotlib Figure out.

Every function takes computed results (xarray) and returns a :class:`matplotlib.figure.Figure`
made on matplotlib's Agg canvas: no pyplot state, no display and no file I/O. Writing them
(and the HTML around them) is :mod:`spectralize.flows.report`'s job.

- :func:`plot_error_map` (Figures 5 and 6): the ground truth and the reconstruction rendered
  to sRGB (:func:`~spectralize.nodes.evaluation.colorimetry.render_srgb`) next to the
  normalised RMSE map in the cubehelix colour map (Green, 2011, as in the paper), with the
  representative pixels numbered;
- :func:`plot_spectra` (Figures 5 and 6, insets): those pixels' spectra, truth solid,
  reconstruction dotted;
- :func:`plot_histograms` (Figure 7): nRMSE histograms over all pixels of the images with and
  without band shots, logarithmic count axis, the 0.03 level marked;
- :func:`plot_capture_time` (sec. 5 "Real Data", Figure 8): total exposure of the reference and
  the fast capture, band shots + RGB stacked, with the speed-up and the accuracy reached.

References
----------
Fast Capture of Spectral Image Series, sec. 5, Figures 5, 6, 7 and 8. Green, D. A. (2011).
A colour scheme for the display of astronomical intensity images. Bull. Astr. Soc. India 39.
"""

from __future__ import annotations

import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from spectralize.nodes.evaluation.metrics import DEFAULT_THRESHOLD

__all__ = [
    "ERROR_COLORMAP",
    "image_label",
    "plot_error_map",
    "plot_spectra",
    "plot_histograms",
    "plot_capture_time",
]

#: Colour map of the error maps: cubehelix (Green, 2011), the paper's choice.
ERROR_COLORMAP: str = "cubehelix"


def image_label(evaluation: xr.Dataset, image: int) -> str:
    """One line naming an image: its position, view and light angles, band shots or not.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.metrics.evaluate`; its per-image
        coords ``theta_o, phi_o, theta_i, phi_i`` and variable ``has_band_shots`` are used
        where present.
    image
        Position of the image along ``image``.

    Returns
    -------
    str
        E.g. ``"image 1, view (45°, 15°), light (30°, 0°), with band shots"``.
    """
    parts = [f"image {image}"]
    coords = evaluation.coords
    if "theta_o" in coords and "phi_o" in coords:
        parts.append(
            f"view ({float(coords['theta_o'][image]):.0f}°, {float(coords['phi_o'][image]):.0f}°)"
        )
    if "theta_i" in coords and "phi_i" in coords:
        parts.append(
            f"light ({float(coords['theta_i'][image]):.0f}°, {float(coords['phi_i'][image]):.0f}°)"
        )
    if "has_band_shots" in evaluation:
        parts.append(
            "with band shots" if bool(evaluation["has_band_shots"][image]) else "without band shots"
        )
    return ", ".join(parts)


def _mark_samples(ax: Axes, evaluation: xr.Dataset, image: int) -> None:
    ys = np.asarray(evaluation["sample_y"][image].values)
    xs = np.asarray(evaluation["sample_x"][image].values)
    for number, (y, x) in enumerate(zip(ys, xs, strict=True), start=1):
        if y < 0:  # an image without finite nRMSE has no picked pixels
            continue
        ax.plot(
            [x],
            [y],
            marker="o",
            markersize=7,
            markerfacecolor="none",
            markeredgecolor="white",
            markeredgewidth=1.5,
        )
        ax.annotate(
            str(number),
            (x, y),
            xytext=(4, 4),
            textcoords="offset points",
            color="white",
            fontsize=9,
            fontweight="bold",
        )


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
        Renders (image, y, x, channel) from
        :func:`~spectralize.nodes.evaluation.colorimetry.render_srgb`; the reconstruction
        panel is left out when ``None``.
    vmax
        Upper end of the colour scale (default: the image's largest nRMSE).

    Returns
    -------
    matplotlib.figure.Figure
        An Agg figure (not registered with pyplot): truth, [reconstruction,] nRMSE map in
        :data:`ERROR_COLORMAP` with a colour bar; the representative pixels are numbered.

    References
    ----------
    Fast Capture of Spectral Image Series, Figures 5 and 6 (normalised RMSE maps).
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
    shown = axes[-1].imshow(nrmse, cmap=ERROR_COLORMAP, vmin=0.0, vmax=top, interpolation="nearest")
    axes[-1].set_title("normalised RMSE")
    _mark_samples(axes[-1], evaluation, image)
    figure.colorbar(shown, ax=axes[-1], shrink=0.85, label="nRMSE")
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    figure.suptitle(image_label(evaluation, image))
    return figure


def plot_spectra(evaluation: xr.Dataset, image: int) -> Figure:
    """Representative spectra of one image: truth solid, reconstruction dotted.

    The curves are numbered like the markers of :func:`plot_error_map`; the legend gives
    each pixel's position, nRMSE and the quantile of the nRMSE map it was picked at.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.metrics.evaluate` (computed), with
        the representative pixels ``sample_*``.
    image
        Position of the image along ``image``.

    Returns
    -------
    matplotlib.figure.Figure
        An Agg figure: two lines per picked pixel (truth ``-``, reconstruction ``:``).

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 and Figures 5 and 6 (representative
    spectra picked at low and high RMSE).
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
    for number in range(truth.shape[0]):
        if ys[number] < 0:
            continue
        colour = f"C{number % 10}"
        label = (
            f"{number + 1}: (y={ys[number]}, x={xs[number]}) nRMSE {errors[number]:.4f} "
            f"(q={quantiles[number]:g})"
        )
        ax.plot(wavelength, truth[number], "-", color=colour, label=label)
        ax.plot(wavelength, recon[number], ":", color=colour, linewidth=2.0)
    ax.set_xlabel("wavelength [nm]")
    ax.set_ylabel("relative radiance")
    ax.set_title(
        f"{image_label(evaluation, image)}\ntruth (solid), reconstruction (dotted)", fontsize=10
    )
    ax.legend(fontsize=7, loc="best")
    ax.grid(alpha=0.3)
    return figure


def _subsets(evaluation: xr.Dataset) -> dict[str, np.ndarray]:
    """Label -> boolean mask over ``image`` of the histograms drawn."""
    n_images = evaluation.sizes["image"]
    if "has_band_shots" in evaluation:
        has = np.asarray(evaluation["has_band_shots"].values, dtype=bool)
        return {"with band shots": has, "without band shots": ~has}
    return {"all images": np.ones(n_images, dtype=bool)}


def plot_histograms(evaluation: xr.Dataset) -> Figure:
    """nRMSE histograms of the images with and without band shots, log count axis.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.metrics.evaluate` (computed): the
        per-image ``nrmse_histogram`` is summed over each subset of images; pixels above the
        histogram range (``nrmse_above_range``) are stated in the legend.

    Returns
    -------
    matplotlib.figure.Figure
        An Agg figure with one step curve per subset and the ``threshold`` level (attr,
        default 0.03) marked.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 and Figure 7 (RMSE histograms of the
    images with and without band shots).
    """
    lower = np.asarray(evaluation["nrmse_bin_lower"].values, dtype=np.float64)
    upper = np.asarray(evaluation["nrmse_bin_upper"].values, dtype=np.float64)
    edges = np.append(lower, upper[-1])
    counts = np.asarray(evaluation["nrmse_histogram"].values, dtype=np.int64)
    above = (
        np.asarray(evaluation["nrmse_above_range"].values, dtype=np.int64)
        if "nrmse_above_range" in evaluation
        else np.zeros(evaluation.sizes["image"], dtype=np.int64)
    )
    figure = Figure(figsize=(7.5, 4.2), layout="constrained")
    ax = figure.subplots()
    for index, (label, mask) in enumerate(_subsets(evaluation).items()):
        total = counts[mask].sum(axis=0)
        ax.stairs(
            np.where(total > 0, total, np.nan),
            edges,
            color=f"C{index}",
            linewidth=1.8,
            label=f"{label} ({int(total.sum())} px, {int(above[mask].sum())} above range)",
        )
    threshold = float(evaluation.attrs.get("threshold", DEFAULT_THRESHOLD))
    ax.axvline(threshold, color="0.4", linestyle="--", linewidth=1.0, label=f"nRMSE = {threshold:g}")
    ax.set_yscale("log")
    ax.set_xlim(edges[0], edges[-1])
    ax.set_xlabel("normalised RMSE")
    ax.set_ylabel("pixel count (log)")
    ax.set_title("nRMSE histogram over all pixels")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3, which="both")
    return figure


def plot_capture_time(capture: xr.Dataset) -> Figure:
    """Total exposure of the reference and the fast capture, band shots + RGB stacked.

    Parameters
    ----------
    capture
        Output of :func:`~spectralize.nodes.evaluation.capture_time.capture_time`. Captures
        named in its attr ``given_as_total`` are drawn as one grey bar.

    Returns
    -------
    matplotlib.figure.Figure
        An Agg bar chart, titled with the speed-up (and the nRMSE median and p95 when
        ``capture`` holds them); logarithmic when the totals differ by more than 20x.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 "Real Data" and Figure 8 (226 212 ms
    against 7 463 ms).
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
        ax.bar(
            positions, np.where(as_total, spectral, 0.0), color="0.6", label="total (given as a number)"
        )
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
        title += (
            f" at nRMSE median {float(capture['nrmse_median']):.4f}, "
            f"p95 {float(capture['nrmse_p95']):.4f}"
        )
    ax.set_title(title)
    ax.legend()
    return figure
