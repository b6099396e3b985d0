"""Figures of the calibration (paper Fig. 2, 3, 4): drawing only, no calibration science.

The numbers come from :func:`spectralize.nodes.calibration.cross_validation.cross_validate` (or the
``calibration/spectral`` group); this module turns them into a matplotlib figure built without
pyplot (no global state).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 and Fig. 4.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = [
    "RESPONSE_FILTER_SIZES",
    "plot_cross_validation",
    "response_histograms",
    "plot_response_histograms",
    "plot_exposure_plan",
    "plot_oecf",
    "plot_quantum_efficiency",
    "plot_flat_field",
    "CROSS_VALIDATION_FLAG",
    "MODEL_DIFFERENCE_FLAG",
    "camera_calibration_rows",
    "plot_camera_matrices",
    "plot_registration",
    "patch_names",
    "registration_precision",
]


def plot_cross_validation(
    table: xr.Dataset, *, columns: int = 6, difference_scale: float = 10.0
) -> Figure:
    """Figure in the style of the paper's Fig. 4 from a cross-validation table.

    Panels: (a) measured RGB of the patches, (b) RGB predicted through ``C``, (c) the
    difference scaled by ``difference_scale`` (around mid grey), (d) relative error per
    patch. Swatches are normalised by the brightest measured value and gamma-encoded (1/2.2)
    for display only.

    Parameters
    ----------
    table
        ``measured``, ``predicted`` (patch, channel) and ``relative_error`` (patch), attrs
        ``mean_relative_error`` and ``max_relative_error``: a
        :func:`~spectralize.nodes.calibration.cross_validation.cross_validate` table.
    columns
        Swatches per row.
    difference_scale
        Gain of panel (c).

    Returns
    -------
    matplotlib.figure.Figure
        Built without pyplot (no global state; saving uses the Agg canvas).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, Fig. 4.
    """
    from matplotlib.figure import Figure

    measured = np.asarray(table["measured"].transpose("patch", "channel").values, dtype=float)
    predicted = np.asarray(table["predicted"].transpose("patch", "channel").values, dtype=float)
    n = measured.shape[0]
    rows = -(-n // columns)
    scale = max(float(np.nanmax(measured)), 1e-300)

    def grid(values: np.ndarray, fill: float) -> np.ndarray:
        out = np.full((rows * columns, values.shape[1]), fill)
        out[:n] = values
        return out.reshape(rows, columns, values.shape[1])[..., :3]

    def encode(values: np.ndarray) -> np.ndarray:
        return np.clip(values / scale, 0, 1) ** (1 / 2.2)

    diff = np.clip(0.5 + difference_scale * (predicted - measured) / scale, 0, 1)
    fig = Figure(figsize=(12, 7), layout="constrained")
    spec = fig.add_gridspec(2, 3)
    panels = [
        (encode(measured), "(a) measured RGB"),
        (encode(predicted), "(b) predicted C S"),
        (diff, f"(c) difference x{difference_scale:g}"),
    ]
    for column, (image, title) in enumerate(panels):
        ax = fig.add_subplot(spec[0, column])
        ax.imshow(grid(image, 1.0), interpolation="nearest")
        ax.set_title(title)
        ax.set_axis_off()
    bar = fig.add_subplot(spec[1, :])
    labels = patch_names(table["relative_error"])
    bar.bar(np.arange(n), 100 * np.asarray(table["relative_error"].values), color="0.4")
    bar.set_xticks(np.arange(n), labels, rotation=90, fontsize=7)  # upright boxes: no overlap
    bar.set_ylabel("relative error [%]")
    bar.set_title(
        f"(d) per patch: mean {100 * table.attrs.get('mean_relative_error', np.nan):.2f}"
        f" %, max {100 * table.attrs.get('max_relative_error', np.nan):.2f} %"
    )
    return fig


def patch_names(values: xr.DataArray) -> list[str]:
    """The colour-checker patches' names (coordinate ``patch_name``), else their indices."""
    for name in ("patch_name", "patch"):
        if name in values.coords:
            return [str(p) for p in values[name].values]
    return [str(i) for i in range(values.sizes["patch"])]


