"""Spectral calibration (paper section 4): quantum efficiency, RGB camera matrix C, cross-check.

- :func:`band_signal`: dark-subtracted, linearised (OECF) signal per second of exposure of
  band-filtered frames; the common first step of everything spectral.
- :func:`quantum_efficiency`: ``Q_lambda`` per band from white-reference shots: the band
  signal divided by the known white reflectance and by the measured illuminant spectrum
  (eq. 5: ``I = f^-1(x t Q_lambda)``).
- :func:`camera_matrix`: the RGB camera matrix ``C`` (channel, wavelength) of eq. 1 from
  colour-checker shots with known spectra, by non-negative least squares with a
  second-difference smoothness penalty.
- :func:`cross_validate`: paper Fig. 4, RGB predicted through ``C`` from a spectral capture
  of the colour checker against the measured RGB, error per patch as a table (the figure is
  :func:`spectralize.nodes.evaluation.figures_calibration.plot_cross_validation`).
- :func:`calibrate_spectral` (node ``calibrate_spectral``): all three from the
  ``raw/white_reference`` and ``raw/colour_checker`` groups.

References
----------
Fast Capture of Spectral Image Series, section 4 ("Calibration", Figs. 3 and 4) and eq. 5.
M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2), 2003
(the OECF used for linearisation).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Annotated

import dask
import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.engine import Choices
from spectralize.nodes.calibration.camera_lobes import (
    WEAK_LIGHT_WEIGHT,
    check_chart_pair,
    lobe_camera_matrix,
)
from spectralize.nodes.calibration.dark import dark_frames_at
from spectralize.nodes.calibration.exposure_series import (
    check_bit_depth,
    frame_chunks,
    frame_flags,
    saturated_frames,
    target_spectral_series,
)
from spectralize.nodes.calibration.hdr import merge_hdr
from spectralize.nodes.calibration.matched_level_qe import level_table, matched_quantum_efficiency
from spectralize.nodes.calibration.oecf.response import apply_response
from spectralize.nodes.calibration.rgb_transform import rgb_transform
from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "band_signal",
    "quantum_efficiency",
    "measured_illuminant_on_bands",
    "camera_matrix",
    "cross_validated_smoothness",
    "SMOOTHNESS_CANDIDATES",
    "patch_means",
    "predict_rgb",
    "cross_validate",
    "calibrate_spectral",
    "CAMERA_MATRIX_METHODS",
    "shot_levels",
]


# -- band signal -------------------------------------------------------------------------------
def _shots(data: xr.Dataset | xr.DataArray, where: str) -> xr.DataArray:
    counts = data["counts"] if isinstance(data, xr.Dataset) and "counts" in data else data
    if isinstance(counts, xr.Dataset):
        raise SchemaError(
            f"{where}: band-filtered shots break the raw/spectral contract",
            [
                Problem(
                    "counts",
                    "a variable (shot, y, x)",
                    f"variables {sorted(map(str, counts.data_vars))}",
                )
            ],
        )
    problems = []
    if counts.dims != ("shot", "y", "x"):
        problems.append(Problem("counts", "dims ('shot', 'y', 'x')", f"dims {counts.dims}"))
    for name in ("exposure_time", "wavelength"):
        if name not in counts.coords or counts[name].dims != ("shot",):
            found = f"dims {counts[name].dims}" if name in counts.coords else "nothing"
            problems.append(Problem(name, "a coord (shot,)", found))
    if problems:
        raise SchemaError(f"{where}: band-filtered shots break the raw/spectral contract", problems)
    times = np.asarray(counts["exposure_time"].values, dtype=np.float64)
    if not np.all(np.isfinite(times)) or np.any(times <= 0):
        raise CalibrationError(f"{where}: exposure_time must be positive, got {times.tolist()}")
    return counts


def _dark_for_shots(
    dark: xr.Dataset | xr.DataArray, counts: xr.DataArray, where: str
) -> tuple[xr.DataArray, xr.DataArray | None]:
    """Mean (and std, if any) dark frame of every shot's exposure time, (shot, y, x)."""
    frames = dark_frames_at(
        dark,
        counts["exposure_time"].values,
        used_by=where,
        dim="shot",
        frame_shape=(counts.sizes["y"], counts.sizes["x"]),
    )
    # the same frames, taken lazily from ``dark`` in the shots' frame chunks (frame_chunks:
    # one frame at 2048^2, thousands of small ones): no (shot, y, x) copy of the dark frames
    # is made (32 shots at 2048^2 would be 0.5 GB of float32 per variable), and a run of
    # small frames is not one piece per shot (15,000 at a full run's count: issue 27)
    source = dark if isinstance(dark, xr.Dataset) else xr.Dataset({"mean": dark})
    known = np.asarray(source["exposure_time"].values, dtype=np.float64)
    positions = np.array(
        [int(np.flatnonzero(known == t)[0]) for t in frames["exposure_time"].values], dtype=int
    )
    step = frame_chunks(counts, ("shot",)).chunks[0][0]

    def per_shot(name: str) -> xr.DataArray:
        stack = source[name].transpose("exposure_time", "y", "x")
        stack = stack.drop_vars([c for c in stack.coords if "exposure_time" in stack[c].dims])
        if stack.chunks is None:
            stack = stack.chunk()  # wrap, no copy: the shots' frames are slices of it
        pieces = [
            stack.isel(exposure_time=xr.DataArray(positions[i : i + step], dims="shot"))
            for i in range(0, len(positions), step)
        ]
        return xr.concat(pieces, dim="shot") if len(pieces) > 1 else pieces[0]

    return per_shot("mean"), per_shot("std") if "std" in frames else None


def band_signal(
    shots: xr.Dataset | xr.DataArray,
    dark: xr.Dataset | xr.DataArray,
    *,
    response: xr.Dataset | xr.DataArray | None = None,
) -> xr.DataArray:
    """Dark-subtracted, linearised signal per second of band-filtered frames.

    Parameters
    ----------
    shots
        Group ``raw/spectral`` (or its ``counts``): (shot, y, x) integer [DN] with coords
        ``exposure_time`` [s] and ``wavelength`` [nm] per shot.
    dark
        Group ``dark``: ``mean`` (exposure_time, y, x) [DN]; a frame for every exposure time.
    response
        The spectral camera's OECF: from
        :func:`~spectralize.nodes.calibration.oecf.recover_oecf_low_snr` or
        :func:`~spectralize.nodes.calibration.oecf.combine_responses` (over dark-subtracted values:
        ``f(I - dark)``) or :func:`~spectralize.nodes.calibration.oecf.recover_oecf` (over raw codes:
        ``f(I) - f(dark)``). ``None``: a linear camera, ``I - dark``.

    Returns
    -------
    xarray.DataArray
        (shot, y, x) float64, ``f(...) / exposure_time``, units ``"1"`` (relative exposure
        per second). Negative values (noise below the dark level) are kept: clipping would
        bias every average taken later (paper Fig. 2). Lazy input stays lazy.

    Raises
    ------
    SchemaError, CalibrationError
        Wrong dims or coords, a dark frame missing for an exposure time or of another size.

    Notes
    -----
    ``signal = f(I - dark_t) / t`` for a response over dark-subtracted values,
    ``(f(I) - f(dark_t)) / t`` for one over raw codes (eq. 5 solved for ``x Q``).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 5 and Fig. 2.
    """
    where = "band_signal"
    counts = _shots(shots, where)
    mean, _ = _dark_for_shots(dark, counts, where)
    return _linearise(counts, mean, response, where)


