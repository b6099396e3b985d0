"""The paper's low-SNR extension of Robertson's response recovery (section 4, Fig. 2).

The spectral camera's useful pixel values lie a few DN above the dark level, where plain
Robertson (:func:`~.recover_oecf`) fails: the
noise is as large as the signal. :func:`recover_oecf_low_snr` subtracts the averaged dark
frame (float, negative values kept), Gaussian-filters as in the reconstruction, stretches the
small interval of filtered values to the full integer range, rounds, runs Robertson, maps the
response back to dark-subtracted pixel values and removes the regression-to-the-mean bias.
Its ``code`` coordinate is fractional DN above dark. :func:`recover_spectral_oecf` (node
``recover_spectral_oecf``) runs it on the white reference and joins it to a full-range
Robertson response.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration") and Fig. 2.
.. [2] M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2),
   219-228, 2003.
"""

from __future__ import annotations

import math
from typing import Annotated, NamedTuple

import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.nodes.calibration.dark import dark_frames_at
from spectralize.nodes.calibration.exposure_series import (
    check_bit_depth,
    check_exposure_times,
    check_integer,
    counts_array,
    raise_first,
    refused,
    saturated_frames,
    target_spectral_series,
    warn_if_geometric,
)
from spectralize.nodes.calibration.oecf.response import (
    combine_responses,
    response_dataarray,
)
from spectralize.nodes.calibration.oecf.reverse_regression import (
    exposure_estimates,
    reverse_regression,
)
from spectralize.nodes.calibration.oecf.robertson import (
    Solver,
    recover_oecf,
    robertson_response,
)
from spectralize.nodes.calibration.oecf.weighting import Weighting, weighting_function
from spectralize.nodes.filter_size import filter_radius, filter_sigma
from spectralize.schemas import CalibrationError, SchemaError, SpectralizeError
from spectralize.schemas.errors import Problem

__all__ = [
    "LOW_SNR_TRUNCATE",
    "recover_oecf_low_snr",
    "recover_spectral_oecf",
    "spectral_oecf_refusals",
]

LOW_SNR_TRUNCATE: float = 2.5
"""Gaussian support of the low-SNR extension in sigmas: kernel radius ``s / 2``.

Deliberately shorter than the reconstruction's ``FILTER_TRUNCATE = 5`` (radius ``s``,
:mod:`spectralize.nodes.filter_size`); the same ``sigma = s / 5`` either way. With 5 sigmas
the joined response is worse at its largest error and at the low end, although the
extension's own table is better, and the wider kernel crops a border twice as wide
(``benchmarks/calibration.py``, see ``docs/benchmarks.md``).
"""


def _series_dim(counts: xr.DataArray, where: str) -> str:
    others = [d for d in counts.dims if d not in ("y", "x")]
    if len(others) != 1 or not {"y", "x"} <= set(counts.dims):
        raise SchemaError(
            f"{where} has the wrong dims",
            [Problem(where, "dims (exposure or shot, y, x)", f"dims {counts.dims}")],
        )
    return str(others[0])


def _quadratic_through_zero(
    exposure: np.ndarray, values: np.ndarray, top: float
) -> tuple[float, float] | None:
    """Least-squares ``v = c1 X + c2 X^2`` over samples with ``0 <= X <= top``; None if unfit."""
    keep = np.isfinite(exposure)
    x, v = exposure[keep], values[keep]
    sel = (x >= 0) & (x <= top)
    if sel.sum() < 16:
        return None
    x, v = x[sel] / top, v[sel]  # scaled for conditioning
    x2 = x * x
    a = np.array([[np.dot(x, x), np.dot(x, x2)], [np.dot(x, x2), np.dot(x2, x2)]])
    rhs = np.array([np.dot(x, v), np.dot(x2, v)])
    try:
        c1, c2 = np.linalg.solve(a, rhs)
    except np.linalg.LinAlgError:
        return None
    c1, c2 = c1 / top, c2 / top**2
    if not c1 > 0 or not c1 + 2 * c2 * top > 0:  # not increasing over the fit range
        return None
    return float(c1), float(c2)