# -- figures of a run without ground truth: calibration (paper Fig. 2, 3), OECF, QE, registration
#: Filter sizes [px] of the response histograms (paper Fig. 2): unfiltered, then increasing.
RESPONSE_FILTER_SIZES: tuple[float, ...] = (0.0, 5.0, 10.0, 20.0)


def response_histograms(
    frames: xr.DataArray,
    *,
    filter_sizes: tuple[float, ...] = RESPONSE_FILTER_SIZES,
    offset: float = 30.0,
    bins: int = 80,
) -> xr.Dataset:
    """Histograms of dark-subtracted frames after Gaussian filters of increasing size (Fig. 2).

    Parameters
    ----------
    frames
        Dark-subtracted frames (exposure_time, y, x) [DN] of a low-signal exposure series.
    filter_sizes
        Filter sizes ``s`` [px]; ``sigma = s / 5`` (``0``: unfiltered). Only pixels whose
        kernel lies inside the frame are counted.
    offset
        Added to the values (the paper shows values offset by 30, so that negative values
        after dark subtraction stay visible).
    bins
        Number of bins, over the range of the unfiltered values.

    Returns
    -------
    xarray.Dataset
        ``density`` (filter_size, exposure_time, bin) [1/DN], coords ``bin_lower``,
        ``bin_upper`` (bin) [DN] and ``mean`` (filter_size, exposure_time) [DN].

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and Fig. 2.
    """
    from scipy.ndimage import gaussian_filter

    from spectralize.nodes.filter_size import filter_radius, filter_sigma

    values = np.asarray(frames.transpose("exposure_time", "y", "x").values, dtype=np.float64) + offset
    finite = values[np.isfinite(values)]
    lo, hi = np.percentile(finite, [0.1, 99.9]) if finite.size else (0.0, 1.0)
    edges = np.linspace(lo, hi if hi > lo else lo + 1.0, bins + 1)
    density = np.zeros((len(filter_sizes), values.shape[0], bins))
    means = np.zeros((len(filter_sizes), values.shape[0]))
    for i, size in enumerate(filter_sizes):
        radius = int(np.ceil(filter_radius(size))) if size > 0 else 0
        for j, frame in enumerate(values):
            out = gaussian_filter(frame, filter_sigma(size), mode="nearest") if size > 0 else frame
            if radius and min(out.shape) > 2 * radius:
                out = out[radius:-radius, radius:-radius]
            density[i, j], _ = np.histogram(out, bins=edges, density=True)
            means[i, j] = float(np.nanmean(out))
    return xr.Dataset(
        {
            "density": (("filter_size", "exposure_time", "bin"), density, {"units": "1/DN"}),
            "mean": (("filter_size", "exposure_time"), means, {"units": "DN"}),
        },
        coords={
            "filter_size": ("filter_size", np.asarray(filter_sizes, dtype=float), {"units": "px"}),
            "exposure_time": frames["exposure_time"].values,
            "bin_lower": ("bin", edges[:-1], {"units": "DN"}),
            "bin_upper": ("bin", edges[1:], {"units": "DN"}),
        },
        attrs={"offset": float(offset)},
    )


def plot_response_histograms(histograms: xr.Dataset, *, title: str = "") -> Figure:
    """Fig. 2: one panel per filter size, one histogram per exposure time.

    Parameters
    ----------
    histograms
        Output of :func:`response_histograms`.
    title
        Figure title (e.g. which band and camera).
    """
    from matplotlib.figure import Figure

    sizes = histograms["filter_size"].values
    fig = Figure(figsize=(3.2 * len(sizes), 3.4), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(sizes), sharex=True))
    lower = histograms["bin_lower"].values
    upper = histograms["bin_upper"].values
    edges = np.append(lower, upper[-1])
    offset = float(histograms.attrs.get("offset", 0.0))
    for ax, size in zip(axes, sizes, strict=True):
        for k, t in enumerate(histograms["exposure_time"].values):
            ax.stairs(
                histograms["density"].sel(filter_size=size).isel(exposure_time=k).values,
                edges,
                color=f"C{k % 10}",
                label=f"{float(t) * 1e3:.3g} ms",
            )
        ax.axvline(offset, color="0.5", linestyle=":", linewidth=1)
        ax.set_title("unfiltered" if size == 0 else f"filter size {size:g} px")
        ax.set_xlabel(f"dark-subtracted value + {offset:g} [DN]")
    axes[0].set_ylabel("density")
    axes[0].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    return fig