def _linearise(
    counts: xr.DataArray, mean: xr.DataArray, response: xr.Dataset | xr.DataArray | None, where: str
) -> xr.DataArray:
    raw = counts.astype(np.float64)
    if response is None:
        linear = raw - mean
    else:
        table = response["response"] if isinstance(response, xr.Dataset) else response
        if table.ndim != 1:
            raise CalibrationError(
                f"{where}: the spectral camera's response must be "
                f"monochrome (code,), got dims {table.dims}"
            )
        if table.attrs.get("dark_subtracted"):
            linear = apply_response(raw - mean, table)
        else:
            linear = apply_response(raw, table) - apply_response(mean, table)
    out = linear / counts["exposure_time"]
    return out.assign_attrs(units="1", long_name="linearised dark-subtracted signal per second")


# -- quantum efficiency -------------------------------------------------------------------------
def _on_wavelengths(
    spectrum: xr.DataArray | float, wavelengths: np.ndarray, name: str, where: str
) -> np.ndarray:
    if not isinstance(spectrum, xr.DataArray):
        value = float(spectrum)
        if not value > 0:
            raise CalibrationError(f"{where}: {name} must be positive, got {value}")
        return np.full(wavelengths.shape, value)
    if spectrum.dims != ("wavelength",):
        raise SchemaError(
            f"{where}: {name} must be a spectrum over 'wavelength'",
            [Problem(name, "dims ('wavelength',)", f"dims {spectrum.dims}")],
        )
    grid = np.asarray(spectrum["wavelength"].values, dtype=np.float64)
    order = np.argsort(grid)
    grid, values = grid[order], np.asarray(spectrum.values, dtype=np.float64)[order]
    outside = (wavelengths < grid[0] - 1e-9) | (wavelengths > grid[-1] + 1e-9)
    if outside.any():
        raise CalibrationError(
            f"{where}: {name} covers {grid[0]}..{grid[-1]} nm but shots are at "
            f"{wavelengths[outside].tolist()} nm"
        )
    result = np.interp(wavelengths, grid, values)
    if np.any(~(result > 0)):
        bad = wavelengths[~(result > 0)].tolist()
        raise CalibrationError(f"{where}: {name} is not positive at {bad} nm")
    return result


def quantum_efficiency(
    white: xr.Dataset | xr.DataArray,
    dark: xr.Dataset | xr.DataArray,
    illuminant: xr.DataArray,
    *,
    reflectance: xr.DataArray | float = 1.0,
    response: xr.Dataset | xr.DataArray | None = None,
    roi: Mapping[str, slice] | None = None,
    min_snr: float = 1.0,
) -> xr.Dataset:
    """Quantum efficiency ``Q_lambda`` per band from white-reference shots.

    ``Q_lambda = mean_roi(f(I - dark) / t) / (rho_lambda L_lambda)`` (eq. 5 with the radiance
    of a white reference ``x = rho L``); several shots at one wavelength are averaged.

    Parameters
    ----------
    white
        Shots of a white diffuse reference: ``raw/spectral``-like (shot, y, x) with coords
        ``wavelength`` [nm] and ``exposure_time`` [s].
    dark
        Group ``dark`` (``mean``, optionally ``std``) with every exposure time of ``white``.
    illuminant
        Measured spectral radiance of the illumination, (wavelength,), any positive units;
        linearly interpolated to the shot wavelengths.
    reflectance
        Known reflectance of the white reference: a number or a spectrum over wavelength.
    response
        The spectral camera's OECF (see :func:`band_signal`); ``None`` for a linear camera.
    roi
        Region of the reference, e.g. ``{"y": slice(10, 90), "x": slice(20, 80)}``; default
        the whole frame.
    min_snr
        Smallest accepted ratio of the mean dark-subtracted signal in the ROI [DN] to the
        per-pixel noise (the mean of ``dark.std`` in the ROI, or the spatial standard
        deviation of the dark-subtracted ROI when ``dark`` has no ``std``).

    Returns
    -------
    xarray.Dataset
        ``quantum_efficiency`` (wavelength) float64, units ``"1"`` (relative: in the units of
        the response's normalisation per second per unit of ``illuminant``), and ``snr``
        (wavelength), the per-pixel SNR of the reference in each band.

    Raises
    ------
    CalibrationError
        A shot darker than ``min_snr`` times the noise (naming shot, wavelength, signal and
        noise), a dark frame missing, an illuminant or reflectance not covering a band or
        not positive, an empty ROI.
    SchemaError
        Wrong dims or coords.

    Notes
    -----
    Domain: integer DN. Range: ``Q >= 0`` for a well-exposed reference; the scale is that of
    the illuminant and the response normalisation, which the camera matrix ``C`` and the
    band radiances share, so relative radiances stay consistent.

    References
    ----------
    Fast Capture of Spectral Image Series, section 4 ("taking images of a white diffuse
    reference surface under the known LED illumination and dividing the response by the
    LED spectrum") and Fig. 3.
    """
    where = "quantum_efficiency"
    counts = _shots(white, where)
    mean, std = _dark_for_shots(dark, counts, where)
    region = dict(roi or {})
    unknown = set(region) - {"y", "x"}
    if unknown:
        raise CalibrationError(f"{where}: roi may only select y and x, got {sorted(unknown)}")
    part = counts.isel(region)
    if part.sizes["y"] * part.sizes["x"] == 0:
        raise CalibrationError(f"{where}: the roi {region} selects no pixel")
    # one shot at a time: every reduction below reads the shots chunk by chunk (a float64
    # copy of 32 shots is 1.1 GB at 2048^2, the response's lookup needs several)
    part = frame_chunks(part, ("shot",))
    dark_part = frame_chunks(mean.isel(region), ("shot",))
    raw_dn = part.astype(np.float64) - dark_part
    spread = std.isel(region).mean(("y", "x")) if std is not None else raw_dn.std(("y", "x"))
    level_, noise_ = dask.compute(raw_dn.mean(("y", "x")), spread)
    level = np.asarray(level_.values)
    noise = np.asarray(noise_.values, dtype=np.float64)
    snr = level / np.maximum(noise, 1e-12)
    wavelengths = np.asarray(counts["wavelength"].values, dtype=np.float64)
    for i in np.flatnonzero(~(snr >= min_snr)):
        raise CalibrationError(
            f"{where}: white reference shot {int(i)} ({wavelengths[i]} nm, exposure_time "
            f"{float(counts['exposure_time'].values[i])} s) is darker than the noise: mean "
            f"signal {level[i]:.3g} DN above dark vs noise {noise[i]:.3g} DN (SNR "
            f"{snr[i]:.3g} < min_snr {min_snr}); use a longer exposure or more light"
        )
    signal = _linearise(part, dark_part, response, where)
    per_shot = np.asarray(signal.mean(("y", "x")).values, dtype=np.float64)
    rho = _on_wavelengths(reflectance, wavelengths, "reflectance", where)
    light = _on_wavelengths(illuminant, wavelengths, "illuminant", where)
    q_shot = per_shot / (rho * light)
    bands, inverse = np.unique(wavelengths, return_inverse=True)
    q = np.bincount(inverse, q_shot) / np.bincount(inverse)
    snr_band = np.bincount(inverse, snr) / np.bincount(inverse)
    return xr.Dataset(
        {
            "quantum_efficiency": (
                "wavelength",
                q,
                {"units": "1", "long_name": "relative quantum efficiency Q_lambda (eq. 5)"},
            ),
            "snr": (
                "wavelength",
                snr_band,
                {"units": "1", "long_name": "per-pixel SNR of the white reference"},
            ),
        },
        coords={"wavelength": ("wavelength", bands, {"units": "nm", "long_name": "wavelength"})},
        attrs={
            "method": "white reference / (reflectance * illuminant)",
            "shots": int(counts.sizes["shot"]),
        },
    )


