"""The HTML report of a run: composition and file I/O (paper sec. 4 and 5, Figures 2-8).

One self-contained HTML file (``index.html``; every figure is an embedded PNG), rendered from
the Jinja2 template ``templates/report.html.j2`` (autoescaped). Headline numbers come first,
then one section per part of the run that exists:

- **Calibration** (no ground truth needed): response histograms of the spectral camera's
  low-SNR series after increasing Gaussian filters (Fig. 2), the exposure plan and filter
  sizes with Q and L (Fig. 3), the colour-checker cross-validation (Fig. 4), the OECFs, the
  quantum efficiency and camera matrix, and the registration residuals;
- **Reconstruction** (no ground truth needed): sRGB thumbnails labelled with image, camera
  and angles, spectra at pixels chosen per camera to show its range (near saturation,
  typical, dark, least confident), and, when the ``spectra`` group has a ``confidence`` (an
  estimated nRMSE), its maps on one percentile scale and a headline of reconstruction
  quality without truth (median, 95th percentile, share of pixels above 0.03); where the
  store holds the light ``L`` the spectra were captured under, the first images relit under
  CIE A, FL11 and D65 beside the capture's render;
- **Accuracy** (simulated runs with ``truth/spectra``): statistics per subset and per image,
  nRMSE histograms over all pixels (Fig. 7, normalised, with an overflow bin), capture time
  (Fig. 8), baselines, and for a few images chosen to show the range of the nRMSE the ground
  truth, reconstruction and error map with the representative spectra (Figs. 5 and 6); with
  the light ``L``, the CIEDE2000 of the spectra relit under CIE A, FL11 and D65 against the
  truth relit alike (:mod:`spectralize.nodes.evaluation.relit_colour`).

Thumbnails are PNGs encoded straight from the arrays (no matplotlib), so a run's report
takes seconds.

Images are selected and named by their *label* (the ``image`` coordinate), never by position:
``spectra`` and ``evaluation`` may be ordered by image set while ``truth/spectra`` is in label
order. The figures are drawn by :mod:`spectralize.nodes.evaluation.figures` and
:mod:`spectralize.nodes.evaluation.figures_calibration`; this module composes and writes.
:func:`write_run_report` reads everything from a run store (``spectralize report STORE``).

References
----------
Fast Capture of Spectral Image Series, sec. 4 and 5, Figures 2-8.
"""

from __future__ import annotations

import base64
import io
import json
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

from spectralize.nodes.evaluation.accuracy import evaluate
from spectralize.nodes.evaluation.capture_time import (
    capture_time,
    capture_time_from_run,
    run_capture_time,
)
from spectralize.nodes.evaluation.colorimetry import (
    auto_exposure,
    render_srgb,
    spectra_to_xyz,
    white_point,
    xyz_to_srgb,
)
from spectralize.nodes.evaluation.comparison import METHOD_DIM, compare_methods
from spectralize.nodes.evaluation.figures import (
    image_label,
    plot_camera_spectra,
    plot_capture_time,
    plot_error_map,
    plot_histograms,
    plot_pixel_spectra,
    plot_spectra,
    representative_pixels,
)
from spectralize.nodes.evaluation.figures_calibration import (
    camera_calibration_rows,
    patch_names,
    plot_camera_matrices,
    plot_cross_validation,
    plot_exposure_plan,
    plot_flat_field,
    plot_oecf,
    plot_quantum_efficiency,
    plot_registration,
    plot_response_histograms,
    registration_precision,
    response_histograms,
)
from spectralize.nodes.evaluation.relit_colour import (
    LIGHT_FLOOR,
    LIGHTS,
    relight,
    relit_delta_e,
    relit_statistics,
)
from spectralize.nodes.evaluation.statistics import DEFAULT_THRESHOLD, STATISTICS
from spectralize.schemas import ParameterError, Problem, SchemaError, SpectralizeError
from spectralize.schemas.run import EVALUATION
from spectralize.store import RunStore

__all__ = [
    "TEMPLATE",
    "write_report",
    "write_run_report",
]

#: The page's Jinja2 template, in this package's ``templates`` folder.
TEMPLATE: str = "report.html.j2"
_DPI = 90
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
                    "a variable made by spectralize.nodes.evaluation.accuracy.evaluate",
                    "nothing",
                )
                for name in missing
            ],
        )


# -- page pieces -----------------------------------------------------------------------------
def _fmt(value: Any, digits: int = 4) -> str:
    value = float(value)
    return "—" if not np.isfinite(value) else f"{value:.{digits}g}"


def _table(
    table_id: str, caption: str, header: Sequence[str], rows: Sequence[Sequence[str]]
) -> dict[str, Any]:
    return {
        "kind": "table",
        "id": table_id,
        "caption": caption,
        "header": list(header),
        "rows": [list(row) for row in rows],
    }


