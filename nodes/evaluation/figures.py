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

from spectralize.nodes.evaluation.statistics import DEFAULT_THRESHOLD

__all__ = [
    "ERROR_COLORMAP",
    "image_label",
    "plot_error_map",
    "plot_spectra",
    "nrmse_histograms",
    "plot_histograms",
    "plot_capture_time",
    "plot_pixel_spectra",
    "plot_confidence",
    "PIXEL_KINDS",
    "representative_pixels",
    "plot_camera_spectra",
]

#: Colour map of the error maps: cubehelix (Green, 2011), the paper's choice.
ERROR_COLORMAP: str = "cubehelix"


def image_label(evaluation: xr.Dataset, image: int) -> str:
    """One line naming an image: its label, view and light angles, band shots or not.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.accuracy.evaluate` (or any group with
        an ``image`` dim); its ``image`` coordinate (the image's label in the run store),
        per-image coords ``theta_o, phi_o, theta_i, phi_i`` and variable ``has_band_shots``
        are used where present.
    image
        Position of the image along ``image`` (the label shown is the coordinate's value).

    Returns
    -------
    str
        E.g. ``"image 7, camera 1, view (45°, 15°), light (30°, 0°), with band shots"``.
    """
    coords = evaluation.coords
    label = int(coords["image"].values[image]) if "image" in coords else image
    parts = [f"image {label}"]
    if "camera" in coords and coords["camera"].dims == ("image",):
        parts.append(f"camera {coords['camera'].values[image]}")
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
        Output of :func:`~spectralize.nodes.evaluation.accuracy.evaluate` (computed).
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
        Output of :func:`~spectralize.nodes.evaluation.accuracy.evaluate` (computed), with
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


def nrmse_histograms(evaluation: xr.Dataset, *, bins: int = 60) -> dict[str, dict[str, np.ndarray]]:
    """Normalised nRMSE histograms per subset of images, over *all* their pixels.

    The range is ``0`` to the 99th percentile of the finite nRMSE (at least the evaluation's
    own histogram range); every pixel above it is counted in a last, overflow bin, so the
    fractions of each subset add up to 1.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.accuracy.evaluate` (computed): the
        ``nrmse`` maps when present, else the stored ``nrmse_histogram`` and
        ``nrmse_above_range`` (the overflow).
    bins
        Number of regular bins below the overflow bin (maps only).

    Returns
    -------
    dict
        Subset label -> ``{"edges": (bins + 1,), "fraction": (bins,), "overflow": float,
        "pixels": int}``; fractions of the pixels with a finite nRMSE.
    """
    out: dict[str, dict[str, np.ndarray]] = {}
    subsets = _subsets(evaluation)
    if "nrmse" in evaluation:
        maps = np.asarray(evaluation["nrmse"].values, dtype=np.float64)
        finite = maps[np.isfinite(maps)]
        stored = (
            float(evaluation["nrmse_bin_upper"].values[-1]) if "nrmse_bin_upper" in evaluation else 0.0
        )
        top = float(np.percentile(finite, 99.0)) if finite.size else 1.0
        top = max(top, stored, 1e-6)
        edges = np.linspace(0.0, top, bins + 1)
        for label, mask in subsets.items():
            values = maps[mask].ravel()
            values = values[np.isfinite(values)]
            counts, _ = np.histogram(np.clip(values, 0.0, None), bins=edges)
            counts[-1] -= int(np.sum(values == top))  # the right edge belongs to the overflow
            over = int(np.sum(values >= top))
            total = max(values.size, 1)
            out[label] = {
                "edges": edges,
                "fraction": counts / total,
                "overflow": over / total,
                "pixels": int(values.size),
            }
        return out
    lower = np.asarray(evaluation["nrmse_bin_lower"].values, dtype=np.float64)
    upper = np.asarray(evaluation["nrmse_bin_upper"].values, dtype=np.float64)
    edges = np.append(lower, upper[-1])
    counts = np.asarray(evaluation["nrmse_histogram"].values, dtype=np.int64)
    above = (
        np.asarray(evaluation["nrmse_above_range"].values, dtype=np.int64)
        if "nrmse_above_range" in evaluation
        else np.zeros(evaluation.sizes["image"], dtype=np.int64)
    )
    for label, mask in subsets.items():
        inside, over = counts[mask].sum(axis=0), int(above[mask].sum())
        total = max(int(inside.sum()) + over, 1)
        out[label] = {
            "edges": edges,
            "fraction": inside / total,
            "overflow": over / total,
            "pixels": int(inside.sum()) + over,
        }
    return out