def measured_illuminant_on_bands(illuminant: xr.DataArray, wavelength: np.ndarray) -> xr.DataArray:
    """The measured illuminant ``L`` (wavelength,) on the band wavelengths, in band radiance units.

    ``Q_lambda`` divides the white reference's band signal by ``rho_lambda L_lambda`` (eq. 5,
    :func:`quantum_efficiency`), so band radiance ``x = I / (t Q)`` is relative to the measured
    illuminant: a white diffuser of reflectance 1 has band radiance ``L_lambda``. ``L`` in band
    radiance units is therefore the measured spectrum itself, taken where ``Q`` took it: linearly
    interpolated onto the band centres (the white reference's band series carries no bandpass;
    the identity where the raw group already holds it on the bands, as ingest writes it).

    Parameters
    ----------
    illuminant
        ``raw/white_reference`` ``illuminant`` (wavelength,), relative spectral radiance.
    wavelength
        The band centre wavelengths [nm] of ``Q``.

    Returns
    -------
    xarray.DataArray
        ``illuminant`` (wavelength,) float64, units ``"1"`` (relative spectral radiance, the
        unit of band radiance), attrs ``source`` and ``method``.

    Raises
    ------
    CalibrationError
        The illuminant does not cover a band or is not positive there (naming
        ``raw/white_reference:illuminant``, the bands and values).
    SchemaError
        Not a spectrum over ``wavelength``.

    References
    ----------
    Fast Capture of Spectral Image Series, section 4 and eq. 5 ("dividing the response by the
    LED spectrum").
    """
    bands = np.asarray(wavelength, dtype=np.float64)
    where = "raw/white_reference:illuminant"
    values = _on_wavelengths(illuminant, bands, "illuminant", where)
    return xr.DataArray(
        values,
        dims="wavelength",
        coords={"wavelength": ("wavelength", bands, {"units": "nm", "long_name": "wavelength"})},
        attrs={
            "units": "1",
            "long_name": "measured illuminant L on the band wavelengths (relative spectral "
            "radiance: the band radiance of a white diffuser of reflectance 1)",
            "source": where,
            "method": "linear interpolation onto the band centres (as Q divides by it, eq. 5)",
        },
    )


# -- camera matrix C ----------------------------------------------------------------------------
def _second_difference(n: int) -> np.ndarray:
    d = np.zeros((n - 2, n))
    rows = np.arange(n - 2)
    d[rows, rows], d[rows, rows + 1], d[rows, rows + 2] = 1.0, -2.0, 1.0
    return d


def camera_matrix(
    rgb: xr.DataArray,
    spectra: xr.DataArray,
    *,
    smoothness: float = 1e-3,
    nonnegative: bool = True,
) -> xr.Dataset:
    """The RGB camera matrix ``C`` (channel, wavelength) from colour-checker shots.

    Solves, per channel ``c``, ``min_C ||S C_c - R_c||^2 + mu ||D2 C_c||^2`` subject to
    ``C_c >= 0`` (``scipy.optimize.nnls`` on the augmented system ``[S; sqrt(mu) D2]``),
    where ``S`` (patch, wavelength) holds the known spectral radiance of the patches, ``R``
    (patch, channel) the measured RGB radiance and ``D2`` the second difference along
    wavelength. ``mu = smoothness * ||S||_F^2 / ||D2||_F^2`` makes ``smoothness``
    independent of the units and of the number of patches and bands.

    Parameters
    ----------
    rgb
        Measured RGB radiance of the patches (patch, channel), e.g. :func:`patch_means` of
        an HDR image.
    spectra
        Known spectral radiance of the same patches (patch, wavelength): reflectance times
        illuminant, in the units the spectral camera reports.
    smoothness
        Relative weight of the smoothness penalty (0: none). With fewer patches than bands
        (24 colour-checker patches, 32 bands) some smoothness is needed for a unique answer.
    nonnegative
        Constrain ``C >= 0`` (sensitivities cannot be negative).

    Returns
    -------
    xarray.Dataset
        ``camera_matrix`` (channel, wavelength) float64 with units ``"1"``; ``residual``
        (patch, channel), ``S C - R``. Attrs ``smoothness``, ``mu``, ``nonnegative``,
        ``relative_rms_residual``.

    Raises
    ------
    SchemaError
        Wrong dims.
    CalibrationError
        Patches that do not match (count or labels), fewer than 3 bands, NaN or inf.

    Notes
    -----
    Domain: non-negative radiances. Range: ``C >= 0`` when ``nonnegative``. ``predict_rgb``
    gives ``C S`` for any spectra on the same wavelengths.

    References
    ----------
    Fast Capture of Spectral Image Series, eq. 1 (matrix ``C``) and section 4.
    """
    from scipy import optimize

    where = "camera_matrix"
    check_chart_pair(rgb, spectra, where)
    if smoothness < 0:
        raise CalibrationError(f"{where}: smoothness must be >= 0, got {smoothness}")
    s = np.asarray(spectra.transpose("patch", "wavelength").values, dtype=np.float64)
    r = np.asarray(rgb.transpose("patch", "channel").values, dtype=np.float64)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(r))):
        raise CalibrationError(f"{where}: rgb and spectra must be finite")
    n_bands = s.shape[1]
    d2 = _second_difference(n_bands)
    mu = smoothness * float(np.sum(s**2)) / float(np.sum(d2**2))
    a = np.vstack([s, np.sqrt(mu) * d2])
    c = np.empty((r.shape[1], n_bands))
    for k in range(r.shape[1]):
        b = np.concatenate([r[:, k], np.zeros(n_bands - 2)])
        if nonnegative:
            c[k] = optimize.nnls(a, b, maxiter=50 * n_bands)[0]
        else:
            c[k] = np.linalg.lstsq(a, b, rcond=None)[0]
    residual = s @ c.T - r
    rel = float(np.sqrt(np.mean(residual**2)) / max(np.sqrt(np.mean(r**2)), 1e-300))
    coords = {
        "channel": rgb["channel"].values if "channel" in rgb.coords else np.arange(r.shape[1]),
        "wavelength": spectra["wavelength"].values
        if "wavelength" in spectra.coords
        else np.arange(n_bands),
    }
    patch = {"patch": rgb["patch"].values} if "patch" in rgb.coords else {}
    return xr.Dataset(
        {
            "camera_matrix": (
                ("channel", "wavelength"),
                c,
                {"units": "1", "long_name": "RGB camera matrix C (spectral sensitivity)"},
            ),
            "residual": (
                ("patch", "channel"),
                residual,
                {"units": "1", "long_name": "C S - R on the calibration patches"},
            ),
        },
        coords={**coords, **patch},
        attrs={
            "method": "nnls + second-difference penalty"
            if nonnegative
            else "least squares + second-difference penalty",
            "smoothness": float(smoothness),
            "mu": mu,
            "nonnegative": bool(nonnegative),
            "relative_rms_residual": rel,
        },
    )


SMOOTHNESS_CANDIDATES: tuple[float, ...] = tuple(float(v) for v in np.logspace(-3, 2, 11))
"""Smoothness values :func:`cross_validated_smoothness` chooses from (1e-3 .. 1e2, half decades)."""