def _figure(figure: Figure, figure_id: str, caption: str) -> dict[str, str]:
    """The figure as an embedded PNG (a data URI): the page needs no other file."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=_DPI)
    data = base64.b64encode(buffer.getvalue()).decode("ascii")
    return {
        "kind": "figure",
        "id": figure_id,
        "src": f"data:image/png;base64,{data}",
        "caption": caption,
    }


def _text(text: str) -> dict[str, str]:
    return {"kind": "text", "text": text}


def _section(section_id: str, title: str, blocks: list[dict[str, Any]]) -> dict[str, Any]:
    return {"id": section_id, "title": title, "blocks": [b for b in blocks if b]}


def _labels(ds: xr.Dataset) -> np.ndarray:
    if "image" in ds.coords and ds["image"].dims == ("image",):
        return np.asarray(ds["image"].values)
    return np.arange(ds.sizes["image"])


def _by_label(ds: xr.Dataset | xr.DataArray, labels: Sequence[int]) -> xr.Dataset | xr.DataArray:
    """The images with these labels, in this order (position-free: ``sel`` on the label)."""
    if "image" in ds.coords and ds["image"].dims == ("image",):
        return ds.sel(image=list(labels))
    return ds.isel(image=list(labels))


# -- accuracy (runs with ground truth) -------------------------------------------------------
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


#: Rows of the per-image table at most: the first images by label (the ``evaluation`` group
#: holds every image's statistics; the summary table covers all of them).
MAX_TABLE_IMAGES = 1000


def _per_image_table(evaluation: xr.Dataset) -> dict[str, Any]:
    """One row per image, named by its label, in label order: the first
    :data:`MAX_TABLE_IMAGES` images, each column taken as one array (no look-up per image)."""
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
    labels = _labels(evaluation)
    order = np.argsort(labels, kind="stable")[:MAX_TABLE_IMAGES]

    def column(values: Any, digits: int = 4) -> list[str]:
        return [_fmt(v, digits) for v in np.asarray(values, dtype=np.float64)[order]]

    def statistic(name: str, stat: str) -> list[str]:
        return column(evaluation[f"{name}_statistics"].sel(statistic=stat).values)

    columns = [[str(int(v)) for v in labels[order]]]
    columns += [column(evaluation.coords[c].values, 5) for c in coords]
    if "has_band_shots" in evaluation:
        shots = np.asarray(evaluation["has_band_shots"].values, dtype=bool)[order]
        columns.append(["yes" if v else "no" for v in shots])
    columns += [statistic("nrmse", s) for s in STATISTICS]
    columns.append(column(evaluation["nrmse_fraction_below"].values))
    columns += [statistic(n, s) for n, s in (("spectral_angle", "median"), ("delta_e", "median"))]
    columns.append(statistic("delta_e", "p95"))
    columns.append([str(int(v)) for v in np.asarray(evaluation["invalid_count"].values)[order]])
    caption = "Statistics per image (by image label)"
    if len(order) < len(labels):
        caption += f": the first {len(order):,} of {len(labels):,} images (all in the evaluation group)"
    return _table("per-image", caption, header, [list(row) for row in zip(*columns, strict=True)])


def _provenance(ds: xr.Dataset) -> dict[str, Any]:
    """How a group read from a run store was made (its ``spectralize_provenance`` attr is
    JSON text; ``RunStore.provenance(group)`` gives the same from the store)."""
    value = ds.attrs.get("spectralize_provenance") or {}
    if isinstance(value, str):
        try:
            value = json.loads(value)
        except ValueError:
            return {}
    return dict(value) if isinstance(value, Mapping) else {}


def _run_table(
    run: str | os.PathLike[str] | None, groups: Mapping[str, xr.Dataset], spectra: xr.Dataset | None
) -> dict[str, Any]:
    rows = [["run store", str(run) if run is not None else "(not given)"]]
    for role, ds in groups.items():
        fingerprint = ds.attrs.get("spectralize_fingerprint")
        provenance = _provenance(ds)
        made_by = (
            f"{provenance.get('node', '?')} v{provenance.get('version', '?')}"
            if provenance
            else "(no provenance)"
        )
        rows.append([f"{role} fingerprint", str(fingerprint) if fingerprint else "(none)"])
        rows.append([f"{role} made by", made_by])
    if spectra is not None:
        sizes = spectra["radiance"].sizes
        wavelength = np.asarray(spectra["wavelength"].values, dtype=np.float64)
        rows += [
            ["images", str(sizes["image"])],
            ["image size", f"{sizes['y']} x {sizes['x']} px"],
            ["wavelengths", f"{wavelength.size} bands, {wavelength[0]:g}..{wavelength[-1]:g} nm"],
            ["radiance", "relative (units 1): band radiance relative to the measured illuminant"],
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


def _relit_colour(
    spectra: xr.Dataset, truth: xr.Dataset, light: xr.DataArray | None, source: str
) -> tuple[list[tuple[str, str]], list[dict[str, Any]]]:
    """The headline and table of the CIEDE2000 of the spectra relit under :data:`LIGHTS`
    against the truth relit alike, or a text saying why it is not measured."""
    if light is None:
        return [], [
            _text(
                "Colour under other lights is not measured: the run has no measured light L "
                f"({source}) to take out of the spectra before relighting them."
            )
        ]
    try:
        relit = relit_delta_e(spectra, truth, light)
    except SchemaError as error:
        return [], [_text(f"Colour under other lights is not measured: {error}")]
    stats = relit_statistics(relit)
    rows = [
        [name, _fmt(v["median"]), _fmt(v["p95"]), _percent(v["excluded"])] for name, v in stats.items()
    ]
    table = _table(
        "relit-colour",
        "Colour under other lights: CIEDE2000 of the spectra relit under CIE A (tungsten), FL11 "
        "(a three-line fluorescent lamp) and D65 (daylight) against the truth relit the same "
        f"way, over all pixels of all images. The light L taken out is {source}; "
        f"{relit.attrs['normalisation']}. Left out: {relit.attrs['excluded']}. Where L is "
        f"below {relit.attrs['light_floor']:g} of its peak it is raised to that before dividing "
        "(the estimate's noise there would be amplified without bound).",
        ["light", "ΔE00 median", "ΔE00 p95", "pixels left out"],
        rows,
    )
    headline = [
        (
            "CIEDE2000 relit under " + " / ".join(stats) + " (median)",
            " / ".join(_fmt(v["median"], 3) for v in stats.values()),
        )
    ]
    return headline, [table]


def accuracy_renders(
    spectra: xr.Dataset,
    truth: xr.Dataset,
    labels: Sequence[int],
    *,
    exposure_percentile: float = 99.0,
) -> tuple[xr.DataArray, xr.DataArray]:
    """sRGB renders of the truth and the reconstruction of the images ``labels``, both
    selected by label (one exposure: the truth's), in the order of ``labels``."""
    truth_srgb = render_srgb(
        _by_label(truth["radiance"], labels), percentile=exposure_percentile
    ).compute()
    scale = float(truth_srgb.attrs["exposure_scale"])
    recon_srgb = render_srgb(_by_label(spectra["radiance"], labels), exposure=scale).compute()
    recon_srgb.attrs.update(exposure_normalisation=truth_srgb.attrs["exposure_normalisation"])
    return truth_srgb, recon_srgb


def error_map_figures(
    evaluation: xr.Dataset,
    spectra: xr.Dataset,
    truth: xr.Dataset,
    labels: Sequence[int],
    *,
    exposure_percentile: float = 99.0,
) -> list[tuple[int, Figure, Figure]]:
    """Per image label: the error-map figure (truth, reconstruction, nRMSE) and the spectra figure.

    Everything is selected by label, so the three panels show the same image whatever the
    order of each group.
    """
    evaluation = _by_label(evaluation, labels)
    truth_srgb, recon_srgb = accuracy_renders(
        spectra, truth, labels, exposure_percentile=exposure_percentile
    )
    finite = np.asarray(evaluation["nrmse"].values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    vmax = float(np.percentile(finite, 99.5)) if finite.size else 1.0
    vmax = vmax if vmax > 0 else 1.0
    out = []
    for position, label in enumerate(labels):
        error_map = plot_error_map(
            evaluation, position, truth_srgb=truth_srgb, reconstruction_srgb=recon_srgb, vmax=vmax
        )
        out.append((int(label), error_map, plot_spectra(evaluation, position)))
    return out


#: Images with an error map and representative spectra (two figures each): enough to show
#: the range; the per-image table has every image up to :data:`MAX_TABLE_IMAGES`.
MAX_ERROR_MAPS = 4


def _range_of_images(evaluation: xr.Dataset, labels: Sequence[int]) -> list[int]:
    """At most :data:`MAX_ERROR_MAPS` of ``labels``, evenly spaced in the ranking of their
    95th-percentile nRMSE (the best and the worst included), in label order."""
    if len(labels) <= MAX_ERROR_MAPS:
        return list(labels)
    p95 = np.asarray(
        _by_label(evaluation["nrmse_statistics"], labels).sel(statistic="p95").values, dtype=float
    )
    ranked = np.argsort(np.where(np.isfinite(p95), p95, np.inf), kind="stable")
    picks = ranked[np.round(np.linspace(0, len(labels) - 1, MAX_ERROR_MAPS)).astype(int)]
    return sorted(int(labels[i]) for i in set(picks.tolist()))


def _accuracy(
    evaluation: xr.Dataset,
    *,
    spectra: xr.Dataset,
    truth: xr.Dataset,
    baselines: xr.Dataset | Mapping[str, xr.DataArray | xr.Dataset] | None,
    capture: xr.Dataset | None,
    shots: xr.Dataset | None,
    max_images: int,
    exposure_percentile: float,
    light: xr.DataArray | None = None,
    light_source: str = "none given",
) -> tuple[list[tuple[str, str]], list[dict[str, Any]]]:
    threshold = float(evaluation.attrs.get("threshold", DEFAULT_THRESHOLD))
    all_px = evaluation["nrmse_subset_statistics"].sel(subset="all")
    headline = [
        ("nRMSE median (all pixels)", _fmt(all_px.sel(statistic="median"))),
        ("nRMSE p95", _fmt(all_px.sel(statistic="p95"))),
        (
            f"pixels with nRMSE < {threshold:g}",
            f"{100 * float(evaluation['nrmse_subset_fraction_below'].sel(subset='all')):.1f} %",
        ),
        (
            "CIEDE2000 median",
            _fmt(evaluation["delta_e_subset_statistics"].sel(subset="all", statistic="median")),
        ),
    ]
    relit_headline, relit_blocks = _relit_colour(spectra, truth, light, light_source)
    headline += relit_headline
    sections = [
        _section(
            "accuracy",
            "Accuracy against the ground truth",
            [
                _table(
                    "summary",
                    "Statistics over all pixels of each subset of images",
                    _summary_header(threshold),
                    _summary_rows(evaluation, [str(s) for s in evaluation["subset"].values]),
                ),
                *relit_blocks,
                _per_image_table(evaluation),
                _figure(
                    plot_histograms(evaluation),
                    "histogram",
                    "Figure 7: per-pixel normalised RMSE over all pixels of the images with and "
                    "without band shots, as fractions of their pixels (logarithmic axis); the "
                    "range covers every pixel, the hatched bars are the pixels above it.",
                ),
            ],
        )
    ]
    if capture is not None:
        headline.append(("speed-up of the capture", f"{float(capture['speedup']):.1f}x"))
        sections.append(
            _section(
                "capture-time",
                "Capture time",
                [
                    _capture_table(capture),
                    _figure(
                        plot_capture_time(capture),
                        "capture_time",
                        "Figure 8: total exposure of the reference and the fast capture.",
                    ),
                ],
            )
        )
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
        sections.append(
            _section(
                "baselines", "Baselines", [_baselines_table(evaluation, table.compute(), threshold)]
            )
        )
    labels = np.sort(_labels(evaluation))
    shown = [int(v) for v in labels[: int(max_images)]]
    blocks: list[dict[str, Any]] = [
        _text(
            "sRGB renders with one exposure for truth and reconstruction; error maps on a common "
            "scale (99.5th percentile of the nRMSE of the images shown). Images are named by "
            "their label in the run store."
        )
    ]
    if len(shown) < len(labels):
        blocks.append(_text(f"Figures for the first {len(shown)} of {len(labels)} images."))
    mapped = _range_of_images(evaluation, shown)
    if len(mapped) < len(shown):
        blocks.append(
            _text(
                f"Error maps for {len(mapped)} of these {len(shown)} images, chosen to show the "
                "range of their 95th-percentile nRMSE, from the best to the worst (the table above "
                "has each of them)."
            )
        )
    for label, error_map, spectra_figure in error_map_figures(
        evaluation, spectra, truth, mapped, exposure_percentile=exposure_percentile
    ):
        position = int(np.flatnonzero(_labels(evaluation) == label)[0])
        name = image_label(evaluation, position)
        blocks.append({"kind": "heading", "text": name})
        blocks.append(
            _figure(
                error_map,
                f"error_map_{label:03d}",
                f"Image {label}: ground truth and reconstruction (sRGB) and the normalised RMSE "
                "map; numbered pixels are the representative spectra.",
            )
        )
        blocks.append(
            _figure(
                spectra_figure,
                f"spectra_{label:03d}",
                f"Image {label}: representative spectra, ground truth solid, reconstruction dotted.",
            )
        )
    sections.append(
        _section("error-maps", "Error maps and representative spectra (Figures 5, 6)", blocks)
    )
    return headline, sections


# -- calibration (no ground truth needed) ----------------------------------------------------
def _read(store: RunStore, group: str) -> xr.Dataset | None:
    return store.read(group) if store.has(group) else None


def _cross_validation(calibration: xr.Dataset) -> list[dict[str, Any]]:
    checked = calibration[["measured_rgb", "predicted_rgb", "relative_error"]].compute()
    error = np.asarray(checked["relative_error"].values, dtype=float)
    names = patch_names(checked["relative_error"])
    rows = [[name, _percent(e)] for name, e in zip(names, error, strict=True)]
    table = _table(
        "cross-validation",
        "Colour checker: RGB predicted through C from the spectral camera's capture against "
        f"the RGB measured, relative error per patch (mean {_percent(np.nanmean(error))}).",
        ["patch", "relative error"],
        rows,
    )
    figure = _figure(
        plot_cross_validation(
            checked.rename(measured_rgb="measured", predicted_rgb="predicted").assign_attrs(
                mean_relative_error=float(np.nanmean(error)), max_relative_error=float(np.nanmax(error))
            )
        ),
        "cross_validation",
        "Figure 4: (a) measured RGB, (b) RGB predicted through C from the spectral capture, "
        "(c) their difference scaled 10x, (d) relative error per patch.",
    )
    return [table, figure]


def _camera_calibration(
    calibration: xr.Dataset, headline: list[tuple[str, str]]
) -> list[dict[str, Any]]:
    """Per RGB camera: its C, where it comes from, its chart cross-validation, flags."""
    rows = camera_calibration_rows(calibration)
    if not rows:
        return []
    flagged = [r["camera"] for r in rows if r["flags"]]
    if flagged:
        headline.append(("cameras flagged in calibration", ", ".join(flagged)))
    table = _table(
        "camera-calibration",
        "Each RGB camera's calibration: its sensor model (capture.toml rgb.models), where its C "
        "comes from, the chart cross-validation through its own C (mean and largest patch) and "
        "the difference of its C from the closest other camera's of its model; flagged above "
        "3 % and 5 %.",
        ["camera", "model", "C from", "chart mean", "chart max", "C vs its model", "flags"],
        [
            [
                r["camera"],
                r["model"],
                r["c_source"],
                _percent(r["mean_relative_error"]),
                _percent(r["max_relative_error"]),
                "—" if r["model_difference"] is None else _percent(r["model_difference"]),
                "; ".join(r["flags"]) or "—",
            ]
            for r in rows
        ],
    )
    figure = _figure(
        plot_camera_matrices(calibration),
        "camera_matrices",
        "The camera matrix C of each RGB camera (rows normalised to its peak): each camera's "
        "images are reconstructed through its own C.",
    )
    return [table, figure]


def _white_levels(oecf_rgb: xr.Dataset, store: RunStore) -> str:
    """Each RGB camera's white level and where it comes from (declared in capture.toml,
    found in the data, or the top code): ``rgb15 1000 DN (found), ...``."""
    raw = _read(store, "raw/rgb")
    names = list(raw.attrs.get("camera_names") or []) if raw is not None else []
    sources = list(oecf_rgb.attrs.get("white_level_source") or [])
    parts = []
    for k, (camera, level) in enumerate(
        zip(oecf_rgb["camera"].values.tolist(), oecf_rgb["white_level"].values.tolist(), strict=True)
    ):
        name = names[camera] if camera < len(names) else f"camera {camera}"
        source = f" ({sources[k]})" if k < len(sources) else ""
        parts.append(f"{name} {int(level)} DN{source}")
    return ", ".join(parts)


def _percent(fraction: float) -> str:
    """``2.31 %`` (``—`` when not finite)."""
    return f"{100 * float(fraction):.2f} %" if np.isfinite(fraction) else "—"


def _response_histograms(store: RunStore) -> dict[str, Any] | None:
    white, dark = _read(store, "raw/white_reference"), _read(store, "dark")
    if white is None or dark is None:
        return None
    oecf = _read(store, "calibration/oecf_spectral")
    wavelength = np.asarray(white["wavelength"].values, dtype=float)
    band = float(oecf.attrs.get("band", wavelength[0])) if oecf is not None else float(wavelength[0])
    band = float(wavelength[np.argmin(np.abs(wavelength - band))])
    times = np.asarray(white["spectral_exposure_time"].values, dtype=float)
    pick = np.argsort(times)[: min(4, times.size)]
    frames = (
        white["spectral_counts"].sel(wavelength=band).isel(spectral_exposure=pick).astype(np.float64)
    )
    dark_times = np.asarray(dark["exposure_time"].values, dtype=float)
    means = [
        dark["mean"].isel(exposure_time=int(np.argmin(np.abs(dark_times - t)))).values
        for t in times[pick]
    ]
    subtracted = (frames - np.stack(means)).rename(spectral_exposure="exposure_time")
    subtracted = subtracted.assign_coords(exposure_time=times[pick])
    return _figure(
        plot_response_histograms(
            response_histograms(subtracted.compute()),
            title=f"white reference at {band:g} nm, shortest exposures of the series",
        ),
        "response_histograms",
        "Figure 2: histograms of the spectral camera's dark-subtracted values (offset by 30) of "
        "its shortest exposures, unfiltered and after Gaussian filters of increasing size "
        "(sigma = size / 5): values stay statistically stable far below one DN of signal.",
    )


def _calibration(store: RunStore) -> tuple[list[tuple[str, str]], list[dict[str, Any]]]:
    headline: list[tuple[str, str]] = []
    blocks: list[dict[str, Any]] = []
    blocks.append(_response_histograms(store))
    plan = _read(store, "raw/exposure_plan")
    spectral = _read(store, "calibration/spectral")
    white = _read(store, "raw/white_reference")
    if plan is not None:
        blocks.append(
            _figure(
                plot_exposure_plan(
                    plan,
                    quantum_efficiency=spectral["quantum_efficiency"] if spectral is not None else None,
                    illuminant=white["illuminant"] if white is not None else None,
                ),
                "exposure_plan",
                "Figure 3: relative quantum efficiency Q and illuminant L, exposure time per band "
                "(eq. 2) and filter size (eq. 3) of the band shots.",
            )
        )
    if spectral is not None and "measured_rgb" in spectral:
        error = np.asarray(spectral["relative_error"].values, dtype=float)
        headline.append(
            ("colour-checker cross-validation, mean error", f"{100 * np.nanmean(error):.2f} %")
        )
        blocks += _cross_validation(spectral)
        blocks += _camera_calibration(spectral, headline)
    oecf_rgb, oecf_spectral = (
        _read(store, "calibration/oecf_rgb"),
        _read(store, "calibration/oecf_spectral"),
    )
    if oecf_rgb is not None and "white_level" in oecf_rgb:
        headline.append(("RGB white level (codes clip at)", _white_levels(oecf_rgb, store)))
    if oecf_rgb is not None or oecf_spectral is not None:
        blocks.append(
            _figure(
                plot_oecf(oecf_rgb, oecf_spectral),
                "oecf",
                "Recovered camera responses (OECF): relative exposure per code of each RGB camera "
                "and channel (Robertson 2003) and of the spectral camera (low-SNR extension).",
            )
        )
    if spectral is not None:
        blocks.append(
            _figure(
                plot_quantum_efficiency(spectral),
                "quantum_efficiency",
                "Relative quantum efficiency of the spectral camera per band and the rows of the "
                "RGB camera matrix C.",
            )
        )
        flat = plot_flat_field(spectral)
        if flat is not None:
            blocks.append(
                _figure(
                    flat,
                    "flat_field",
                    "Flat fields from the white reference: each RGB camera's lens falloff (1 at "
                    "the frame centre) and the spectral camera's along the frame diagonal, per "
                    "band; every image and band shot is divided by its camera's.",
                )
            )
    registration = _read(store, "registration")
    if registration is not None:
        shift = np.asarray(registration["shift"].values, dtype=float)
        residual = np.asarray(registration["residual"].values, dtype=float)
        step = registration_precision(registration)
        largest = float(np.nanmax(residual)) if residual.size else 0.0
        agreement = (
            f"the rotation pairs agree within the estimate's precision ({step:g} px)"
            if step and largest <= step
            else f"the rotation pairs differ from it by up to {largest:.2f} px"
        )
        headline.append(
            ("misregistration (dy, dx)", f"({shift[0]:+.2f}, {shift[1]:+.2f}) px; {agreement}")
        )
        blocks.append(
            _figure(
                plot_registration(registration),
                "registration",
                "Misregistration of the spectral camera to its RGB camera per rotation pair "
                "(phase correlation) and each pair's residual from the run's shift, against "
                "the precision of the estimate (1 / its upsampling factor).",
            )
        )
    blocks = [b for b in blocks if b]
    return headline, [_section("calibration", "Calibration", blocks)] if blocks else []


# -- reconstruction (no ground truth needed) -------------------------------------------------
#: Percentiles of the confidence that span its colour scale (a few outliers do not set it).
CONFIDENCE_PERCENTILES: tuple[float, float] = (2.0, 98.0)
#: Cameras with a panel of spectra (a gantry has a few; more would not be read side by side).
MAX_CAMERA_PANELS = 6
#: The estimated nRMSE above which a pixel is flagged: the paper's Figure 7 level.
CONFIDENCE_FLAG = DEFAULT_THRESHOLD


def _png(pixels: np.ndarray) -> str:
    """A ``(y, x, 3 or 4)`` uint8 image as a PNG data URI (no matplotlib: milliseconds)."""
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels)).save(buffer, format="PNG", compress_level=1)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _gallery(gallery_id: str, caption: str, items: list[tuple[str, str]], legend: str = "") -> dict:
    """Thumbnails with a caption each: ``items`` of (PNG data URI, caption)."""
    return {
        "kind": "gallery",
        "id": gallery_id,
        "caption": caption,
        "legend": legend,
        "items": [{"src": src, "caption": text} for src, text in items],
    }