def plot_exposure_plan(
    plan: xr.Dataset,
    *,
    quantum_efficiency: xr.DataArray | None = None,
    illuminant: xr.DataArray | None = None,
) -> Figure:
    """Fig. 3: exposure time and filter size per band, with Q and L when given.

    Parameters
    ----------
    plan
        Group ``raw/exposure_plan``: ``exposure_time`` and ``filter_size`` (wavelength).
    quantum_efficiency, illuminant
        Relative quantum efficiency and illuminant (wavelength), drawn above the bars
        (normalised to their maxima).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 2, 3 and Fig. 3.
    """
    from matplotlib.figure import Figure

    curves = [
        (n, c)
        for n, c in (("quantum efficiency Q", quantum_efficiency), ("illuminant L", illuminant))
        if c is not None
    ]
    rows = 2 + bool(curves)
    fig = Figure(figsize=(8.0, 2.4 * rows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(rows, 1, sharex=True))
    wl = np.asarray(plan["wavelength"].values, dtype=float)
    width = 0.8 * (np.min(np.diff(wl)) if wl.size > 1 else 10.0)
    if curves:
        for k, (name, curve) in enumerate(curves):
            values = np.asarray(curve.values, dtype=float)
            top = np.nanmax(values) if np.isfinite(values).any() and np.nanmax(values) > 0 else 1.0
            axes[0].plot(curve["wavelength"].values, values / top, color=f"C{k + 2}", label=name)
        axes[0].set_ylabel("relative")
        axes[0].legend(fontsize=8)
        axes[0].set_title("calibration: Q and L (normalised)")
    axes[-2].bar(wl, plan["exposure_time"].values, width=width, color="C0")
    axes[-2].set_ylabel("exposure time [s]")
    axes[-2].set_title(
        f"exposure times (eq. 2), total {float(np.sum(plan['exposure_time'].values)):.3g} s"
    )
    axes[-1].bar(wl, plan["filter_size"].values, width=width, color="C1")
    axes[-1].set_ylabel("filter size [px]")
    axes[-1].set_title("filter sizes s_i (eq. 3), sigma = s_i / 5")
    axes[-1].set_xlabel("wavelength [nm]")
    return fig


def plot_oecf(oecf_rgb: xr.Dataset | None, oecf_spectral: xr.Dataset | None) -> Figure:
    """Recovered camera responses: relative exposure per code, RGB per camera and channel, and
    the spectral camera's (low-SNR extension joined to Robertson)."""
    from matplotlib.figure import Figure

    panels = [p for p in (oecf_rgb, oecf_spectral) if p is not None]
    fig = Figure(figsize=(5.2 * max(1, len(panels)), 3.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, max(1, len(panels))))
    k = 0
    if oecf_rgb is not None:
        ax = axes[k]
        k += 1
        response = oecf_rgb["response"]
        colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
        for c, camera in enumerate(response["camera"].values):
            for channel in response["channel"].values:
                curve = response.sel(camera=camera, channel=channel)
                ax.plot(
                    curve["code"].values,
                    curve.values,
                    color=colours.get(str(channel), "0.3"),
                    linestyle=("-", "--", ":", "-.")[c % 4],
                    linewidth=1.2,
                    label=f"camera {camera} {channel}",
                )
        ax.set_yscale("log")
        ax.set_xlabel("code [DN]")
        ax.set_ylabel("relative exposure")
        ax.set_title(
            f"RGB OECF (black level {oecf_rgb.attrs.get('black_level', '?')}, "
            f"saturation {oecf_rgb.attrs.get('saturation', '?')})"
        )
        ax.legend(fontsize=6, ncol=2)
    if oecf_spectral is not None:
        ax = axes[k]
        response = oecf_spectral["response"]
        positive = response.values > 0
        ax.plot(response["code"].values[positive], response.values[positive], color="0.2")
        ax.set_yscale("log")
        ax.set_xlabel("code above dark [DN]")
        ax.set_ylabel("relative exposure")
        ax.set_title(
            f"spectral camera OECF (low-SNR series at {oecf_spectral.attrs.get('band', '?')} nm)"
        )
    for ax in axes:
        ax.grid(alpha=0.3, which="both")
    return fig


def plot_quantum_efficiency(calibration: xr.Dataset) -> Figure:
    """Relative quantum efficiency per band and the rows of the RGB camera matrix ``C``."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10.0, 3.6), layout="constrained")
    ax_q, ax_c = fig.subplots(1, 2)
    q = calibration["quantum_efficiency"]
    ax_q.plot(q["wavelength"].values, q.values, "o-", color="0.2", markersize=3)
    ax_q.set_xlabel("wavelength [nm]")
    ax_q.set_ylabel("relative QE")
    ax_q.set_title("spectral camera: quantum efficiency Q")
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
    matrix = calibration["camera_matrix"]
    for channel in matrix["channel"].values:
        row = matrix.sel(channel=channel)
        ax_c.plot(
            row["wavelength"].values,
            row.values,
            color=colours.get(str(channel), "0.3"),
            label=str(channel),
        )
    ax_c.set_xlabel("wavelength [nm]")
    ax_c.set_title("RGB camera matrix C (rows)")
    ax_c.legend(fontsize=8)
    for ax in (ax_q, ax_c):
        ax.grid(alpha=0.3)
    return fig


FLAT_FIELD_SAMPLES = 96
"""Points per frame side at which a falloff map is drawn (the maps are smooth)."""


def plot_flat_field(calibration: xr.Dataset, *, max_cameras: int = 6) -> Figure | None:
    """Falloff maps of the RGB cameras and the spectral camera's per-band profile.

    One panel per RGB camera (at most ``max_cameras``): its flat field (mean over channels,
    1 at the frame centre) with its corner value and noise floor; one panel of the spectral
    camera's map at its middle band; one panel of the spectral camera's flat field along the
    frame diagonal (corner to corner), one curve per band coloured by wavelength. ``None``
    where ``calibration/spectral`` has no flat field.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (white reference) and eq. 5.
    """
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    from spectralize.nodes.calibration.flat_field_maps import from_calibration

    rgb, bands = from_calibration(calibration, "rgb"), from_calibration(calibration, "spectral")
    if rgb is None or bands is None:
        return None
    ny, nx = bands.frame
    sample = (
        slice(0, ny, max(1, ny // FLAT_FIELD_SAMPLES)),
        slice(0, nx, max(1, nx // FLAT_FIELD_SAMPLES)),
    )
    cameras = list(range(min(len(rgb.keys), max_cameras)))
    names = (
        [str(v) for v in calibration["camera_name"].values]
        if "camera_name" in calibration.coords
        else [str(k) for k in rgb.keys]
    )
    maps = [rgb.maps([k], *sample)[0].mean(axis=-1) for k in cameras]
    middle = len(bands.keys) // 2
    maps.append(bands.maps([middle], *sample)[0])
    low = min(0.5, min(float(m.min()) for m in maps))
    fig = Figure(figsize=(2.6 * (len(maps) + 1.6), 3.0), layout="constrained")
    axes = fig.subplots(1, len(maps) + 1, gridspec_kw={"width_ratios": [1] * len(maps) + [1.6]})
    noise_rgb = calibration.get("flat_field_rgb_noise")
    for i, (ax, image) in enumerate(zip(axes[:-1], maps, strict=True)):
        shown = ax.imshow(image, vmin=low, vmax=1.02, cmap="magma", extent=(0, nx, ny, 0))
        ax.contour(
            np.linspace(0, nx, image.shape[1]),
            np.linspace(0, ny, image.shape[0]),
            image,
            levels=np.arange(0.5, 1.0, 0.05),
            colors="w",
            linewidths=0.5,
        )
        corners = image[[0, 0, -1, -1], [0, -1, 0, -1]].mean()
        if i < len(cameras):
            floor = (
                float(np.nanmax(noise_rgb.isel(camera=i).values)) if noise_rgb is not None else np.nan
            )
            title = f"camera {names[i]}\ncorners {corners:.2f}, noise {100 * floor:.2f} %"
        else:
            title = f"spectral, {float(bands.keys[middle]):g} nm\ncorners {corners:.2f}"
        ax.set_title(title, fontsize=8)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(shown, ax=axes[:-1].tolist(), shrink=0.8, label="flat field (1 at the centre)")
    steps = max(ny, nx)
    diagonal = (
        np.linspace(0, ny - 1, steps).round().astype(int),
        np.linspace(0, nx - 1, steps).round().astype(int),
    )
    full = bands.maps(np.arange(len(bands.keys)))[:, diagonal[0], diagonal[1]]
    wavelength = np.asarray(bands.keys, dtype=float)
    colour = colormaps["viridis"]((wavelength - wavelength.min()) / max(np.ptp(wavelength), 1e-9))
    position = np.linspace(-1.0, 1.0, steps)
    ax = axes[-1]
    for row in range(len(wavelength)):
        ax.plot(position, full[row], color=colour[row], linewidth=0.8)
    ax.set_xlabel("frame diagonal (corner to corner)")
    ax.set_ylabel("flat field")
    ax.set_title(
        f"spectral camera per band ({wavelength.min():g} nm violet .. {wavelength.max():g} nm yellow)",
        fontsize=8,
    )
    ax.grid(alpha=0.3)
    return fig


CROSS_VALIDATION_FLAG = 0.03
"""A camera whose chart cross-validation (mean over patches) exceeds this is flagged."""
MODEL_DIFFERENCE_FLAG = 0.05
"""A camera whose ``C`` differs from every other camera's of its model by more than this (per
channel, RMS over wavelength after one scale per channel, relative to the peak) is flagged."""


def _shape_difference(c: np.ndarray, other: np.ndarray) -> float:
    """Largest per-channel RMS of ``s c - other`` relative to ``other``'s peak."""
    scale = (c * other).sum(1) / np.maximum((c * c).sum(1), 1e-30)
    rms = np.sqrt(np.mean((scale[:, None] * c - other) ** 2, axis=1))
    return float(np.max(rms / np.maximum(other.max(1), 1e-30)))