def _invert_quadratic(v: np.ndarray, c1: float, c2: float) -> np.ndarray:
    """``X`` with ``c1 X + c2 X^2 = v`` on the increasing branch through 0 (stable form)."""
    root = np.sqrt(np.maximum(c1 * c1 + 4.0 * c2 * v, 0.0))
    return 2.0 * v / (c1 + root)


class _LowSnrSeries(NamedTuple):
    """The frames of a low-SNR series, checked (:func:`_checked_low_snr_series`)."""

    raw_values: np.ndarray
    """(exposure, y, x) integer pixel values [DN]."""
    times: np.ndarray
    """(exposure,) exposure times [s], strictly increasing."""
    dark_mean: np.ndarray
    """(exposure, y, x) float64 mean dark frame of each exposure time [DN]."""
    depth: int
    levels: int
    """Integer levels of the stretch."""


def _checked_low_snr_series(
    series: xr.Dataset | xr.DataArray,
    dark: xr.Dataset | xr.DataArray,
    *,
    bit_depth: int | None,
    levels: int | None,
    filter_size: float,
    truncate: float,
    where: str,
) -> _LowSnrSeries:
    """The series of :func:`recover_oecf_low_snr` read once, with its dark frames, checked.

    Raises
    ------
    SchemaError
        Wrong dims, no ``exposure_time`` coord along the series, non-integer data, an unknown
        bit depth.
    CalibrationError
        Fewer than two exposures, unsorted or duplicate exposure times, a filter size, a
        truncation or fewer than 16 levels that are not allowed, values beyond the bit depth,
        saturated pixels, a dark frame missing for an exposure time or of another size.
    """
    counts = counts_array(series)
    dim = _series_dim(counts, where)
    check_integer(counts, where)
    depth = check_bit_depth(
        counts.attrs.get("bit_depth") if bit_depth is None else bit_depth,
        where=f"{where}.attrs['bit_depth']",
    )
    if "exposure_time" not in counts.coords or counts["exposure_time"].dims != (dim,):
        raise SchemaError(
            f"{where} needs an exposure_time coord along {dim!r}",
            [
                Problem(
                    f"{where}:exposure_time",
                    f"a coord ({dim},) [s]",
                    f"coords {sorted(map(str, counts.coords))}",
                )
            ],
        )
    if counts.sizes[dim] < 2:
        raise CalibrationError(
            f"{where}: an exposure series needs at least 2 exposures, got {counts.sizes[dim]}"
        )
    check_exposure_times(counts["exposure_time"], dim, where)
    warn_if_geometric(counts["exposure_time"], dim, where)
    if not filter_size > 0 or not truncate > 0:
        raise CalibrationError(
            f"{where}: filter_size and truncate must be positive, got {filter_size} and {truncate}"
        )
    levels = 2**depth if levels is None else int(levels)
    if levels < 16:
        raise CalibrationError(f"{where}: levels must be at least 16, got {levels}")
    counts = counts.transpose(dim, "y", "x").load()  # the series (a few frames), read once
    times = np.asarray(counts["exposure_time"].values, dtype=np.float64)
    ny, nx = counts.sizes["y"], counts.sizes["x"]
    dark_mean = np.asarray(
        dark_frames_at(dark, times, used_by=where, dim=dim, frame_shape=(ny, nx))["mean"].values,
        dtype=np.float64,
    )
    raw_values = np.asarray(counts.values)
    lo_code, hi_code = int(raw_values.min()), int(raw_values.max())
    if lo_code < 0 or hi_code > 2**depth - 1:
        raise CalibrationError(
            f"{where}: pixel values must lie in [0, {2**depth - 1}], found [{lo_code}, {hi_code}]"
        )
    saturated = saturated_frames(counts, depth)
    if saturated.any():
        raise CalibrationError(
            f"{where}: saturated pixels (value {2**depth - 1}) at "
            f"exposure_time {times[saturated].tolist()} s in a low-SNR "
            "series; use shorter exposures"
        )
    return _LowSnrSeries(raw_values, times, dark_mean, depth, levels)