def cross_validated_smoothness(
    rgb: xr.DataArray,
    spectra: xr.DataArray,
    *,
    candidates: tuple[float, ...] = SMOOTHNESS_CANDIDATES,
    nonnegative: bool = True,
) -> tuple[float, xr.DataArray]:
    """The smoothness of :func:`camera_matrix` that best predicts a patch left out.

    For every candidate, ``C`` is fitted to all patches but one and predicts the RGB of the
    one left out; the score is the mean over patches of ``|C s_p - R_p|^2 / |R_p|^2``
    (leave-one-out cross-validation). A chart's smooth spectra, under an illuminant with a
    narrow peak, leave many ``C`` that reproduce every patch: the fit alone cannot tell a
    sensitivity that peaks at 600 nm from one that puts its weight where the light is weak,
    and a fixed smoothness that suits one chart and light gives a wrongly shaped ``C`` on
    another. A patch left out is the test the fit has to pass
    (``tests/flows/test_foreign_capture.py`` checks the shape of ``C`` on a foreign capture).

    Parameters
    ----------
    rgb, spectra, nonnegative
        As :func:`camera_matrix`.
    candidates
        Smoothness values to try.

    Returns
    -------
    tuple
        The chosen smoothness (the smallest score, ties to the smoother) and the scores,
        a DataArray over ``smoothness``.

    References
    ----------
    .. [1] Stone, M. (1974). Cross-validatory choice and assessment of statistical
       predictions. J. R. Stat. Soc. B 36(2).
    .. [2] Fast Capture of Spectral Image Series, section 4 (C from a colour checker).
    """
    if not candidates:
        raise CalibrationError("cross_validated_smoothness: no candidate smoothness given")
    n = rgb.sizes["patch"]
    if n < 3:
        raise CalibrationError(f"cross_validated_smoothness: need at least 3 patches, got {n}")
    r = np.asarray(rgb.transpose("patch", "channel").values, dtype=np.float64)
    energy = np.maximum(np.sum(r**2, axis=1), 1e-300)
    scores = []
    for value in candidates:
        error = 0.0
        for p in range(n):
            keep = np.arange(n) != p
            c = camera_matrix(
                rgb.isel(patch=keep), spectra.isel(patch=keep), smoothness=value, nonnegative=nonnegative
            )["camera_matrix"]
            s = np.asarray(spectra.isel(patch=p).transpose("wavelength").values, dtype=np.float64)
            predicted = np.asarray(c.transpose("channel", "wavelength").values) @ s
            error += float(np.sum((predicted - r[p]) ** 2) / energy[p])
        scores.append(error / n)
    scores_arr = np.asarray(scores)
    best = int(np.flatnonzero(scores_arr <= scores_arr.min() * (1 + 1e-9))[-1])
    curve = xr.DataArray(
        scores_arr,
        dims="smoothness",
        coords={"smoothness": np.asarray(candidates, dtype=float)},
        attrs={"units": "1", "long_name": "leave-one-patch-out relative squared RGB error"},
    )
    return float(candidates[best]), curve


CAMERA_MATRIX_METHODS = {
    "lobes": lobe_camera_matrix,
    "smooth": camera_matrix,
}
"""How :func:`calibrate_spectral` fits ``C``: a non-negative sum of smooth lobes
(:func:`~spectralize.nodes.calibration.camera_lobes.lobe_camera_matrix`, the default) or
second-difference-penalised non-negative least squares (:func:`camera_matrix`)."""


# -- patches, prediction and cross-validation ---------------------------------------------------
def patch_means(
    data: xr.DataArray,
    labels: xr.DataArray | np.ndarray,
    *,
    names: Sequence[str] | None = None,
) -> xr.DataArray:
    """Mean of ``data`` over each labelled patch.

    Parameters
    ----------
    data
        Any array with dims ``y`` and ``x`` (e.g. HDR radiance (y, x, channel) or band
        radiance (wavelength, y, x)).
    labels
        (y, x) integer patch index per pixel; negative values are background.
    names
        Patch names for the ``patch`` coordinate (one per patch index ``0..n-1``).

    Returns
    -------
    xarray.DataArray
        ``(patch, ...)``: the other dims of ``data``.

    Raises
    ------
    CalibrationError
        Labels of another shape than ``data``'s (y, x), a patch without pixels, names of the
        wrong length.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (colour-checker patches).
    """
    lab = np.asarray(labels.values if isinstance(labels, xr.DataArray) else labels)
    shape = (data.sizes.get("y"), data.sizes.get("x"))
    if lab.shape != shape:
        raise CalibrationError(f"patch_means: labels have shape {lab.shape}, data (y, x) {shape}")
    n = int(lab.max()) + 1 if lab.size and lab.max() >= 0 else 0
    if n == 0:
        raise CalibrationError("patch_means: labels contain no patch (all negative)")
    counts = np.bincount(lab[lab >= 0].ravel(), minlength=n)
    if np.any(counts == 0):
        raise CalibrationError(
            f"patch_means: patch(es) {np.flatnonzero(counts == 0).tolist()} have no pixel"
        )
    if names is not None and len(names) != n:
        raise CalibrationError(f"patch_means: {len(names)} names for {n} patches")
    others = [d for d in data.dims if d not in ("y", "x")]
    # the dtype a mean keeps (float32 stays float32, as xarray's mean); summed in float64
    dtype = data.dtype if np.issubdtype(data.dtype, np.floating) else np.dtype(np.float64)
    if data.chunks is not None:  # whole frames per chunk: the sums of a chunk are its patches'
        data = data.chunk({"y": -1, "x": -1})
    out = xr.apply_ufunc(
        _patch_means,
        data,
        kwargs={"labels": lab, "n": n, "dtype": dtype},
        input_core_dims=[["y", "x"]],
        output_core_dims=[["patch"]],
        dask="parallelized",
        output_dtypes=[dtype],
        dask_gufunc_kwargs={"output_sizes": {"patch": n}},
    )
    out = out.transpose("patch", *others)
    return out.assign_coords(patch=list(names) if names is not None else np.arange(n))


def _patch_means(values: np.ndarray, labels: np.ndarray, n: int, dtype: np.dtype) -> np.ndarray:
    """Per patch ``0..n-1`` the mean of ``values`` (..., y, x) over its pixels, NaN skipped
    (NaN where a patch has none): the pixels of a patch taken in raster order and averaged as
    ``mean(skipna=True)`` over (y, x) does (the same sums, in the same precision), with no
    masked copy of the frame per patch."""
    import warnings

    moved = np.moveaxis(values, (-2, -1), (0, 1))  # (y, x, ...): the caller's own layout
    flat = moved.reshape(labels.size, -1)
    order = np.argsort(labels.ravel(), kind="stable")  # raster order within each patch
    ends = np.searchsorted(labels.ravel()[order], np.arange(n + 1) - 0.5)
    out = np.empty((n, flat.shape[1]), dtype=dtype)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a patch of NaN only: NaN
        for k in range(n):
            out[k] = np.nanmean(flat[order[ends[k] : ends[k + 1]]], axis=0)
    return np.moveaxis(out.reshape(n, *moved.shape[2:]), 0, -1)


def predict_rgb(spectra: xr.DataArray, camera_matrix: xr.Dataset | xr.DataArray) -> xr.DataArray:
    """RGB through the camera matrix: ``R = C S`` over wavelength (eq. 1, second term).

    Parameters
    ----------
    spectra
        Spectral radiance with a ``wavelength`` dim (any other dims).
    camera_matrix
        ``C`` (channel, wavelength) from :func:`camera_matrix`, on the same wavelengths.

    Returns
    -------
    xarray.DataArray
        ``spectra``'s other dims plus ``channel``.

    Raises
    ------
    SchemaError
        Spectra without a ``wavelength`` dim.
    CalibrationError
        When the wavelengths differ.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1.
    """
    c = camera_matrix["camera_matrix"] if isinstance(camera_matrix, xr.Dataset) else camera_matrix
    if "wavelength" not in spectra.dims:
        raise SchemaError(
            "predict_rgb: spectra have no wavelength dim",
            [Problem("spectra", "a 'wavelength' dim", f"dims {spectra.dims}")],
        )
    a = np.asarray(spectra["wavelength"].values, dtype=np.float64)
    b = np.asarray(c["wavelength"].values, dtype=np.float64)
    if a.shape != b.shape or not np.allclose(a, b, rtol=0, atol=1e-6):
        raise CalibrationError(f"predict_rgb: spectra are at {a.tolist()} nm, C at {b.tolist()} nm")
    out = xr.dot(c.assign_coords(wavelength=a), spectra, dim="wavelength")
    out = out.transpose(
        *[d for d in spectra.dims if d != "wavelength"], *[d for d in c.dims if d != "wavelength"]
    )
    return out.assign_attrs(units="1", long_name="RGB radiance predicted through C")