def _thumbnail_caption(ds: xr.Dataset, position: int) -> str:
    """``image 7 · camera 1 · view θo 45°, φo 15° · light θi 30°, φi 0°``."""
    coords = ds.coords
    label = int(coords["image"].values[position]) if "image" in coords else position
    parts = [f"image {label}"]
    if "camera" in coords and coords["camera"].dims == ("image",):
        parts.append(f"camera {coords['camera'].values[position]}")
    if "theta_o" in coords and "phi_o" in coords:
        parts.append(
            f"view θo {float(coords['theta_o'][position]):.0f}°, "
            f"φo {float(coords['phi_o'][position]):.0f}°"
        )
    if "theta_i" in coords and "phi_i" in coords:
        parts.append(
            f"light θi {float(coords['theta_i'][position]):.0f}°, "
            f"φi {float(coords['phi_i'][position]):.0f}°"
        )
    return " · ".join(parts)


#: Pixels the headline's statistics of the confidence are computed over at most: a run with
#: more has them computed over images spread evenly over the run (and every few pixels of an
#: image larger than this), so the report reads a bounded amount whatever the image count.
STATISTICS_PIXELS = 2**20
#: Images those statistics are computed over at most (each read with the stored chunk that
#: holds it: its own, or a few neighbours' too in a run of small frames).
STATISTICS_IMAGES = 512
#: Stored shards those images come from at most (a shard is read whole once, to check it
#: against its checksum), spread over the run like the images.
STATISTICS_SHARDS = 3