def _filtered_above_dark(
    frames: _LowSnrSeries, filter_size: float, truncate: float, where: str
) -> np.ndarray:
    """Steps (1) and (2) of :func:`recover_oecf_low_snr`: each frame less its dark frame (in
    float, negative values kept), Gaussian-filtered with ``sigma = filter_size / 5``
    truncated at ``truncate`` sigmas, without the border of the kernel radius. Returns
    (exposure, pixel) float64; a :class:`CalibrationError` for frames smaller than the
    kernel."""
    from scipy import ndimage

    raw_values, times, dark_mean = frames.raw_values, frames.times, frames.dark_mean
    ny, nx = raw_values.shape[1:]
    sigma = filter_sigma(filter_size)
    radius = int(math.ceil(filter_radius(filter_size, truncate=truncate)))
    if ny <= 2 * radius or nx <= 2 * radius:
        raise CalibrationError(
            f"{where}: frames of {ny}x{nx} px are too small for "
            f"filter_size {filter_size} (kernel radius {radius} px)"
        )
    filtered = np.empty((times.size, ny - 2 * radius, nx - 2 * radius))
    for j in range(times.size):
        signal = raw_values[j].astype(np.float64) - dark_mean[j]  # negative values kept
        smooth = ndimage.gaussian_filter(signal, sigma, mode="nearest", truncate=truncate)
        filtered[j] = smooth[radius : ny - radius, radius : nx - radius]
    return filtered.reshape(times.size, -1)


def _debiased(
    table: np.ndarray,
    codes: np.ndarray,
    times: np.ndarray,
    weights: np.ndarray,
    values: np.ndarray,
    grid: np.ndarray,
    *,
    mid: float,
    fit_top: float,
    monotone: bool,
    where: str,
) -> tuple[np.ndarray, bool]:
    """Steps (6) and (7) of :func:`recover_oecf_low_snr` on Robertson's ``table`` over
    ``grid``: the reverse regression from the leave-one-out exposures of the samples
    (``codes`` at ``times``, filtered ``values``), then the quadratic through 0 fitted up to
    ``fit_top`` and cross-faded in below it (``fit_top <= 0``: no fit), made non-decreasing
    when ``monotone`` and normalised to 1 at ``mid``. Returns the table and whether the
    quadratic was fitted."""
    from scipy.optimize import isotonic_regression

    exposure = exposure_estimates(codes, times, weights, table)
    table = reverse_regression(exposure, values, table, grid)
    fit = None
    if fit_top > 0:
        fit = _quadratic_through_zero(exposure, values, float(np.interp(fit_top, grid, table)))
    if fit is not None:
        alpha = np.clip((grid - 0.5 * fit_top) / (0.5 * fit_top), 0.0, 1.0)
        table = (1 - alpha) * _invert_quadratic(grid, *fit) + alpha * table
    if monotone:
        table = isotonic_regression(table).x
    mid_value = float(np.interp(mid, grid, table))
    if not mid_value > 0:
        raise CalibrationError(
            f"{where}: the de-biased response is not positive at the middle of the stretched interval"
        )
    return table / mid_value, fit is not None