def cross_validate(
    measured_rgb: xr.DataArray,
    spectra: xr.DataArray,
    camera_matrix: xr.Dataset | xr.DataArray,
) -> xr.Dataset:
    """Cross-validation of the calibration (paper Fig. 4): predicted vs measured RGB per patch.

    Parameters
    ----------
    measured_rgb
        RGB radiance of the colour-checker patches measured by the RGB camera
        (patch, channel).
    spectra
        Spectral radiance of the same patches from the spectral camera system (patch,
        wavelength), e.g. :func:`patch_means` of :func:`band_signal` / ``Q``.
    camera_matrix
        ``C`` from :func:`camera_matrix`.

    Returns
    -------
    xarray.Dataset
        The table: ``measured``, ``predicted``, ``difference`` (predicted - measured)
        (patch, channel) and ``relative_error`` (patch) =
        ``||difference|| / ||measured||`` over channels. Attrs ``mean_relative_error``,
        ``max_relative_error``, ``worst_patch``.

    Raises
    ------
    CalibrationError
        Different patches in ``measured_rgb`` and ``spectra``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and Fig. 4.
    """
    if measured_rgb.sizes.get("patch") != spectra.sizes.get("patch"):
        raise CalibrationError(
            f"cross_validate: measured_rgb has {measured_rgb.sizes.get('patch')} patches, "
            f"spectra {spectra.sizes.get('patch')}"
        )
    predicted = predict_rgb(spectra, camera_matrix).transpose("patch", "channel")
    measured = measured_rgb.transpose("patch", "channel")
    if "patch" in measured.coords:
        predicted = predicted.assign_coords(patch=measured["patch"].values)
    predicted = (
        predicted.assign_coords(channel=measured["channel"].values)
        if "channel" in measured.coords
        else predicted
    )
    difference = predicted - measured
    norm = np.sqrt((measured**2).sum("channel"))
    relative = np.sqrt((difference**2).sum("channel")) / norm.where(norm > 0)
    worst = int(np.nanargmax(relative.values))
    patch_labels = relative["patch"].values if "patch" in relative.coords else np.arange(relative.size)
    return xr.Dataset(
        {
            "measured": measured.assign_attrs(units="1", long_name="measured RGB radiance"),
            "predicted": predicted.assign_attrs(units="1", long_name="RGB predicted through C"),
            "difference": difference.assign_attrs(units="1", long_name="predicted - measured"),
            "relative_error": relative.assign_attrs(
                units="1", long_name="|predicted - measured| / |measured| per patch"
            ),
        },
        attrs={
            "mean_relative_error": float(np.nanmean(relative.values)),
            "max_relative_error": float(np.nanmax(relative.values)),
            "worst_patch": str(patch_labels[worst]),
        },
    )


# -- the calibrate_spectral node: Q, C and the cross-check from the calibration targets --
def _shot_frames(counts: xr.DataArray, picks: np.ndarray, depth: int, group: str) -> xr.DataArray:
    """One frame per band: ``counts[band, picks[band]]`` as (shot, y, x) band shots."""
    times = counts["spectral_exposure_time"].values[picks]
    bare = counts.drop_vars(list(counts.coords))
    # one slice per band (lazy on a lazy series: each shot a chunk of its own, read when used)
    frames = xr.concat(
        [bare.isel(wavelength=k, spectral_exposure=int(e)) for k, e in enumerate(picks)], dim="shot"
    )
    return frames.assign_coords(
        wavelength=("shot", counts["wavelength"].values.astype(float), {"units": "nm"}),
        exposure_time=("shot", times, {"units": "s"}),
    ).assign_attrs(bit_depth=depth, source=f"{group}:spectral_counts")


def _saturated_by_band(counts: xr.DataArray, depth: int) -> np.ndarray:
    """:func:`saturated_frames` of a (wavelength, exposure, y, x) series, one band per
    computation: the frames of one band are read and reduced before the next band's. (One
    computation over the series read the stored tiles of every band ahead of their maxima,
    which split each tile into its exposures' frames: 4 GB at 2048^2, issue 27.)"""
    return np.concatenate(
        [saturated_frames(counts.isel(wavelength=[k]), depth) for k in range(counts.sizes["wavelength"])]
    )


def _longest_unsaturated(counts: xr.DataArray, depth: int, group: str) -> np.ndarray:
    """Per band, the index of the longest exposure without a saturated pixel."""
    top = ~_saturated_by_band(counts, depth)  # (wavelength, exp)
    bad = np.flatnonzero(~top.any(axis=1))
    if bad.size:
        wl = counts["wavelength"].values[bad].tolist()
        raise CalibrationError(
            f"{group}:spectral_counts: every exposure of band(s) {wl} nm has saturated pixels "
            f"(value {2**depth - 1}); add shorter exposures"
        )
    return np.asarray([int(np.flatnonzero(row)[-1]) for row in top])


def target_cameras(target: xr.Dataset) -> list[int]:
    """The raw/rgb camera indices of a calibration target's RGB series, in its ``camera`` order."""
    if "camera" in target["rgb_counts"].dims:
        return [int(v) for v in target["camera"].values]
    return [int(target.attrs.get("rgb_camera", 0))]


def _rgb_series(target: xr.Dataset, group: str, camera: int | None = None) -> xr.Dataset:
    """One camera's RGB exposure series of a target (default: the paired camera's) as a
    one-image raw/rgb Dataset (usable exposures)."""
    depth = check_bit_depth(target.attrs.get("rgb_bit_depth"), where=f"{group}.attrs['rgb_bit_depth']")
    camera = int(target.attrs.get("rgb_camera", 0)) if camera is None else camera
    counts, times = target["rgb_counts"], target["rgb_exposure_time"]
    if "camera" in counts.dims:
        cameras = target_cameras(target)
        if camera not in cameras:
            raise CalibrationError(
                f"{group}:rgb_counts: no exposure series of RGB camera {camera} (cameras {cameras})"
            )
        counts = counts.isel(camera=cameras.index(camera))
        times = times.isel(camera=cameras.index(camera)) if "camera" in times.dims else times
    counts = counts.transpose("rgb_exposure", "y", "x", "channel").load()
    _, _, not_saturated, not_dark = frame_flags(
        counts, ("y", "x"), black_level=0, saturation=2**depth - 1
    )
    usable = not_saturated.all(axis=1) & not_dark.all(axis=1)  # per exposure
    if usable.sum() < 1:
        raise CalibrationError(
            f"{group}:rgb_counts: every exposure of camera {camera} is saturated or dark"
        )
    counts = counts.isel(rgb_exposure=np.flatnonzero(usable))
    times = np.asarray(times.values, dtype=float)[usable]
    data = (
        counts.rename(rgb_exposure="exposure")
        .drop_vars([c for c in counts.coords if c != "channel"])
        .expand_dims(image=[0])
    )
    return xr.Dataset(
        {"counts": data},
        coords={"exposure_time": (("image", "exposure"), times[None]), "camera": ("image", [camera])},
        attrs={"bit_depth": depth},
    )


