"""The ``evaluate`` node: a reconstruction against its ground truth (paper sec. 5, Fig. 5-7).

:func:`evaluate` gives the three per-pixel maps of :mod:`.pixel_metrics` (nRMSE, spectral
angle, CIEDE2000; image, y, x), per-image statistics (mean, median, 95th and 99th
percentile; the fraction of pixels with nRMSE below 0.03, the level Figure 7 discusses),
per-image nRMSE histograms (Figure 7 is their sum over the images with and without band
shots), statistics per subset of images (all / with band shots / without;
:mod:`.statistics`, :mod:`.band_shots`) and representative spectra picked at low and high
error (:mod:`.representative`; Figures 5 and 6, insets), as the ``evaluation`` group.
Everything is lazy over images when the inputs are dask-backed, as read from a run store.

References
----------
Fast Capture of Spectral Image Series, sec. 5 ("Full Correspondences", "Sparsely Measured
Spectral Bands"), Figures 5, 6 (normalised RMSE maps, representative spectra) and 7 (RMSE
histograms, images with and without band shots, logarithmic count axis).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
import xarray as xr
from pydantic import AfterValidator, Field
from pydantic_core import PydanticCustomError

from spectralize.engine import Choices

from .band_shots import has_band_shots, image_index
from .cubes import align, as_float64, cube, string_labels
from .illuminants import ILLUMINANTS
from .pixel_metrics import METRICS, pixel_maps
from .representative import DEFAULT_SAMPLE_QUANTILES, representative
from .statistics import (
    DEFAULT_THRESHOLD,
    STATISTICS,
    map_statistics,
    nrmse_histogram,
    subset_statistics,
)

__all__ = ["evaluate"]


def _ascending(value: tuple[float, ...]) -> tuple[float, ...]:
    if list(value) != sorted(value):
        raise PydanticCustomError("ascending", "ascending quantiles")
    return value


def evaluate(
    spectra: xr.Dataset,
    truth: xr.Dataset,
    *,
    shots: xr.Dataset | None = None,
    illuminant: Annotated[str, Choices(ILLUMINANTS, "illuminant")] = "D65",
    threshold: Annotated[float, Field(gt=0)] = DEFAULT_THRESHOLD,
    histogram_bins: Annotated[int, Field(ge=1, le=10000)] = 60,
    histogram_max: Annotated[float, Field(gt=0)] = 0.12,
    sample_quantiles: Annotated[
        tuple[Annotated[float, Field(ge=0, le=1)], ...], Field(min_length=1), AfterValidator(_ascending)
    ] = DEFAULT_SAMPLE_QUANTILES,
) -> xr.Dataset:
    """Compare a reconstructed spectral cube with its ground truth (paper sec. 5, Fig. 5-7).

    Parameters
    ----------
    spectra
        Group ``spectra``: ``radiance`` (image, wavelength, y, x) [1].
    truth
        Group ``truth/spectra``, the same layout, same shape and wavelengths (the images
        may be in another order: they are matched by their ``image`` labels).
    shots
        Group ``raw/spectral`` (or ``bands``): its per-shot ``image`` tells which images have
        band shots. Without it only the subset ``all`` is summarised.
    illuminant
        Illuminant of the CIEDE2000 colour difference (colour-science name, or 'E').
        A key of :data:`ILLUMINANTS`: of ``colour.SDS_ILLUMINANTS``, or ``"E"`` to integrate
        the cubes as they are.
    threshold
        nRMSE level of the fraction-below statistics (Figure 7: ~0.03).
    histogram_bins
        Number of bins of the per-image nRMSE histograms.
        Equal bins over ``[0, histogram_max]``.
    histogram_max
        Upper end of the nRMSE histograms.
        Larger values are counted in ``nrmse_above_range``.
    sample_quantiles
        Quantiles of the nRMSE map where representative spectra are picked.
        Ascending, in [0, 1]: per image, the pixel closest to each quantile.

    Returns
    -------
    xarray.Dataset
        The ``evaluation`` group (schema :data:`spectralize.schemas.run.EVALUATION`): maps
        ``nrmse``,
        ``spectral_angle``, ``delta_e`` (image, y, x) float32; per image ``truth_mean``,
        ``{metric}_statistics`` (image, statistic), ``nrmse_fraction_below``,
        ``invalid_count``, ``nrmse_histogram`` (image, nrmse_bin), ``nrmse_above_range`` and,
        with ``shots``, ``has_band_shots``; per subset ``{metric}_subset_statistics``
        (subset, statistic), ``nrmse_subset_fraction_below``, ``subset_pixel_count``;
        representative pixels ``sample_*`` (image, sample[, wavelength]). Per-image coords of
        the truth are kept. Lazy (dask) when the inputs are; the subset statistics hold the
        maps of a subset in one chunk when computed.

    Raises
    ------
    SchemaError
        If the two cubes do not fit together (shapes, wavelengths, image labels).

    Notes
    -----
    This is the function of the ``evaluate`` node
    (:data:`spectralize.nodes.evaluation.declarations.EVALUATE`). The engine checks its
    groups against their schemas (``spectra``, ``truth/spectra``, ``raw/spectral``) and its
    options against the constraints annotated in this signature before it runs, so only
    what those cannot say, that the two cubes fit together, is checked here. A direct call
    should pass groups that follow the schemas (``spectralize.schemas.check_dataset``) and
    valid options (``EVALUATE.parse_parameters``).

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 and Figures 5, 6 and 7.
    """
    quantiles = np.asarray(sample_quantiles, dtype=np.float64)
    s, t = align(cube(spectra), cube(truth))

    maps = pixel_maps(s, t, tuple(METRICS), illuminant=illuminant)
    nrmse, delta_e = maps["nrmse"], maps["delta_e"]

    truth_mean = as_float64(t).mean(("wavelength", "y", "x"), skipna=False)
    out = xr.Dataset(
        {
            **maps,
            "truth_mean": truth_mean.assign_attrs(
                units=t.attrs.get("units", "1"),
                long_name="mean ground-truth intensity of the image (nRMSE normaliser)",
            ),
        }
    )
    for name, error_map in maps.items():
        units, long_name = METRICS[name]
        out[f"{name}_statistics"] = map_statistics(error_map).assign_attrs(
            units=error_map.attrs.get("units", units),
            long_name=f"per-image statistics of the {long_name}",
        )
    finite = nrmse.notnull().sum(("y", "x")).astype(np.int64)
    out["nrmse_fraction_below"] = (
        ((nrmse < threshold).sum(("y", "x")) / finite.where(finite > 0))
        .astype(np.float64)
        .assign_attrs(
            units="1",
            threshold=threshold,
            long_name=f"fraction of finite pixels with nRMSE < {threshold:g}",
        )
    )
    out["invalid_count"] = (
        (nrmse.sizes["y"] * nrmse.sizes["x"] - finite)
        .astype(np.int64)
        .assign_attrs(units="1", long_name="pixels with an undefined (NaN) nRMSE")
    )

    edges = np.linspace(0.0, float(histogram_max), int(histogram_bins) + 1)
    out["nrmse_histogram"] = nrmse_histogram(nrmse, edges).assign_attrs(
        units="1", long_name="per-image histogram of the nRMSE (pixel counts)"
    )
    out["nrmse_above_range"] = (
        (nrmse > histogram_max)
        .sum(("y", "x"))
        .astype(np.int64)
        .assign_attrs(units="1", long_name=f"pixels with nRMSE above {histogram_max:g}")
    )
    out = out.assign_coords(
        nrmse_bin_lower=(
            "nrmse_bin",
            edges[:-1],
            {"units": "1", "long_name": "lower edge of the nRMSE bin"},
        ),
        nrmse_bin_upper=(
            "nrmse_bin",
            edges[1:],
            {"units": "1", "long_name": "upper edge of the nRMSE bin"},
        ),
    )

    images = image_index(t)
    masks: dict[str, np.ndarray] = {"all": np.ones(images.size, dtype=bool)}
    if shots is not None:
        has = has_band_shots(shots, images)
        out["has_band_shots"] = has
        masks["with_band_shots"] = has.values
        masks["without_band_shots"] = ~has.values
    out = out.merge(subset_statistics(maps, masks, threshold), compat="override", join="exact")

    samples = representative(nrmse, s, t, quantiles)
    out = out.merge(samples, compat="override", join="exact")

    per_image = {name: coord.variable for name, coord in t.coords.items() if coord.dims == ("image",)}
    out = out.assign_coords(per_image)
    out = out.assign_coords(statistic=string_labels(STATISTICS))
    out["wavelength"].attrs.update({"units": "nm", "long_name": "wavelength"})
    out.attrs = {
        "illuminant": delta_e.attrs["illuminant"],
        "observer": delta_e.attrs["observer"],
        "threshold": float(threshold),
        "band_shots_known": int(shots is not None),
        "references": "Fast Capture of Spectral Image Series, sec. 5, Figures 5, 6 and 7",
    }
    for role, ds in (("spectra", spectra), ("truth", truth)):
        fingerprint = ds.attrs.get("spectralize_fingerprint") if isinstance(ds, xr.Dataset) else None
        if fingerprint:
            out.attrs[f"{role}_fingerprint"] = str(fingerprint)
    return out