def plot_histograms(evaluation: xr.Dataset) -> Figure:
    """nRMSE histograms of the images with and without band shots, normalised, log axis.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.accuracy.evaluate` (computed); see
        :func:`nrmse_histograms`: the range covers every pixel, the last bar (hatched) is the
        overflow bin of the pixels above the range.

    Returns
    -------
    matplotlib.figure.Figure
        An Agg figure with one step curve per subset (fraction of its pixels per bin), the
        overflow bin as a hatched bar per subset and the ``threshold`` level (attr, default
        0.03) marked.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 and Figure 7 (RMSE histograms of the
    images with and without band shots).
    """
    tables = nrmse_histograms(evaluation)
    figure = Figure(figsize=(7.5, 4.2), layout="constrained")
    ax = figure.subplots()
    top = 0.0
    for index, (label, table) in enumerate(tables.items()):
        edges, fraction = table["edges"], table["fraction"]
        width = edges[1] - edges[0]
        top = edges[-1]
        ax.stairs(
            np.where(fraction > 0, fraction, np.nan),
            edges,
            color=f"C{index}",
            linewidth=1.8,
            label=f"{label} ({table['pixels']} px, {100 * table['overflow']:.2g} % above "
            f"{edges[-1]:.3g})",
        )
        if table["overflow"] > 0:
            ax.bar(
                edges[-1] + (1.5 + index) * width * 2,
                table["overflow"],
                width=width * 2,
                color=f"C{index}",
                alpha=0.5,
                hatch="//",
            )
    threshold = float(evaluation.attrs.get("threshold", DEFAULT_THRESHOLD))
    ax.axvline(threshold, color="0.4", linestyle="--", linewidth=1.0, label=f"nRMSE = {threshold:g}")
    ax.axvline(top, color="0.7", linewidth=0.8)
    ax.annotate(
        "overflow",
        (top, 1.0),
        xycoords=("data", "axes fraction"),
        xytext=(4, -12),
        textcoords="offset points",
        fontsize=8,
        color="0.4",
    )
    ax.set_yscale("log")
    ax.set_xlim(0.0, top * 1.18 if top > 0 else 1.0)
    ax.set_xlabel("normalised RMSE")
    ax.set_ylabel("fraction of pixels (log)")
    ax.set_title("nRMSE histogram over all pixels (last bars: above the range)")
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
        ``capture`` holds them); logarithmic when the totals differ by more than a factor
        of twenty.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 "Real Data" and Figure 8 (226 212 ms
    against 7 463 ms in the paper).
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
    if positive.size and positive.max() > 20 * positive.min():  # else the short bar would be invisible
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


# -- figures of a reconstruction without ground truth ------------------------------------
def plot_pixel_spectra(
    srgb: np.ndarray,
    spectra: np.ndarray,
    pixels: list[tuple[int, int]],
    wavelength: np.ndarray,
    *,
    title: str = "",
) -> Figure:
    """One image (sRGB) with numbered pixels, and the reconstructed spectra at those pixels.

    Parameters
    ----------
    srgb
        (y, x, 3) render in 0..1.
    spectra
        (pixel, wavelength) relative radiance at ``pixels``.
    pixels
        (y, x) of each spectrum.
    wavelength
        [nm].
    title
        Figure title (e.g. :func:`image_label`).
    """
    figure = Figure(figsize=(11.0, 3.8), layout="constrained")
    ax_img, ax_sp = figure.subplots(1, 2, width_ratios=(1, 1.8))
    ax_img.imshow(srgb, interpolation="nearest")
    ax_img.set_xticks([])
    ax_img.set_yticks([])
    for number, ((y, x), spectrum) in enumerate(zip(pixels, spectra, strict=True), start=1):
        colour = f"C{(number - 1) % 10}"
        ax_img.plot([x], [y], marker="o", markersize=7, markerfacecolor="none", markeredgecolor="white")
        ax_img.annotate(
            str(number),
            (x, y),
            xytext=(4, 4),
            textcoords="offset points",
            color="white",
            fontsize=9,
            fontweight="bold",
        )
        ax_sp.plot(wavelength, spectrum, color=colour, label=f"{number}: (y={y}, x={x})")
    ax_sp.set_xlabel("wavelength [nm]")
    ax_sp.set_ylabel("relative radiance")
    ax_sp.legend(fontsize=7)
    ax_sp.grid(alpha=0.3)
    if title:
        figure.suptitle(title, fontsize=10)
    return figure