def _eroded_labels(labels: np.ndarray, margin: int) -> np.ndarray:
    from scipy import ndimage

    if margin <= 0:
        return labels
    out = np.full_like(labels, -1)
    for k in np.unique(labels[labels >= 0]):
        patch = labels == k
        for iterations in range(margin, -1, -1):  # small patches: erode less, keep pixels
            inner = ndimage.binary_erosion(patch, iterations=iterations) if iterations else patch
            if inner.any():
                break
        out[inner] = k
    return out


def _white_rgb(
    white_reference: xr.Dataset,
    response: xr.DataArray,
    attrs: Mapping,
    group: str,
    margin: float = 0.1,
    camera: int | None = None,
) -> xr.DataArray:
    """HDR RGB (channel,) of the white reference: median over the frame less a border of
    ``margin`` of its size (hot pixels and the target's edge do not move a median)."""
    raw = _rgb_series(white_reference, group, camera).drop_vars("camera")
    hdr = merge_hdr(raw, response.assign_attrs(dict(attrs) | response.attrs))["radiance"].isel(image=0)
    ny, nx = hdr.sizes["y"], hdr.sizes["x"]
    dy, dx = int(margin * ny), int(margin * nx)
    centre = hdr.isel(y=slice(dy, ny - dy), x=slice(dx, nx - dx))
    return (
        centre.median(("y", "x"))
        .compute()
        .drop_vars([c for c in centre.coords if c != "channel"], errors="ignore")
    )


def _white_levels(
    counts: xr.DataArray,
    depth: int,
    dark: xr.Dataset,
    response: xr.Dataset,
    light: np.ndarray,
    group: str,
    min_snr: float = 10.0,
) -> xr.Dataset:
    """:func:`~spectralize.nodes.calibration.matched_level_qe.level_table` of the white
    reference's whole exposure series (exposures without dark frames left out).

    Read band by band: one band's series (its exposures, stored together) and the dark
    frames of the series' exposure times (read once) are in memory, and every reduction
    runs on one frame; not the (band, exposure) stack (3.5 GB of uint16 at 2048^2)."""
    top = ~_saturated_by_band(counts, depth)  # (wavelength, exposure)
    n_bands, n_exposures = top.shape
    signal = np.full(top.shape, np.nan)
    usable = np.zeros(top.shape, dtype=bool)
    times = np.asarray(counts["spectral_exposure_time"].values, dtype=np.float64)
    frame = (counts.sizes["y"], counts.sizes["x"])
    found = []  # the exposures that have a dark frame
    for e in range(n_exposures):
        try:  # lazy: only checks that the dark frame is there
            dark_frames_at(dark, times[e : e + 1], used_by=group, dim="shot", frame_shape=frame)
        except CalibrationError:
            continue
        found.append(e)
    if found:
        darks = dark_frames_at(dark, times[found], used_by=group, dim="shot", frame_shape=frame)
        darks = darks.drop_vars("exposure_time").transpose("shot", "y", "x").load()
    for k in range(n_bands):
        series = counts.isel(wavelength=k).drop_vars(list(counts.coords)).load()
        for i, e in enumerate(found):
            shot = series.isel(spectral_exposure=e).assign_coords(exposure_time=times[e])
            mean = darks["mean"].isel(shot=i)
            above = shot.astype(np.float64) - mean
            noise = darks["std"].isel(shot=i).mean() if "std" in darks else above.std()
            signal[k, e] = float(_linearise(shot, mean, response, group).mean())
            usable[k, e] = (
                top[k, e]
                and float(above.mean()) >= min_snr * max(float(noise), 1e-12)
                and signal[k, e] > 0
            )
    return level_table(signal, times, usable, light, np.asarray(counts["wavelength"].values, float))


def shot_levels(signal: xr.DataArray) -> np.ndarray:
    """(shot,) mean linearised level ``f(I - dark)`` of band shots, from :func:`band_signal`."""
    return np.asarray((signal * signal["exposure_time"]).mean(("y", "x")).values, dtype=np.float64)


def _bare(data: xr.DataArray, keep: str) -> xr.DataArray:
    """``data`` without coords other than ``keep``."""
    return data.drop_vars([c for c in data.coords if c != keep])


def _method_settings(method, cm, smoothness, ridge, cv_scores, nonnegative) -> dict:
    """The chosen settings of C's fit, for the group's attrs."""
    if method == "lobes":
        return {
            "ridge": [float(v) for v in cm["ridge"].values],
            "ridge_choice": "given" if ridge is not None else "leave-one-patch-out cross-validation",
            "lobe_widths_nm": cm.attrs["widths"],
            "weak_light": cm.attrs["weak_light"],
            "weak_light_floor": cm.attrs["weak_light_floor"],
        }
    return {
        "smoothness": float(smoothness),
        "smoothness_choice": "leave-one-patch-out cross-validation"
        if cv_scores is not None
        else "given",
        "nonnegative": bool(nonnegative),
    }