def camera_calibration_rows(calibration: xr.Dataset) -> list[dict]:
    """Per RGB camera: its name, model, where its ``C`` comes from, the chart cross-validation
    and the difference of its ``C`` from the closest other camera's of its model, with flags.

    Flagged: a cross-validation above :data:`CROSS_VALIDATION_FLAG`, a ``C`` more than
    :data:`MODEL_DIFFERENCE_FLAG` from every other camera's of the same model (each fitted
    from its own chart frames; with two cameras of a model both are flagged, as either may
    be the one off). Empty for a calibration without per-camera results.
    """
    if "camera_matrices" not in calibration:
        return []
    names = [str(v) for v in calibration["camera_name"].values]
    models = (
        [str(v) for v in calibration["camera_model"].values]
        if "camera_model" in calibration.coords
        else [""] * len(names)
    )
    sources = [str(v) for v in calibration["c_source"].values]
    matrices = np.asarray(calibration["camera_matrices"].values, float)
    rows = []
    for k, name in enumerate(names):
        own = sources[k] == "own chart frames"
        peers = [
            j
            for j in range(len(names))
            if j != k and models[k] and models[j] == models[k] and sources[j] == "own chart frames"
        ]
        difference = (
            min(_shape_difference(matrices[k], matrices[j]) for j in peers) if own and peers else None
        )
        mean = float(calibration["camera_mean_relative_error"].values[k])
        flags = []
        if mean > CROSS_VALIDATION_FLAG:
            flags.append(f"cross-validation above {100 * CROSS_VALIDATION_FLAG:g} %")
        if difference is not None and difference > MODEL_DIFFERENCE_FLAG:
            flags.append(f"C differs from its model's by more than {100 * MODEL_DIFFERENCE_FLAG:g} %")
        rows.append(
            {
                "camera": name,
                "model": models[k] or "—",
                "c_source": sources[k],
                "mean_relative_error": mean,
                "max_relative_error": float(calibration["camera_max_relative_error"].values[k]),
                "model_difference": difference,
                "flags": flags,
            }
        )
    return rows


