"""What the spectral camera measures of the white reference: ``Q``, ``L`` and ``Q`` per level.

- :func:`quantum_efficiency`: ``Q_lambda`` per band from white-reference shots: the band
  signal divided by the known white reflectance and by the measured illuminant spectrum
  (eq. 5: ``I = f^-1(x t Q_lambda)``).
- :func:`measured_illuminant_on_bands`: the measured illuminant ``L`` on the band
  wavelengths, in band radiance units.
- :func:`white_level_table`: ``Q`` at every exposure of the white reference's series, for
  :func:`~spectralize.nodes.calibration.matched_level_qe.matched_quantum_efficiency`.
- :func:`calibrate_white_reference`: the three from the ``raw/white_reference`` group, the
  first step of :func:`~.calibrate_spectral`.

References
----------
Fast Capture of Spectral Image Series, section 4 ("Calibration", Fig. 3) and eq. 5.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import dask
import numpy as np
import xarray as xr

from spectralize.nodes.calibration.band_shots import (
    checked_shots,
    dark_for_shots,
    linearise,
    longest_unsaturated_shots,
    saturated_by_band,
    series_pieces,
)
from spectralize.nodes.calibration.dark import dark_frames_at
from spectralize.nodes.calibration.exposure_series import frame_chunks
from spectralize.nodes.calibration.flat_field_maps import FlatField
from spectralize.nodes.calibration.matched_level_qe import level_table
from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "quantum_efficiency",
    "measured_illuminant_on_bands",
    "white_level_table",
    "WhiteReferenceCalibration",
    "calibrate_white_reference",
]


def _on_wavelengths(
    spectrum: xr.DataArray | float, wavelengths: np.ndarray, name: str, where: str
) -> np.ndarray:
    """``spectrum`` (a positive number or a spectrum over ``wavelength``) at ``wavelengths``,
    linearly interpolated; a :class:`CalibrationError` where it does not cover them or is
    not positive."""
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
    flat_field: FlatField | None = None,
) -> xr.Dataset:
    """Quantum efficiency ``Q_lambda`` per band from white-reference shots.

    ``Q_lambda = mean_roi(f(I - dark) / (t F_lambda)) / (rho_lambda L_lambda)`` (eq. 5 with
    the radiance of a white reference ``x = rho L`` and the band's flat field ``F_lambda``,
    1 at the frame centre, where given: ``Q`` is then the centre's); several shots at one
    wavelength are averaged.

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
        The spectral camera's OECF (see :func:`~.band_signal`); ``None`` for a linear camera.
    roi
        Region of the reference, e.g. ``{"y": slice(10, 90), "x": slice(20, 80)}``; default
        the whole frame.
    min_snr
        Smallest accepted ratio of the mean dark-subtracted signal in the ROI [DN] to the
        per-pixel noise (the mean of ``dark.std`` in the ROI, or the spatial standard
        deviation of the dark-subtracted ROI when ``dark`` has no ``std``).
    flat_field
        The spectral camera's flat field per band
        (:func:`~spectralize.nodes.calibration.flat_field.spectral_flat_field`); ``None``: none.

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
    counts = checked_shots(white, where)
    mean, std = dark_for_shots(dark, counts, where)
    region = dict(roi or {})
    unknown = set(region) - {"y", "x"}
    if unknown:
        raise CalibrationError(f"{where}: roi may only select y and x, got {sorted(unknown)}")
    part = counts.isel(region)
    if part.sizes["y"] * part.sizes["x"] == 0:
        raise CalibrationError(f"{where}: the roi {region} selects no pixel")
    # one shot at a time: every reduction below reads the shots chunk by chunk (no float64
    # copy of every shot, of which the response's lookup would need several)
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
    signal = linearise(part, dark_part, response, where)
    if flat_field is not None:  # each shot over its band's map
        origin = tuple(region[d].indices(counts.sizes[d])[0] if d in region else 0 for d in ("y", "x"))
        signal = flat_field.divide(signal, flat_field.rows(wavelengths, "band"), origin)
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


def white_level_table(
    counts: xr.DataArray,
    depth: int,
    dark: xr.Dataset,
    response: xr.Dataset,
    light: np.ndarray,
    group: str,
    min_snr: float = 10.0,
    flat_field: FlatField | None = None,
) -> xr.Dataset:
    """:func:`~spectralize.nodes.calibration.matched_level_qe.level_table` of the white
    reference's whole exposure series (exposures without dark frames left out).

    ``counts`` is the (wavelength, spectral_exposure, y, x) series of bit depth ``depth``,
    ``response`` the spectral camera's OECF, ``light`` the white's radiance (reflectance
    times illuminant) per band. An exposure is usable in a band when it has no saturated
    pixel, its mean signal above dark is at least ``min_snr`` times the noise and its
    linearised level is positive. With ``flat_field`` (per band) each frame is divided by its
    band's map before its mean, as :func:`quantum_efficiency` divides it.

    Read in the pieces of :func:`~.series_pieces`: the bands of a batch (one band of a
    large sensor: its exposures, stored together) and the dark frames of the series'
    exposure times (read once) are in memory, and each reduction takes the frames of a piece
    that fit in the frame-chunk budget (one frame of a large sensor) together; never the
    whole (band, exposure) stack of a large sensor.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    top = ~saturated_by_band(counts, depth)  # (wavelength, exposure)
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
    if not found:
        return level_table(signal, times, usable, light, np.asarray(counts["wavelength"].values, float))
    darks = dark_frames_at(dark, times[found], used_by=group, dim="shot", frame_shape=frame)
    darks = darks.drop_vars("exposure_time").transpose("shot", "y", "x").load()
    # the dark noise of each exposure (the mean of its std frame), the same in every band
    noise = (
        [float(darks["std"].isel(shot=i).mean()) for i in range(len(found))] if "std" in darks else None
    )
    bands = np.asarray(counts["wavelength"].values, dtype=float)
    for part, positions, shots in series_pieces(counts, found):
        # a piece's frames at once (wavelength, spectral_exposure, y, x), each reduced on its own
        mean = darks["mean"].isel(shot=positions).rename(shot="spectral_exposure")
        falloff: xr.DataArray | float = 1.0  # the bands' flat fields, a frame each
        if flat_field is not None:
            maps = [
                flat_field.maps(flat_field.rows(bands[k : k + 1], "band"))[0]
                for k in range(n_bands)[part]
            ]
            falloff = xr.DataArray(np.stack(maps), dims=("wavelength", "y", "x"))
        above = shots.astype(np.float64) - mean
        spread = np.asarray(noise)[positions] if noise is not None else above.std(("y", "x")).values
        level = np.asarray((linearise(shots, mean, response, group) / falloff).mean(("y", "x")).values)
        cell = np.ix_(range(n_bands)[part], [found[i] for i in positions])
        signal[cell] = level
        usable[cell] = (
            top[cell]
            & (above.mean(("y", "x")).values >= min_snr * np.maximum(spread, 1e-12))
            & (level > 0)
        )
    return level_table(signal, times, usable, light, np.asarray(counts["wavelength"].values, float))


class WhiteReferenceCalibration(NamedTuple):
    """What :func:`calibrate_white_reference` measures."""

    quantum_efficiency: xr.Dataset
    """:func:`quantum_efficiency` of the longest unsaturated exposure per band."""
    illuminant: xr.DataArray
    """:func:`measured_illuminant_on_bands` on ``Q``'s wavelengths."""
    levels: xr.Dataset
    """:func:`white_level_table` of the whole exposure series."""


def calibrate_white_reference(
    white_reference: xr.Dataset,
    dark: xr.Dataset,
    oecf_spectral: xr.Dataset,
    *,
    min_snr: float = 1.0,
    flat_field: FlatField | None = None,
) -> WhiteReferenceCalibration:
    """``Q``, ``L`` on the bands and ``Q`` per level from the ``raw/white_reference`` group.

    ``Q`` from each band's longest unsaturated exposure (:func:`quantum_efficiency`, the
    target reflectance times the measured illuminant as the white's radiance), the measured
    illuminant on ``Q``'s wavelengths (:func:`measured_illuminant_on_bands`) and the level
    table of the whole series (:func:`white_level_table`), each through the spectral camera's
    ``flat_field`` where given.

    Raises
    ------
    CalibrationError
        A white reference darker than the noise, naming ``raw/white_reference:
        spectral_counts``; a band saturated at every exposure; dark frames missing.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 5 and Fig. 3.
    """
    group = "raw/white_reference"
    counts, depth, shots = longest_unsaturated_shots(white_reference, group)
    illuminant = white_reference["illuminant"].load()
    try:
        qe = quantum_efficiency(
            shots,
            dark,
            illuminant,
            reflectance=white_reference["target_reflectance"].load(),
            response=oecf_spectral,
            min_snr=min_snr,
            flat_field=flat_field,
        )
    except CalibrationError as error:
        raise CalibrationError(f"{group}:spectral_counts: {error}") from None
    band_illuminant = measured_illuminant_on_bands(illuminant, qe["wavelength"].values)
    light = (white_reference["target_reflectance"] * illuminant).sel(
        wavelength=counts["wavelength"].values
    )
    levels = white_level_table(
        counts,
        depth,
        dark,
        oecf_spectral,
        np.asarray(light.values, float),
        group,
        flat_field=flat_field,
    )
    return WhiteReferenceCalibration(qe, band_illuminant, levels)