def calibrate_spectral(
    white_reference: xr.Dataset,
    colour_checker: xr.Dataset,
    dark: xr.Dataset,
    oecf_rgb: xr.Dataset,
    oecf_spectral: xr.Dataset,
    *,
    camera_matrix_method: Annotated[
        str,
        Choices(CAMERA_MATRIX_METHODS, "camera matrix method"),
        Field(
            description="how C is fitted: 'lobes' (non-negative sum of smooth lobes) or "
            "'smooth' (non-negative second-difference-penalised least squares)"
        ),
    ] = "lobes",
    ridge: Annotated[
        float | None,
        Field(
            ge=0,
            description="'lobes': relative ridge weight on the lobe amplitudes; "
            "None: chosen per channel by leaving each patch out in turn",
        ),
    ] = None,
    weak_light: Annotated[
        float,
        Field(
            ge=0,
            description="'lobes': relative weight of the penalty holding C to zero in bands "
            "where the calibration targets had little light (0: none)",
        ),
    ] = WEAK_LIGHT_WEIGHT,
    smoothness: Annotated[
        float | None,
        Field(
            ge=0,
            description="'smooth': relative weight of the second-difference penalty of C; "
            "None: chosen by leaving each patch out in turn",
        ),
    ] = None,
    nonnegative: Annotated[bool, Field(description="'smooth': constrain C >= 0")] = True,
    white_patch: Annotated[
        bool,
        Field(
            description="fit C to the white reference's RGB as one more patch "
            "(reflectance times illuminant) beside the chart's"
        ),
    ] = True,
    matched_levels: Annotated[
        bool,
        Field(
            description="divide band shots by the Q of the white-reference exposure at their "
            "own signal level (the response's level-dependent error cancels), not by the Q of "
            "the longest unsaturated exposure"
        ),
    ] = True,
    patch_margin: Annotated[
        int,
        Field(
            ge=0,
            description="pixels removed at every patch "
            "border (misregistration, blur) before patch means; "
            "less where a patch would vanish",
        ),
    ] = 2,
    min_snr: Annotated[
        float,
        Field(gt=0, description="smallest accepted per-pixel SNR of the white reference in a band"),
    ] = 1.0,
) -> xr.Dataset:
    """Quantum efficiency, camera matrix C and the cross-validation of paper Fig. 4.

    - ``Q`` per band: the white reference's longest unsaturated exposure of each band,
      linearised with the spectral response, per second, divided by the target reflectance
      times the measured illuminant (:func:`quantum_efficiency`).
    - ``C``: the colour checker's RGB exposure series merged to HDR with the RGB response
      (:func:`~spectralize.nodes.calibration.hdr.merge_hdr`), patch means, against patch
      reflectance times the measured illuminant; with ``white_patch`` the white reference's
      HDR RGB (median over the frame less a 10 % border) against its reflectance times the
      illuminant is one more patch, the one spectrum a chart of pigments lacks (flat). By
      default ``C`` is a non-negative sum of smooth lobes
      (:func:`~spectralize.nodes.calibration.camera_lobes.lobe_camera_matrix`, the ridge
      chosen per channel by leaving each patch out in turn, held to zero by ``weak_light``
      where the targets had little light): a second-difference penalty
      (``camera_matrix_method="smooth"``, :func:`camera_matrix`) extrapolates linearly where
      the light is weak and lets a row keep rising to the end of the bands.
    - Cross-validation: the spectral camera's capture of the checker (longest unsaturated
      exposure per band, band signal / Q, patch means) through ``C`` against the measured
      HDR RGB (:func:`cross_validate`).

    Returns
    -------
    xarray.Dataset
        Group ``calibration/spectral``: ``quantum_efficiency`` (wavelength) [1],
        ``illuminant`` (wavelength) [1] (the measured illuminant ``L`` on the band
        wavelengths, :func:`measured_illuminant_on_bands`: a white diffuser's band radiance),
        ``camera_matrix`` (channel, wavelength) [1], ``measured_rgb`` / ``predicted_rgb``
        (patch, channel) [1], ``relative_error`` (patch) [1], ``patch_spectra`` (patch,
        wavelength) [1] (from the spectral camera), ``qe_snr`` (wavelength) [1],
        ``ridge_cv`` (ridge_candidate, channel) or ``smoothness_cv`` (smoothness) [1] (the
        cross-validation scores, when chosen). Attrs ``mean_relative_error``,
        ``max_relative_error``, ``worst_patch``, ``c_relative_rms_residual`` and the chosen
        settings: ``camera_matrix_method``, ``white_patch``, ``ridge`` (per channel),
        ``lobe_widths_nm``, ``weak_light`` and ``weak_light_floor``, or ``smoothness`` and
        ``nonnegative``.

    Raises
    ------
    CalibrationError
        A white reference darker than the noise (naming ``raw/white_reference:
        spectral_counts``, band and values), dark frames missing for an exposure time, RGB
        series without a usable exposure.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 1 and 5, Figs. 3 and 4.
    """
    # -- Q from the white reference
    white_counts, depth = target_spectral_series(white_reference, "raw/white_reference")
    picks = _longest_unsaturated(white_counts, depth, "raw/white_reference")
    shots = _shot_frames(white_counts, picks, depth, "raw/white_reference")
    illuminant = white_reference["illuminant"].load()
    try:
        qe = quantum_efficiency(
            shots,
            dark,
            illuminant,
            reflectance=white_reference["target_reflectance"].load(),
            response=oecf_spectral,
            min_snr=min_snr,
        )
    except CalibrationError as error:
        raise CalibrationError(f"raw/white_reference:spectral_counts: {error}") from None
    q = qe["quantum_efficiency"]
    band_illuminant = measured_illuminant_on_bands(illuminant, q["wavelength"].values)
    light = (white_reference["target_reflectance"] * illuminant).sel(
        wavelength=white_counts["wavelength"].values
    )
    levels = _white_levels(
        white_counts, depth, dark, oecf_spectral, np.asarray(light.values, float), "raw/white_reference"
    )

    # -- C of every RGB camera from its own HDR RGB of the colour checker
    group = "raw/colour_checker"
    fit = {
        "method": camera_matrix_method,
        "ridge": ridge,
        "weak_light": weak_light,
        "smoothness": smoothness,
        "nonnegative": nonnegative,
        "white_patch": white_patch,
        "patch_margin": patch_margin,
    }
    cameras = target_cameras(colour_checker)
    paired = int(colour_checker.attrs.get("rgb_camera", cameras[0]))
    fits = {k: _fit_camera(k, white_reference, colour_checker, oecf_rgb, **fit) for k in cameras}
    names_of, lender_of = _camera_names(colour_checker, cameras)
    reference = paired if paired in fits else lender_of[paired]
    cm, measured, fit_spectra, cv_scores, smoothness, camera = (
        fits[reference]["cm"],
        fits[reference]["measured"],
        fits[reference]["fit_spectra"],
        fits[reference]["cv_scores"],
        fits[reference]["smoothness"],
        paired,
    )
    labels = _eroded_labels(np.asarray(colour_checker["patch_index"].values), patch_margin)
    names = (
        [str(v) for v in colour_checker["patch_name"].values]
        if "patch_name" in colour_checker.coords
        else None
    )

    # -- cross-validation: the spectral camera's capture of the checker through C
    checker_counts, cdepth = target_spectral_series(colour_checker, group)
    cpicks = _longest_unsaturated(checker_counts, cdepth, group)
    cshots = _shot_frames(checker_counts, cpicks, cdepth, group)
    try:
        signal = band_signal(cshots, dark, response=oecf_spectral)
    except CalibrationError as error:
        raise CalibrationError(f"{group}:spectral_counts: {error}") from None
    q_shot = q.sel(wavelength=cshots["wavelength"].values).values
    # Band by band: each computation reads one band's shot, linearises it and reduces it
    # before the next band's is read. (One computation over every band reads the bands'
    # frames ahead of their reductions: 9.7 GB at 2048^2, issue 27.) Each band's numbers are
    # those of the one computation: the same chunks, the same reductions.
    shots = [signal.isel(shot=[k]) for k in range(signal.sizes["shot"])]
    if matched_levels:
        q_shot = matched_quantum_efficiency(
            levels,
            cshots["wavelength"].values,
            np.concatenate([shot_levels(shot) for shot in shots]),
            q_shot,
        )
    spectra = []
    for shot, q_k in zip(shots, q_shot, strict=True):
        band_radiance = shot / xr.DataArray([q_k], dims="shot")
        band_radiance = band_radiance.swap_dims(shot="wavelength").drop_vars(
            [c for c in band_radiance.coords if c != "wavelength"]
        )
        spectra.append(patch_means(band_radiance, labels).compute())
    patch_spectra = xr.concat(spectra, dim="wavelength").assign_coords(patch=measured["patch"].values)
    table = cross_validate(measured, patch_spectra, cm)
    per_camera = _per_camera(fits, lender_of, names_of, reference, patch_spectra, fit_spectra)
    models = [str(m) for m in colour_checker.attrs.get("camera_models", [])]
    per_camera = per_camera.assign_coords(
        camera_model=(
            "camera",
            np.asarray([models[k] if k < len(models) else "" for k in per_camera["camera"].values]),
        )
    )

    unit = {"units": "1"}
    out = xr.Dataset(
        {
            "quantum_efficiency": q.assign_attrs(
                **unit,
                long_name="relative quantum efficiency Q (band signal per unit of the "
                "measured illuminant)",
            ),
            "qe_snr": qe["snr"].assign_attrs(**unit, long_name="per-pixel SNR of the white reference"),
            "illuminant": band_illuminant,
            "camera_matrix": cm["camera_matrix"].assign_attrs(
                **unit, long_name="RGB camera matrix C (HDR units per band radiance unit)"
            ),
            "measured_rgb": table["measured"].assign_attrs(
                **unit, long_name="HDR RGB radiance of the patch, measured"
            ),
            "predicted_rgb": table["predicted"].assign_attrs(
                **unit, long_name="RGB predicted through C from the spectral capture"
            ),
            "relative_error": table["relative_error"].assign_attrs(
                **unit, long_name="|predicted - measured| / |measured| per patch"
            ),
            "patch_spectra": patch_spectra.transpose("patch", "wavelength").assign_attrs(
                **unit, long_name="patch band radiance from the spectral camera"
            ),
        },
        attrs={
            "mean_relative_error": table.attrs["mean_relative_error"],
            "max_relative_error": table.attrs["max_relative_error"],
            "worst_patch": table.attrs["worst_patch"],
            "c_relative_rms_residual": cm.attrs["relative_rms_residual"],
            "camera_matrix_method": camera_matrix_method,
            **_method_settings(camera_matrix_method, cm, smoothness, ridge, cv_scores, nonnegative),
            "white_patch": bool(white_patch),
            "matched_levels": bool(matched_levels),
            "patch_margin": int(patch_margin),
            "rgb_camera": camera,
            "units_note": "band radiance relative to the measured illuminant; C maps it to "
            "HDR units (RGB = C @ spectrum)",
        },
    )
    out["qe_by_level"] = levels["qe_by_level"]
    out["qe_level"] = levels["qe_level"]
    if cv_scores is not None:
        out["smoothness_cv"] = cv_scores
    if "ridge_cv" in cm:
        out["ridge_cv"] = cm["ridge_cv"]
    out = out.drop_vars(
        [
            c
            for c in out.coords
            if c not in ("wavelength", "channel", "patch", "smoothness", "ridge_candidate")
        ]
    )
    out = out.merge(per_camera.assign_coords(patch=out["patch"].values))
    if names is not None:
        out = out.assign_coords(patch_name=("patch", names))
    out["wavelength"].attrs.update(units="nm", long_name="band centre wavelength")
    return out