def _spread(n: int, kept: int) -> np.ndarray:
    """``kept`` of ``range(n)`` spread evenly, the first and the last included."""
    return np.unique(np.round(np.linspace(0, n - 1, min(n, kept))).astype(int))


def _spread_sample(
    values: xr.DataArray,
    limit: int = STATISTICS_PIXELS,
    images: int = STATISTICS_IMAGES,
    shards: int = STATISTICS_SHARDS,
) -> tuple[xr.DataArray, int]:
    """``values`` (image, y, x) on at most about ``limit`` pixels, and the images it keeps.

    All of it when it has that few pixels; else as many images as fit, at most ``images``
    and at least two, spread evenly over the run (the first and the last included), and
    every ``step``-th pixel along ``y`` and ``x`` where they have more. Of a variable stored
    in more than ``shards`` shards along ``image`` (its ``encoding``), the images come from
    ``shards`` of them spread over the run. One selection: read from a variable as stored
    (:func:`_stored_variable`), it reads those images' chunks only, whatever the run's size.
    """
    stored = dict(zip(values.dims, values.encoding.get("shards") or (), strict=False))
    values = values.transpose("image", "y", "x")
    n, ny, nx = values.shape
    if n * ny * nx <= limit:
        return values, n
    candidates = np.arange(n)
    per_shard = int(stored.get("image", n))
    if -(-n // per_shard) > shards:
        picked = _spread(-(-n // per_shard), shards)
        candidates = np.concatenate(
            [np.arange(k * per_shard, min(n, (k + 1) * per_shard)) for k in picked]
        )
    kept = max(2, min(int(images), limit // (ny * nx)))
    positions = candidates[_spread(len(candidates), kept)]
    step = max(1, int(np.ceil(np.sqrt(len(positions) * ny * nx / limit))))
    return values.isel(image=positions, y=slice(None, None, step), x=slice(None, None, step)), len(
        positions
    )


def _stored_variable(run: RunStore, group: str, name: str) -> xr.DataArray | None:
    """Variable ``name`` of ``group`` as stored, indexed lazily without dask (None if absent).

    A selection of it reads only the stored chunks it touches, each checked against its
    checksum: a sample of a run's images reads those images, not a dask task per image or a
    whole shard per task.
    """
    ds = run.read(group, friendly=False, dask=False)
    return ds[name] if name in ds else None


def _confidence_headline(confidence: xr.DataArray) -> list[tuple[str, str]]:
    """Reconstruction quality without ground truth: the estimated nRMSE's median and 95th
    percentile over all pixels, and the share flagged (above :data:`CONFIDENCE_FLAG`); in a
    run of more than :data:`STATISTICS_PIXELS` pixels, over a sample of images spread over
    the run (:func:`_spread_sample`; the headline says which)."""
    sample, images = _spread_sample(confidence)
    values = np.asarray(sample.values, dtype=np.float64).reshape(-1)
    values = values[np.isfinite(values)]
    if not values.size:
        return []
    median, p95 = np.percentile(values, [50, 95])
    flagged = float(np.mean(values > CONFIDENCE_FLAG))
    total = confidence.sizes["image"]
    over = (
        ""
        if sample.size == confidence.size
        else f" (over {values.size:,} of the {confidence.size:,} pixels: {images:,} of the "
        f"{total:,} images, spread over the run)"
    )
    return [
        (
            "reconstruction quality (no ground truth)",
            f"estimated nRMSE median {median:.4f}, 95th percentile {p95:.4f}; "
            f"{100 * flagged:.1f} % of pixels above {CONFIDENCE_FLAG:g}{over}",
        ),
        (
            "what that means",
            "the estimated nRMSE is how much similar-looking neighbouring pixels disagree in "
            "spectral shape, in the units of the paper's nRMSE; pixels above "
            f"{CONFIDENCE_FLAG:g} (the paper's Figure 7 level) are where to trust the spectra "
            "less (highlights, edges, saturation)",
        ),
    ]


def _confidence_gallery(confidence: xr.DataArray, captions: list[str]) -> dict[str, Any]:
    """Confidence maps as thumbnails on one colour scale, spanning the percentiles
    :data:`CONFIDENCE_PERCENTILES` of the images shown."""
    from matplotlib import colormaps

    values = np.asarray(confidence.transpose("image", "y", "x").values, dtype=np.float64)
    finite = values[np.isfinite(values)]
    lo, hi = np.percentile(finite, CONFIDENCE_PERCENTILES) if finite.size else (0.0, 1.0)
    hi = hi if hi > lo else lo + 1e-12
    colour = colormaps["viridis"]
    scaled = np.clip((values - lo) / (hi - lo), 0.0, 1.0)
    items = [
        (_png((colour(np.nan_to_num(scaled[k]))[..., :3] * 255).astype(np.uint8)), captions[k])
        for k in range(values.shape[0])
    ]
    bar = (colour(np.linspace(0, 1, 256))[None, :, :3] * 255).astype(np.uint8).repeat(12, axis=0)
    low, high = CONFIDENCE_PERCENTILES
    return _gallery(
        "confidence",
        "Estimated nRMSE of the reconstruction per pixel (the confidence of the spectra group; "
        f"higher: trust less). One colour scale for all maps, from its {low:g} % to its "
        f"{high:g} % percentile over the images shown: {lo:.4f} (dark) to {hi:.4f} (bright); "
        "values beyond are clipped.",
        items,
        legend=_png(bar),
    ) | {"legend_low": f"{lo:.4f}", "legend_high": f"{hi:.4f}"}


def _camera_spectra(
    cube: xr.Dataset, brightness: np.ndarray, confidence: np.ndarray | None
) -> dict[str, Any]:
    """Spectra at pixels that show the range per camera (:func:`representative_pixels`)."""
    cameras = (
        np.asarray(cube["camera"].values)
        if "camera" in cube.coords and cube["camera"].dims == ("image",)
        else np.zeros(cube.sizes["image"], int)
    )
    labels = _labels(cube)
    radiance = cube["radiance"]
    panels = []
    every = sorted(set(cameras.tolist()), key=str)
    for camera in every[:MAX_CAMERA_PANELS]:
        mine = np.flatnonzero(cameras == camera)
        picks = representative_pixels(brightness[mine], None if confidence is None else confidence[mine])
        lines = [
            (
                f"{kind}: image {int(labels[mine[m]])}, y {y}, x {x}",
                np.asarray(radiance.isel(image=int(mine[m]), y=y, x=x).values, dtype=float),
            )
            for kind, m, y, x in picks
        ]
        panels.append((f"camera {camera}", lines))
    return _figure(
        plot_camera_spectra(panels, np.asarray(cube["wavelength"].values, dtype=float)),
        "camera_spectra",
        "Reconstructed spectra at pixels chosen per camera to show the range of its images "
        "shown: near saturation (99.9th percentile of brightness), typical (median), dark "
        "(2nd percentile) and, where the run has a confidence, the least confident pixel"
        + (
            f"; the first {MAX_CAMERA_PANELS} of {len(every)} cameras."
            if len(every) > MAX_CAMERA_PANELS
            else "."
        ),
    )


#: Images relit under every light of :data:`LIGHTS` beside the capture's render: enough to
#: see what the light changes; the ground-truth comparison covers every image.
MAX_RELIT_IMAGES = 4


def _display_render(radiance: xr.DataArray, percentile: float) -> np.ndarray:
    """(image, y, x, channel) uint8 sRGB of a radiance cube as a display shows a scene: the
    luminance's ``percentile``-th percentile is white and sRGB's white, D65, is neutral
    (no adaptation), so daylight looks white and tungsten orange."""
    xyz = spectra_to_xyz(radiance, illuminant=None)
    scaled = xyz * auto_exposure(xyz, percentile=percentile)
    rgb = xyz_to_srgb(scaled, white=white_point("D65"))
    return np.asarray(rgb.transpose("image", "y", "x", "channel").values)


def _relit_renders(
    cube: xr.Dataset,
    light: xr.DataArray,
    source: str,
    captions: list[str],
    *,
    exposure_percentile: float,
) -> list[dict[str, Any]]:
    """The first images as captured and relit under each of :data:`LIGHTS`, one row each.

    Every render of a row is exposed alike (the ``exposure_percentile``-th percentile of its
    light's luminance over the images relit is white) and shows its light's own colour
    against sRGB's white, D65 (:func:`_display_render`).
    """
    n = min(MAX_RELIT_IMAGES, cube.sizes["image"])
    radiance = cube["radiance"].isel(image=slice(0, n))
    try:
        renders = {"captured": _display_render(radiance, exposure_percentile)} | {
            name: _display_render(relight(radiance, light, name), exposure_percentile) for name in LIGHTS
        }
    except SchemaError as error:
        return [_text(f"No renders under other lights: {error}")]
    blocks = [
        _text(
            f"The first {n} images as captured and relit under CIE "
            + ", ".join(LIGHTS)
            + f": the spectra divided by the light L they were captured under ({source}; "
            f"raised to {LIGHT_FLOOR:g} of its peak where lower) times the new light. Each "
            "render is exposed like those above and shows its light's colour against sRGB's "
            "white (D65): daylight looks white, tungsten (A) orange."
        )
    ]
    labels = _labels(cube)
    for k in range(n):
        items = [(_png(renders["captured"][k]), f"{captions[k]} · as captured")]
        items += [(_png(renders[name][k]), f"image {int(labels[k])} · under {name}") for name in LIGHTS]
        blocks.append(
            _gallery(
                f"relit-{int(labels[k])}",
                f"Image {int(labels[k])} under the capture's light and under " + ", ".join(LIGHTS) + ".",
                items,
            )
        )
    return blocks


def _reconstruction(
    spectra: xr.Dataset,
    *,
    max_images: int,
    pixels: Sequence[tuple[int, int]] | None,
    exposure_percentile: float,
    light: xr.DataArray | None = None,
    light_source: str = "none given",
    confidence: xr.DataArray | None = None,
) -> tuple[list[tuple[str, str]], list[dict[str, Any]]]:
    """The reconstruction section: the first ``max_images`` images by label, and the
    headline's statistics of the confidence (read as ``confidence`` where given: the
    store's as stored, :func:`_stored_variable`; else ``spectra``'s)."""
    labels = np.sort(_labels(spectra))
    shown = [int(v) for v in labels[: int(max_images)]]
    cube = _by_label(spectra, shown).compute()
    height, width = spectra.sizes["y"], spectra.sizes["x"]
    bad = [p for p in pixels or () if not (0 <= p[0] < height and 0 <= p[1] < width)]
    if bad:
        raise ParameterError.single("pixels", f"(y, x) inside {height} x {width} px", f"{bad}")
    srgb = render_srgb(cube["radiance"], percentile=exposure_percentile, dtype="float").compute()
    captions = [_thumbnail_caption(cube, k) for k in range(len(shown))]
    headline = [("images reconstructed", str(len(labels)))]
    if "confidence" in spectra:
        headline += _confidence_headline(spectra["confidence"] if confidence is None else confidence)
    blocks: list[dict[str, Any]] = []
    if len(shown) < len(labels):
        blocks.append(_text(f"Figures for the first {len(shown)} of {len(labels)} images."))
    rgb8 = (np.clip(np.asarray(srgb.transpose("image", "y", "x", "channel").values), 0, 1) * 255).astype(
        np.uint8
    )
    blocks.append(
        _gallery(
            "renders",
            "sRGB renders of the reconstructed spectral images (CIE 1931 2°, one exposure: "
            f"{srgb.attrs.get('exposure_normalisation', '')}).",
            [(_png(rgb8[k]), captions[k]) for k in range(len(shown))],
        )
    )
    if light is not None:
        blocks += _relit_renders(
            cube, light, light_source, captions, exposure_percentile=exposure_percentile
        )
    brightness = np.asarray(cube["radiance"].mean("wavelength").transpose("image", "y", "x").values)
    confidence = (
        np.asarray(cube["confidence"].transpose("image", "y", "x").values, dtype=float)
        if "confidence" in cube
        else None
    )
    blocks.append(_camera_spectra(cube, brightness, confidence))
    if pixels:
        points = list(pixels)
        picked = cube["radiance"].isel(
            image=0, y=xr.DataArray([p[0] for p in points]), x=xr.DataArray([p[1] for p in points])
        )
        blocks.append(
            _figure(
                plot_pixel_spectra(
                    rgb8[0].astype(float) / 255,
                    np.asarray(picked.transpose("dim_0", "wavelength").values),
                    points,
                    np.asarray(cube["wavelength"].values, dtype=float),
                    title=image_label(cube, 0),
                ),
                f"pixel_spectra_{shown[0]:03d}",
                f"Image {shown[0]}: reconstructed spectra at the numbered pixels asked for.",
            )
        )
    if "confidence" in cube:
        blocks.append(_confidence_gallery(cube["confidence"], captions))
    return headline, [_section("reconstruction", "Reconstruction", blocks)]


#: Where a run store holds the light L its spectra are radiance under, in the order looked at:
#: the calibration's measurement (what the reconstruction uses), the white reference's raw
#: group, a simulated run's true light.
LIGHT_SOURCES: tuple[tuple[str, str], ...] = (
    ("calibration/spectral", "illuminant"),
    ("raw/white_reference", "illuminant"),
    ("truth/camera", "illuminant"),
)


def _capture_light(store: RunStore) -> tuple[xr.DataArray | None, str]:
    """The light L of the run (wavelength,) and where it was read, or None and where it
    was looked for."""
    for group, name in LIGHT_SOURCES:
        if store.has(group):
            ds = store.read(group)
            if name in ds and ds[name].dims == ("wavelength",):
                return ds[name].load(), f"{group}:{name}"
    return None, "none in " + ", ".join(f"{g}:{n}" for g, n in LIGHT_SOURCES)


# -- writing ---------------------------------------------------------------------------------
def _write_page(
    directory: str | os.PathLike[str],
    *,
    title: str,
    run_table: dict[str, Any],
    headline: list[tuple[str, str]],
    sections: list[dict[str, Any]],
) -> Path:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    index = directory / "index.html"
    page = (
        _environment()
        .get_template(TEMPLATE)
        .render(
            title=title,
            written=time.strftime("%Y-%m-%d %H:%M:%S"),
            headline=headline,
            run=run_table,
            sections=sections,
        )
    )
    partial = index.with_name(index.name + ".partial")
    partial.write_text(page, encoding="utf-8")
    os.replace(partial, index)
    return index


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
    illuminant: xr.DataArray | None = None,
) -> Path:
    """Write the report of an evaluation against ground truth: one self-contained HTML file.

    Parameters
    ----------
    evaluation
        Output of :func:`~spectralize.nodes.evaluation.accuracy.evaluate` (the ``evaluation``
        group); it is computed here.
    spectra, truth
        Groups ``spectra`` and ``truth/spectra`` the evaluation was made from. Images are
        matched by label (``image`` coordinate), whatever the order of each group.
    directory
        Folder to write ``index.html`` into (created; the file is replaced atomically).
    baselines
        Comparison of methods: the output of
        :func:`~spectralize.nodes.evaluation.comparison.compare_methods` (dim
        ``reconstruction``), or what it accepts, which is then evaluated here against
        ``truth`` (with ``shots``). Left out when ``None``.
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
        At most this many images (the lowest labels) are considered for figures; of them at
        most :data:`MAX_ERROR_MAPS`, chosen to show the range of the nRMSE, get an error map
        and a spectra figure (all are tabulated).
    exposure_percentile
        Percentile of the truth's luminance mapped to sRGB white (one exposure for truth and
        reconstruction, over the images shown).
    calibration
        Group ``calibration/spectral``; its colour-checker cross-validation (Figure 4) is
        tabulated and drawn.
    illuminant
        The light ``L`` the spectra were captured under, on their bands (e.g.
        ``calibration/spectral``'s ``illuminant``): the colour of the spectra relit under
        CIE A, FL11 and D65 is then compared with the truth's (a CIEDE2000 table). Without
        it, the report says that colour under other lights is not measured.

    Returns
    -------
    pathlib.Path
        The path of ``index.html``.

    Raises
    ------
    SchemaError
        If ``evaluation`` lacks variables that
        :func:`~spectralize.nodes.evaluation.accuracy.evaluate` makes.
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
    evaluation = evaluation.compute()
    headline, sections = _accuracy(
        evaluation,
        spectra=spectra,
        truth=truth,
        baselines=baselines,
        capture=capture,
        shots=shots,
        max_images=max_images,
        exposure_percentile=exposure_percentile,
        light=illuminant,
        light_source="the illuminant given" if illuminant is not None else "none given",
    )
    if calibration is not None and "measured_rgb" in calibration:
        sections.insert(1, _section("calibration", "Calibration", _cross_validation(calibration)))
    return _write_page(
        directory,
        title=title,
        run_table=_run_table(
            run, {"spectra": spectra, "truth/spectra": truth, "evaluation": evaluation}, spectra
        ),
        headline=headline,
        sections=sections,
    )


def write_run_report(
    store: RunStore | str | os.PathLike[str],
    *,
    directory: str | os.PathLike[str] | None = None,
    reference: xr.Dataset | float | None = None,
    title: str | None = None,
    max_images: int = 24,
    pixels: Sequence[tuple[int, int]] | None = None,
    exposure_percentile: float = 99.0,
) -> Path:
    """Write the report of a run store, with or without ground truth: one HTML file.

    Sections, each when its groups exist: calibration (``raw/white_reference``, ``dark``,
    ``raw/exposure_plan``, ``calibration/*``, ``registration``), reconstruction
    (``spectra``), accuracy (``truth/spectra``: the stored ``evaluation`` group, else an
    evaluation made now) and capture time (``raw/spectral``, ``raw/rgb``, ``raw/exposure_plan``).
    Where the store holds the light ``L`` (:data:`LIGHT_SOURCES`), the first images are also
    shown relit under CIE A, FL11 and D65 and, with ground truth, the relit colour is
    compared with the truth's.

    Parameters
    ----------
    store
        The run store or its path.
    directory
        Where to write ``index.html`` (default: the folder ``report`` inside the run store).
    reference
        The long-exposure reference capture: a plan or its total [s] (default: one
        reference set of bands per image from ``raw/exposure_plan``, else the capture time
        the paper reports, 226.212 s; the report says which). Runs with ground truth only.
    title
        Title of the page (default: the store's name).
    max_images
        At most this many images (the lowest labels) get thumbnails (and, with ground truth,
        are considered for the error maps).
    pixels
        (y, x) whose spectra are drawn on the first image, besides the spectra per camera at
        pixels chosen to show its range (default: none).
    exposure_percentile
        Percentile of the luminance mapped to sRGB white.

    Returns
    -------
    pathlib.Path
        The path of ``index.html``.

    Raises
    ------
    SpectralizeError
        When the store has neither calibration groups nor ``spectra``: nothing to report.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 4 and 5, Figures 2-8.
    """
    run = store if isinstance(store, RunStore) else RunStore.open(store)
    if int(max_images) < 1:
        raise ParameterError.single("max_images", "at least 1 image with figures", repr(max_images))
    spectra = _read(run, "spectra")
    headline: list[tuple[str, str]] = []
    sections: list[dict[str, Any]] = []
    found, calibration_sections = _calibration(run)
    headline += found
    groups: dict[str, xr.Dataset] = {}
    light, light_source = _capture_light(run)
    if spectra is not None:
        groups["spectra"] = spectra
        found, recon = _reconstruction(
            spectra,
            max_images=max_images,
            pixels=pixels,
            exposure_percentile=exposure_percentile,
            light=light,
            light_source=light_source,
            # as stored: the headline's sample reads the chunks of its images only
            confidence=_stored_variable(run, "spectra", "confidence"),
        )
        headline = found + headline
        sections += recon
    if spectra is not None and run.has("truth/spectra"):
        truth = run.read("truth/spectra")
        shots = _read(run, "raw/spectral")
        evaluation = _read(run, "evaluation")
        if evaluation is None:
            evaluation = evaluate(spectra, truth, shots=shots)
        evaluation = evaluation.compute()
        _check_evaluation(evaluation)
        capture = None
        if shots is not None:
            raw_rgb = _read(run, "raw/rgb")
            if reference is None:
                capture = run_capture_time(
                    shots, raw_rgb, _read(run, "raw/exposure_plan"), evaluation=evaluation
                )
            else:
                capture = capture_time(
                    capture_time_from_run(shots, raw_rgb), reference, evaluation=evaluation
                )
        found, accuracy = _accuracy(
            evaluation,
            spectra=spectra,
            truth=truth,
            baselines=None,
            capture=capture,
            shots=shots,
            max_images=max_images,
            exposure_percentile=exposure_percentile,
            light=light,
            light_source=light_source,
        )
        headline = found + headline
        sections = accuracy + sections
        groups |= {"truth/spectra": truth, "evaluation": evaluation}
    elif run.has("raw/spectral"):
        # exposure times only: the groups as stored (their pixels are not read)
        raw_rgb = run.read("raw/rgb", friendly=False) if run.has("raw/rgb") else None
        fast = capture_time_from_run(run.read("raw/spectral", friendly=False), raw_rgb)
        band = float(fast["exposure_time"].sum())
        rgb = float(fast["rgb_exposure_time"].sum())
        headline.append(
            (
                "total exposure of the capture",
                f"{band + rgb:.3g} s ({band:.3g} s band shots, {rgb:.3g} s RGB)",
            )
        )
    sections += calibration_sections
    if not sections:
        raise SpectralizeError.single(
            str(run.path),
            "calibration groups or a spectra group to report on (run `spectralize run btf` first)",
            f"groups {run.groups()}",
        )
    return _write_page(
        run.path / "report" if directory is None else directory,
        title=title or f"spectralize: {run.path.name}",
        run_table=_run_table(str(run.path), groups, spectra),
        headline=headline,
        sections=sections,
    )