def recover_oecf_low_snr(
    series: xr.Dataset | xr.DataArray,
    dark: xr.Dataset | xr.DataArray,
    *,
    filter_size: float = 25.0,
    bit_depth: int | None = None,
    levels: int | None = None,
    weighting: Weighting = "gaussian",
    tolerance: float = 1e-6,
    max_iterations: int = 5000,
    monotone: bool = True,
    max_bins: int = 1024,
    max_pixels: int | None = None,
    seed: int = 0,
    solver: Solver = "lanczos",
    debias: bool = True,
    fit_below: float | None = None,
    truncate: float = LOW_SNR_TRUNCATE,
) -> xr.Dataset:
    """Response of a camera working at its noise floor (the paper's extension of Robertson).

    Steps (paper section 4): (1) subtract the averaged dark frame of the same exposure time,
    in float, keeping negative values (clipping them would bias the result, paper Fig. 2);
    (2) Gaussian-filter every frame with the reconstruction's ``sigma = filter_size / 5``
    (:func:`~spectralize.nodes.filter_size.filter_sigma`), truncated at ``truncate`` sigmas
    (default 2.5: radius ``filter_size / 2``), keeping only pixels whose kernel lies inside
    the image; (3) stretch the interval ``[lo, hi]`` of filtered values to the integer range
    ``0 .. levels-1`` and round; (4) run Robertson (:func:`~.robertson_response`) on these
    codes; (5) map stretched code ``k`` back to the dark-subtracted pixel value
    ``lo + k (hi - lo) / (levels - 1)``; with ``debias`` (default) two more steps follow:
    (6) de-bias by reverse regression and (7) fit the lowest values through 0 (see Notes).

    Filtering averages many pixels, so the noise (Gaussian read noise, shot noise and the
    quantisation of ``floor`` in eq. 5, which the noise dithers) shrinks by the filter
    (white noise by about ``2 sqrt(pi) sigma``) and the recovered response holds down to
    pixel values with per-pixel SNR of 1 or less.

    Parameters
    ----------
    series
        Integer frames ``(exposure or shot, y, x)`` [DN] of a spatially smooth target (white
        reference, grey card, smooth illumination gradient) with an ``exposure_time`` coord
        [s] along the first dim; a Dataset with variable ``counts`` (group ``raw/spectral``
        of one wavelength) works as well.
    dark
        Group ``dark`` (``mean`` (exposure_time, y, x) float [DN]) or that DataArray; it must
        have a frame for every exposure time of ``series``.
    filter_size
        Gaussian filter size ``s`` [px] (eq. 3); ``sigma = s / 5``.
    bit_depth
        ADC bit depth; default ``attrs["bit_depth"]``.
    levels
        Number of integer levels of the stretch; default ``2**bit_depth`` ("the full range of
        integers corresponding to the camera's bit depth").
    weighting, tolerance, max_iterations, monotone, max_bins, solver
        As for :func:`~.robertson_response`; the weights apply to the stretched codes, whose
        ends are the extremes of the data, not saturation.
    max_pixels, seed
        Optional reproducible subset of filtered pixel positions.
    debias
        Steps (6) and (7): replace Robertson's estimate ``E[x t | v]`` by the reverse
        regression ``E[v | x t]`` and fit the lowest values through 0 (Notes). ``False``:
        the plain fixed point of step (4).
    fit_below
        Top [DN above dark] of the quadratic fit through 0 of step (7); the fit replaces the
        table below ``fit_below / 2`` and is cross-faded into it up to ``fit_below``.
        Default: a tenth of the top of the stretched interval. 0 switches step (7) off.
    truncate
        Support of the Gaussian in sigmas (``scipy.ndimage.gaussian_filter``'s ``truncate``;
        :func:`~spectralize.nodes.filter_size.filter_radius`); frames lose a border of the
        kernel radius. Default :data:`LOW_SNR_TRUNCATE`.

    Returns
    -------
    xarray.Dataset
        Variable ``response`` (code): ``code`` is the dark-subtracted pixel value [DN]
        (fractional, may be negative) on a grid of ``levels`` points spanning ``[lo, hi]``;
        values are relative exposures normalised to 1 at the middle of the grid. Attrs as
        :func:`~.recover_oecf` plus ``dark_subtracted=True``, ``dark_level`` (mean dark value
        [DN]; add it to ``code`` for raw pixel values), ``stretch_low``, ``stretch_high``,
        ``filter_size``, ``levels``, ``debiased``, ``fit_below`` (NaN when step (7) did not
        run). ``iterations``/``converged`` are those of Robertson's iteration (step 4).

    Raises
    ------
    SchemaError
        Wrong dims, non-integer data, unknown bit depth.
    CalibrationError
        Fewer than two exposures, unsorted or duplicate exposure times, a dark frame missing
        for an exposure time or of another size, a frame smaller than the filter, filtered
        values without spread.

    Notes
    -----
    Domain: the returned table covers ``[lo, hi]``; :func:`~.apply_response` extrapolates
    linearly beyond it. The target must be smooth on the scale of the filter: the filter acts
    on pixel values, so a non-linear OECF mixes neighbouring exposures at edges.

    Why de-bias (step 6): Robertson's update sets ``f(m)`` to the mean exposure ``X = x t`` of
    the samples *observed* at ``m``, ``E[X | v]``. With noise of variance ``s^2`` on ``v``
    this is regression to the mean: ``E[X | v] ~ f(v + s^2 d/dv log p(v))``, ``p`` the
    density of observed values. At the bottom of a low-SNR series ``p`` falls steeply, and
    the bias is largest there (``docs/benchmarks_notes.md``, calibration). The noise is
    additive and independent of the exposure, so the reverse regression ``E[v | X]`` is
    unbiased: every sample gets the leave-one-out exposure ``X_ij = t_j x_i^(-j)`` from
    Robertson's irradiance step with the converged response (independent of the noise of
    sample ``j``), samples are binned by ``X`` at the levels of that response, and the mean
    ``X`` and mean ``v`` of each bin are a point of the curve (made monotone by pool adjacent
    violators, interpolated at the grid).

    Step (7): a handful of DN above dark the mean of a bin still scatters (filtered noise is
    correlated over the kernel, so few independent patches fall into one bin). The
    dark-subtracted response passes through 0 (zero exposure gives zero signal after
    subtracting the mean dark frame), and over a few DN it is smooth, so
    ``v = c1 X + c2 X^2`` is fitted by least squares to all samples with
    ``0 <= X <= f(fit_below)`` (noise in ``v`` only: unbiased) and inverted below
    ``fit_below``; negative values follow its increasing branch.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and Fig. 2.
    .. [2] Robertson, Borman, Stevenson 2003.
    """
    where = "recover_oecf_low_snr: series"
    frames = _checked_low_snr_series(
        series,
        dark,
        bit_depth=bit_depth,
        levels=levels,
        filter_size=filter_size,
        truncate=truncate,
        where=where,
    )
    depth, levels, times = frames.depth, frames.levels, frames.times
    values = _filtered_above_dark(frames, filter_size, truncate, where)
    if max_pixels is not None and values.shape[1] > max_pixels:
        rng = np.random.default_rng(seed)
        values = values[:, np.sort(rng.choice(values.shape[1], int(max_pixels), replace=False))]
    lo, hi = float(values.min()), float(values.max())
    if not hi - lo > 0:
        raise CalibrationError(f"{where}: filtered values have no spread ({lo} .. {hi})")
    step = (hi - lo) / (levels - 1)
    codes = np.rint((values - lo) / step).astype(np.int64)
    weights = weighting_function(np.arange(levels), black_level=-1.0, saturation=levels, kind=weighting)
    result = robertson_response(
        codes,
        times,
        n_codes=levels,
        weights=weights,
        tolerance=tolerance,
        max_iterations=max_iterations,
        monotone=monotone,
        max_bins=max_bins,
        solver=solver,
    )
    grid = lo + step * np.arange(levels)
    table, fitted = result.response, False
    fit_top = 0.1 * hi if fit_below is None else float(fit_below)
    if debias:
        table, fitted = _debiased(
            table,
            codes,
            times,
            weights,
            values,
            grid,
            mid=lo + step * (levels - 1) / 2,
            fit_top=fit_top,
            monotone=monotone,
            where=where,
        )
    attrs = {
        "bit_depth": depth,
        "method": "robertson2003_low_snr",
        "iterations": result.iterations,
        "converged": bool(result.converged),
        "tolerance": float(tolerance),
        "weighting": weighting,
        "dark_subtracted": True,
        "dark_level": float(frames.dark_mean.mean()),
        "stretch_low": lo,
        "stretch_high": hi,
        "filter_size": float(filter_size),
        "truncate": float(truncate),
        "levels": levels,
        "mid_code": float(grid[(levels - 1) // 2] + step * ((levels - 1) / 2 % 1)),
        "normalisation": "response at the middle of the stretched interval = 1",
        "debiased": bool(debias),
        "fit_below": float(fit_top) if fitted else float("nan"),
    }
    response = response_dataarray(table, result.samples, (), {}, grid, attrs)
    response["code"].attrs.update(long_name="dark-subtracted pixel value")
    return xr.Dataset({"response": response}, attrs={"bit_depth": depth})


def _low_snr_choice(
    counts: xr.DataArray, dark: xr.Dataset, depth: int, band: float | None, fraction: float
) -> tuple[int, np.ndarray]:
    """The band and the exposures (indices) of the low-SNR series of the white reference."""
    group = "raw/white_reference"
    times = counts["spectral_exposure_time"].values
    level = np.asarray(
        dark_frames_at(dark, times, used_by=f"{group}:spectral_counts", dim="spectral_exposure")["mean"]
        .mean(("y", "x"))
        .values
    )
    mean = np.asarray(counts.mean(("y", "x")).values) - level[None, :]
    unsaturated = ~saturated_frames(counts, depth)
    low = unsaturated & (mean <= fraction * (2**depth - 1 - level.mean()))
    wavelengths = counts["wavelength"].values
    if band is None:
        score = [
            (int(low[j].sum()), float(mean[j][low[j]].max()) if low[j].any() else -1.0)
            for j in range(low.shape[0])
        ]
        j = max(range(len(score)), key=lambda k: score[k])
    else:
        hit = np.flatnonzero(np.isclose(wavelengths, band, atol=1e-6))
        if hit.size == 0:
            raise CalibrationError(
                f"{group}:wavelength has no band at {band} nm; bands: {wavelengths.tolist()}"
            )
        j = int(hit[0])
    picks = np.flatnonzero(low[j])
    if picks.size < 2:
        raise CalibrationError(
            f"{group}:spectral_counts: band {wavelengths[j]} nm has {picks.size} unsaturated "
            f"exposure(s) with signal below {fraction:g} of the range (mean signal above dark "
            f"{np.round(mean[j], 2).tolist()} DN); the low-SNR extension needs at least 2"
        )
    return j, picks


def recover_spectral_oecf(
    white_reference: xr.Dataset,
    dark: xr.Dataset,
    *,
    band: Annotated[
        float | None,
        Field(
            description="wavelength [nm] of the white "
            "reference's exposure series used for the low-SNR "
            "extension; None: the band with the most "
            "unsaturated exposures at low signal"
        ),
    ] = None,
    low_signal_fraction: Annotated[
        float,
        Field(
            gt=0,
            le=1,
            description="exposures whose "
            "mean signal above dark is at most this "
            "fraction of the code range form the low-SNR "
            "series",
        ),
    ] = 0.15,
    filter_size: Annotated[
        float,
        Field(gt=0, description="Gaussian filter size of the low-SNR extension [px] (sigma = size / 5)"),
    ] = 25.0,
    full_exposures: Annotated[
        int,
        Field(
            ge=2,
            description="longest unsaturated exposures "
            "per band used for the full-range Robertson "
            "response",
        ),
    ] = 4,
    tolerance: Annotated[
        float, Field(gt=0, lt=1e-2, description="Robertson convergence tolerance")
    ] = 1e-6,
) -> xr.Dataset:
    """Spectral camera response: the paper's low-SNR extension joined to a full-range one.

    1. Low end: :func:`recover_oecf_low_snr` on the white
       reference's exposure series of one band (``band``, default the band with the most
       unsaturated exposures whose mean signal is below ``low_signal_fraction`` of the
       range): dark subtracted (negative values kept), Gaussian-filtered, stretched, Robertson.
       Only unsaturated exposures are passed.
    2. Full range: :func:`~.recover_oecf` over raw codes on the
       ``full_exposures`` longest unsaturated exposures of every band (each band one
       "image" with its own exposure times): the bands' different brightness spreads the
       samples over the whole code range.
    3. :func:`~.combine_responses` scales the low-SNR response onto
       the full one and cross-fades them (default overlap: 50..90 % of the low interval).

    Returns
    -------
    xarray.Dataset
        Group ``calibration/oecf_spectral``: ``response`` (code) [1], ``code`` = pixel value
        above the dark frame [DN] (fractional, may be negative), variable attrs
        ``dark_subtracted=True`` and ``dark_level``; plus the parts ``low_snr_response``
        (low_snr_code) and ``full_response`` (raw_code) for diagnostics. Group attrs
        ``band``, ``low_snr_exposure_time``, ``filter_size``, ``overlap``, ``scale``.

    Raises
    ------
    CalibrationError
        A dark frame missing for an exposure time (naming ``dark:mean`` and the time), too
        few low-signal exposures, bands saturated in every exposure.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and Fig. 2.
    """
    group = "raw/white_reference"
    raise_first(spectral_oecf_refusals(white_reference))
    counts, depth = target_spectral_series(white_reference, group)
    j, picks = _low_snr_choice(counts, dark, depth, band, low_signal_fraction)
    series = (
        counts.isel(wavelength=j, spectral_exposure=picks)
        .rename(spectral_exposure="exposure")
        .rename(spectral_exposure_time="exposure_time")
    )
    series = series.drop_vars([c for c in series.coords if c != "exposure_time"])
    series = series.assign_attrs(bit_depth=depth)
    # lazy: the low-SNR series reads the dark frames of its own exposure times only
    try:
        low = recover_oecf_low_snr(series, dark["mean"], filter_size=filter_size, tolerance=tolerance)
    except CalibrationError as error:
        raise CalibrationError(
            f"{group}:spectral_counts (band {float(counts['wavelength'][j])} nm): {error}"
        ) from None

    # full range: the longest `full_exposures` unsaturated exposures of every band
    top = ~saturated_frames(counts, depth)
    rows, times = [], []
    all_times = counts["spectral_exposure_time"].values
    for k in range(counts.sizes["wavelength"]):
        ok = np.flatnonzero(top[k])
        if ok.size >= full_exposures:
            chosen = ok[-full_exposures:]
            rows.append((k, chosen))
            times.append(all_times[chosen])
    if len(rows) == 0:
        raise CalibrationError(
            f"{group}:spectral_counts: no band has {full_exposures} unsaturated exposures "
            "for the full-range response"
        )
    # the raw codes of the chosen frames, read band by band into one array (no list of
    # copies to stack): the full-range Robertson response pools them all
    stack = np.empty((len(rows), full_exposures, counts.sizes["y"], counts.sizes["x"]), counts.dtype)
    for i, (k, chosen) in enumerate(rows):
        stack[i] = counts.isel(wavelength=k, spectral_exposure=chosen).values
    full_in = xr.DataArray(
        stack,
        dims=("image", "exposure", "y", "x"),
        coords={"exposure_time": (("image", "exposure"), np.stack(times))},
        attrs={"bit_depth": depth},
    )
    try:
        full = recover_oecf(full_in, tolerance=tolerance)
    except CalibrationError as error:
        raise CalibrationError(f"{group}:spectral_counts (full range): {error}") from None
    combined = combine_responses(low, full)
    response = combined["response"]
    low_r = low["response"].rename(code="low_snr_code").rename("low_snr_response")
    full_r = full["response"].rename(code="raw_code").rename("full_response")
    out = xr.Dataset(
        {
            "response": response.drop_vars("samples"),
            "low_snr_response": low_r.drop_vars("samples").assign_attrs(
                long_name="low-SNR response (paper's extension), before scaling"
            ),
            "full_response": full_r.drop_vars("samples").assign_attrs(
                long_name="full-range Robertson response over raw codes"
            ),
        },
        attrs={
            "bit_depth": depth,
            "band": float(counts["wavelength"][j]),
            "low_snr_exposure_time": [float(t) for t in series["exposure_time"].values],
            "filter_size": float(filter_size),
            "full_exposures": int(full_exposures),
            "full_bands": len(rows),
            "dark_level": float(response.attrs["dark_level"]),
            "overlap": [float(v) for v in response.attrs["overlap"]],
            "scale": float(response.attrs["scale"]),
            "converged": bool(response.attrs.get("converged", True)),
            "source": group,
        },
    )
    out["code"].attrs.update(units="DN", long_name="pixel value above the dark frame")
    out["low_snr_code"].attrs.update(units="DN", long_name="pixel value above the dark frame")
    out["raw_code"].attrs.update(units="DN", long_name="raw pixel value")
    return out


def spectral_oecf_refusals(white_reference: xr.Dataset) -> list[SpectralizeError]:
    """What :func:`recover_spectral_oecf` refuses in the white reference before computing.

    The spectral camera's bit depth (8..16) and the band series' exposure times: positive,
    finite and strictly increasing along ``spectral_exposure`` (its value check).
    """
    group = "raw/white_reference"
    return refused(
        lambda: check_bit_depth(
            white_reference.attrs.get("spectral_bit_depth"), where=f"{group}.attrs['spectral_bit_depth']"
        ),
        lambda: check_exposure_times(
            white_reference["spectral_exposure_time"].transpose(..., "spectral_exposure"),
            "spectral_exposure",
            f"recover_spectral_oecf: {group}",
        ),
    )