def plot_confidence(
    confidence: xr.DataArray, *, titles: list[str] | None = None, columns: int = 4
) -> Figure:
    """Maps of the reconstruction's ``confidence`` variable (image, y, x), one colour scale
    spanning its 2nd to 98th percentile (values beyond are clipped)."""
    conf = confidence
    if "wavelength" in conf.dims:
        conf = conf.mean("wavelength")
    n = conf.sizes["image"]
    columns = max(1, min(columns, n))
    rows = -(-n // columns)
    figure = Figure(figsize=(3.0 * columns + 0.8, 3.0 * rows), layout="constrained")
    axes = np.atleast_1d(figure.subplots(rows, columns)).ravel()
    values = np.asarray(conf.transpose("image", "y", "x").values, dtype=np.float64)
    finite = values[np.isfinite(values)]
    # the 2nd to 98th percentile: a few outliers do not darken every map
    lo, hi = (float(v) for v in np.percentile(finite, (2, 98))) if finite.size else (0.0, 1.0)
    labels = conf["image"].values if "image" in conf.coords else np.arange(n)
    shown = None
    for k, ax in enumerate(axes):
        ax.set_xticks([])
        ax.set_yticks([])
        if k >= n:
            ax.set_axis_off()
            continue
        shown = ax.imshow(values[k], cmap="viridis", vmin=lo, vmax=hi if hi > lo else lo + 1)
        ax.set_title(titles[k] if titles else f"image {int(labels[k])}", fontsize=8)
    if shown is not None:
        figure.colorbar(
            shown, ax=list(axes), shrink=0.8, label=str(confidence.attrs.get("long_name", "confidence"))
        )
    return figure


#: What :func:`representative_pixels` picks per camera: a name and the brightness percentile
#: (``None``: the least trustworthy pixel, the highest estimated nRMSE of ``confidence``).
PIXEL_KINDS: tuple[tuple[str, float | None], ...] = (
    ("near saturation", 99.9),
    ("typical", 50.0),
    ("dark", 2.0),
    ("least confident", None),
)


def representative_pixels(
    brightness: np.ndarray, confidence: np.ndarray | None = None
) -> list[tuple[str, int, int, int]]:
    """Pixels that show the range of one camera's images: ``(kind, image, y, x)``.

    The pixel nearest each brightness percentile of :data:`PIXEL_KINDS` (near saturation,
    typical, dark) and, with ``confidence`` (estimated nRMSE, higher: trust less), the
    least confident pixel.

    Parameters
    ----------
    brightness
        ``(image, y, x)`` mean radiance over wavelength of the camera's images.
    confidence
        ``(image, y, x)`` estimated nRMSE, or ``None``.
    """
    picks = []
    finite = np.isfinite(brightness)
    if not finite.any():
        return picks
    for kind, percentile in PIXEL_KINDS:
        if percentile is None:
            if confidence is None or not np.isfinite(confidence).any():
                continue
            flat = int(np.nanargmax(np.where(finite, confidence, np.nan)))
        else:
            level = np.percentile(brightness[finite], percentile)
            flat = int(np.nanargmin(np.where(finite, np.abs(brightness - level), np.nan)))
        picks.append((kind, *(int(v) for v in np.unravel_index(flat, brightness.shape))))
    return picks


def plot_camera_spectra(
    panels: list[tuple[str, list[tuple[str, np.ndarray]]]], wavelength: np.ndarray
) -> Figure:
    """Reconstructed spectra at chosen pixels, one panel per camera, one scale for all.

    Parameters
    ----------
    panels
        Per camera: its title and ``(legend label, spectrum)`` pairs (the label names the
        kind of pixel, its image and position; see :func:`representative_pixels`).
    wavelength
        [nm].
    """
    columns = max(1, len(panels))
    width = 3.6 * columns + 0.6
    figure = Figure(figsize=(width, 4.6))  # a fixed layout: drawn in a fraction of the time
    figure.subplots_adjust(left=0.6 / width, right=0.99, bottom=0.32, top=0.93, wspace=0.06)
    axes = np.atleast_1d(figure.subplots(1, columns, sharey=True))
    styles = {kind: f"C{i}" for i, (kind, _) in enumerate(PIXEL_KINDS)}
    for ax, (title, lines) in zip(axes, panels, strict=True):
        for label, spectrum in lines:
            kind = label.split(":")[0]
            ax.plot(wavelength, spectrum, color=styles.get(kind, "0.3"), label=label)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("wavelength [nm]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6.5, loc="upper left", bbox_to_anchor=(0.0, -0.16), frameon=False)
    axes[0].set_ylabel("relative radiance")
    return figure