def plot_camera_matrices(calibration: xr.Dataset) -> Figure:
    """The rows of ``C`` of every RGB camera side by side (each normalised to its peak),
    titled with its model and chart cross-validation."""
    from matplotlib.figure import Figure

    matrices = calibration["camera_matrices"]
    n = matrices.sizes["camera"]
    fig = Figure(figsize=(3.4 * n + 0.6, 3.2), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, n, sharey=True))
    colours = {"R": "tab:red", "G": "tab:green", "B": "tab:blue"}
    rows = camera_calibration_rows(calibration)
    for ax, k, row in zip(axes, range(n), rows, strict=True):
        matrix = matrices.isel(camera=k)
        peak = float(np.nanmax(matrix.values)) or 1.0
        for channel in matrix["channel"].values:
            line = matrix.sel(channel=channel)
            ax.plot(
                line["wavelength"].values,
                line.values / peak,
                color=colours.get(str(channel), "0.3"),
                label=str(channel),
            )
        title = f"{row['camera']} ({row['model']})\nchart {100 * row['mean_relative_error']:.1f} %"
        ax.set_title(title + (" [flagged]" if row["flags"] else ""), fontsize=9)
        ax.set_xlabel("wavelength [nm]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("C / its peak")
    axes[0].legend(fontsize=8)
    return fig


def registration_precision(registration: xr.Dataset) -> float:
    """The step [px] of the shift estimate (1 / the upsampling factor of its phase
    correlation): differences below it are not measured."""
    factor = registration.attrs.get("upsample_factor")
    return 1.0 / float(factor) if factor else 0.0


def plot_registration(registration: xr.Dataset) -> Figure:
    """Shift per rotation pair (phase correlation) around the run's shift, and each pair's
    residual from it against the estimate's precision (1 / upsampling factor): a residual
    below that step is no measured disagreement, and the panel says so."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import FormatStrFormatter, MaxNLocator

    fig = Figure(figsize=(10.0, 3.6), layout="constrained")
    ax_s, ax_r = fig.subplots(1, 2)
    axis = [str(a) for a in registration["axis"].values]
    pairs = np.asarray(registration["pair_shift"].transpose("pair", "axis").values, dtype=float)
    shift = np.asarray(registration["shift"].values, dtype=float)
    iy, ix = axis.index("y"), axis.index("x")
    ax_s.scatter(pairs[:, ix], pairs[:, iy], color="C0", label="rotation pairs")
    ax_s.scatter([shift[ix]], [shift[iy]], color="C3", marker="x", s=80, label="run shift (median)")
    # at least +-0.25 px around the shift, a few ticks: the spread shows at its true scale
    for index, limits, target in ((ix, ax_s.set_xlim, ax_s.xaxis), (iy, ax_s.set_ylim, ax_s.yaxis)):
        spread = np.nanmax(np.abs(pairs[:, index] - shift[index])) if pairs.size else 0.0
        half = max(0.25, 1.3 * float(spread))
        limits(shift[index] - half, shift[index] + half)
        target.set_major_locator(MaxNLocator(5))
        target.set_major_formatter(FormatStrFormatter("%.2f"))
    ax_s.set_xlabel("x shift [px]")
    ax_s.set_ylabel("y shift [px]")
    ax_s.set_title(f"misregistration: dy {shift[iy]:+.2f} px, dx {shift[ix]:+.2f} px")
    ax_s.legend(fontsize=8)
    ax_s.grid(alpha=0.3)
    residual = np.asarray(registration["residual"].values, dtype=float)
    step = registration_precision(registration)
    labels = [
        f"{a}->{b}"
        for a, b in zip(
            registration["rgb_rotation"].values, registration["spectral_rotation"].values, strict=True
        )
    ]
    ax_r.bar(np.arange(residual.size), residual, color="0.4")
    ax_r.set_xticks(np.arange(residual.size), labels, rotation=60, fontsize=7)
    ax_r.set_xlabel("rotation pair (RGB -> spectral)")
    ax_r.set_ylabel("residual [px]")
    if step:
        ax_r.axhline(step, color="C3", linestyle="--", label=f"precision of the estimate ({step:g} px)")
        ax_r.set_ylim(0, max(2.5 * step, 1.2 * float(np.nanmax(residual)) if residual.size else 0))
        ax_r.legend(fontsize=8, loc="upper left")
    largest = float(np.nanmax(residual)) if residual.size else 0.0
    if step and largest <= step:
        ax_r.set_title("residual per pair: every pair agrees within the precision")
    else:
        ax_r.set_title(f"residual per pair (max {largest:.2f} px)")
    return fig