def _camera_names(target: xr.Dataset, cameras: list[int]) -> tuple[dict[int, str], dict[int, int]]:
    """``{index: name}`` of every RGB camera, and ``{index: lender}`` for those without chart
    frames that borrow the calibration of a camera of the same model (ingest's attrs)."""
    names = [str(n) for n in target.attrs.get("camera_names", [])]
    names_of = {k: (names[k] if k < len(names) else f"camera {k}") for k in cameras}
    names_of |= {k: n for k, n in enumerate(names)}
    lender_of = {
        names.index(borrower): names.index(lender)
        for borrower, lender in _borrowed(target.attrs.get("calibration_borrowed")).items()
        if borrower in names and lender in names and names.index(lender) in cameras
    }
    return names_of, lender_of


def _borrowed(value: object) -> dict[str, str]:
    """Ingest's ``calibration_borrowed`` attr: JSON text (a mapping in stores of its first
    version)."""
    if isinstance(value, str):
        value = json.loads(value or "{}")
    return {str(k): str(v) for k, v in dict(value or {}).items()}


def _fit_camera(
    camera: int,
    white_reference: xr.Dataset,
    colour_checker: xr.Dataset,
    oecf_rgb: xr.Dataset,
    *,
    method: str,
    ridge: float | None,
    weak_light: float,
    smoothness: float | None,
    nonnegative: bool,
    white_patch: bool,
    patch_margin: int,
) -> dict:
    """``C`` of one RGB camera from its own HDR RGB of the chart (and the white reference),
    through its own response and patch label image."""
    group = "raw/colour_checker"
    rgb_raw = _rgb_series(colour_checker, group, camera)
    response = oecf_rgb["response"]
    if "camera" in response.dims:
        response = response.sel(
            camera=camera if camera in response["camera"].values.tolist() else response["camera"][0]
        )
    hdr = merge_hdr(rgb_raw.drop_vars("camera"), response.assign_attrs(oecf_rgb.attrs | response.attrs))
    index = colour_checker["patch_index"]
    if "rgb_patch_index" in colour_checker:
        index = colour_checker["rgb_patch_index"].isel(
            camera=target_cameras(colour_checker).index(camera)
        )
    labels = _eroded_labels(np.asarray(index.values), patch_margin)
    measured = patch_means(hdr["radiance"].isel(image=0), labels).compute()
    spectra = (colour_checker["patch_reflectance"] * colour_checker["illuminant"]).load()
    spectra = spectra.assign_coords(patch=measured["patch"].values).transpose("patch", "wavelength")
    fit_rgb, fit_spectra = measured, spectra
    if white_patch:
        white_rgb = _white_rgb(
            white_reference, response, oecf_rgb.attrs, "raw/white_reference", camera=camera
        )
        white_spectrum = (white_reference["target_reflectance"] * white_reference["illuminant"]).load()
        white_spectrum = white_spectrum.interp(wavelength=spectra["wavelength"].values)
        n = measured.sizes["patch"] + 1
        fit_rgb = xr.concat(
            [_bare(measured, "channel"), _bare(white_rgb, "channel").expand_dims(patch=1)], dim="patch"
        ).assign_coords(patch=np.arange(n))
        fit_spectra = xr.concat(
            [_bare(spectra, "wavelength"), _bare(white_spectrum, "wavelength").expand_dims(patch=1)],
            dim="patch",
        ).assign_coords(patch=np.arange(n))
        fit_spectra = fit_spectra.transpose("patch", "wavelength")
    cv_scores = None
    if method == "lobes":
        cm = lobe_camera_matrix(fit_rgb, fit_spectra, ridge=ridge, weak_light=weak_light)
    else:
        if smoothness is None:
            smoothness, cv_scores = cross_validated_smoothness(
                fit_rgb, fit_spectra, nonnegative=nonnegative
            )
        cm = camera_matrix(fit_rgb, fit_spectra, smoothness=smoothness, nonnegative=nonnegative)
    return {
        "cm": cm,
        "measured": measured,
        "fit_spectra": fit_spectra,
        "cv_scores": cv_scores,
        "smoothness": smoothness,
    }


def _per_camera(
    fits: dict[int, dict],
    lender_of: dict[int, int],
    names_of: dict[int, str],
    reference: int,
    patch_spectra: xr.DataArray,
    fit_spectra: xr.DataArray,
) -> xr.Dataset:
    """C, the map onto the reference camera's RGB and the chart cross-validation per camera."""
    cameras = sorted(set(fits) | set(lender_of))
    c_ref = np.asarray(fits[reference]["cm"]["camera_matrix"].values, float)
    matrices, transforms, errors, sources = [], [], [], []
    for k in cameras:
        own = fits[k if k in fits else lender_of[k]]
        cm = own["cm"]["camera_matrix"]
        matrices.append(np.asarray(cm.values, float))
        transforms.append(rgb_transform(cm.values, c_ref, np.asarray(fit_spectra.values, float)))
        errors.append(np.asarray(cross_validate(own["measured"], patch_spectra, cm)["relative_error"]))
        sources.append(
            "own chart frames"
            if k in fits
            else f"borrowed from {names_of[lender_of[k]]} (same model in capture.toml rgb.models)"
        )
    channel = fits[reference]["cm"]["camera_matrix"]["channel"].values
    wavelength = fits[reference]["cm"]["camera_matrix"]["wavelength"].values
    unit = {"units": "1"}
    errors_ = np.stack(errors)
    return xr.Dataset(
        {
            "camera_matrices": (
                ("camera", "channel", "wavelength"),
                np.stack(matrices),
                unit | {"long_name": "RGB camera matrix C of each RGB camera"},
            ),
            "rgb_transform": (
                ("camera", "channel", "channel_in"),
                np.stack(transforms),
                unit | {"long_name": "3 x 3 map of each camera's HDR RGB onto the paired camera's"},
            ),
            "camera_relative_error": (
                ("camera", "patch"),
                errors_,
                unit | {"long_name": "chart cross-validation per camera: |C_k S - R_k| / |R_k|"},
            ),
            "camera_mean_relative_error": (("camera",), np.nanmean(errors_, axis=1), unit),
            "camera_max_relative_error": (("camera",), np.nanmax(errors_, axis=1), unit),
        },
        coords={
            "camera": ("camera", np.asarray(cameras, np.int64), {"long_name": "raw/rgb camera index"}),
            "camera_name": ("camera", np.asarray([names_of[k] for k in cameras])),
            "c_source": ("camera", np.asarray(sources)),
            "channel": channel,
            "wavelength": wavelength,
            "channel_in": ("channel_in", np.asarray(channel)),
        },
        attrs={"reference_camera": int(reference)},
    )
