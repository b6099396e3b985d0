"""Band radiance (paper section 4): calibrated, registered noisy band shots.

:func:`calibrate_bands` (node ``calibrate_bands``) turns every raw band shot into relative
band radiance in the units of the measured illuminant, the input of the reconstruction:
dark subtracted (negative values kept), linearised with the spectral camera's response, per
second, divided by its band's flat field (the lens and filter falloff) and by the quantum
efficiency of its band, scaled from its LED's power to that of
the RGB image it pairs with (``calibration/led_power.csv``), and resampled onto the RGB pixel
grid.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration") and eq. 5.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.nodes.calibration.band_shots import band_signal, shot_levels
from spectralize.nodes.calibration.exposure_series import frame_chunks
from spectralize.nodes.calibration.flat_field_maps import from_calibration
from spectralize.nodes.calibration.matched_level_qe import matched_quantum_efficiency
from spectralize.nodes.calibration.registration import register_frames
from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = ["calibrate_bands", "led_power_gain", "WRITE_SHOTS"]

WRITE_SHOTS = 8
"""The most shots per chunk of the ``bands`` group (float32); fewer where raw/spectral's
chunks hold fewer. Computed one shot at a time whatever those chunks (a
store's may hold every shot of a run in one)."""


def led_power_gain(raw_spectral: xr.Dataset) -> np.ndarray:
    """(shot,) power of the paired RGB image's LED over the shot's own LED's.

    Multiplying a band shot's radiance by it puts the shot on the scale of the RGB image it
    pairs with (the radiance is proportional to the LED's power). Ones where raw/spectral has
    no ``led_power`` / ``image_led_power`` coords (no ``calibration/led_power.csv``).
    """
    if "led_power" not in raw_spectral.coords or "image_led_power" not in raw_spectral.coords:
        return np.ones(raw_spectral.sizes["shot"])
    own = np.asarray(raw_spectral["led_power"].values, dtype=float)
    paired = np.asarray(raw_spectral["image_led_power"].values, dtype=float)
    return paired / own


def calibrate_bands(
    raw_spectral: xr.Dataset,
    dark: xr.Dataset,
    oecf_spectral: xr.Dataset,
    spectral: xr.Dataset,
    registration: xr.Dataset,
    *,
    filter_size: Annotated[
        float | None,
        Field(gt=0, description="filter size [px] for shots when raw/spectral has no filter_size coord"),
    ] = None,
    order: Annotated[
        int, Field(ge=0, le=5, description="spline order of the registration resampling")
    ] = 1,
    led_power: Annotated[
        bool,
        Field(
            description="scale each shot by the power of its paired RGB image's LED over its own "
            "LED's (raw/spectral led_power, image_led_power: calibration/led_power.csv)"
        ),
    ] = True,
) -> xr.Dataset:
    """Band radiance of every shot: ``band_signal / Q(lambda_shot)``, registered to RGB.

    ``L_shot(p) = f(I_shot(p + shift) - dark_t) / (t Q_lambda F_lambda(p + shift))`` (eq. 5
    solved for the radiance ``x``, ``F_lambda`` the band's flat field where
    ``calibration/spectral`` has one: ``flat_field``), ``Q_lambda`` of the white-reference
    exposure at the shot's own mean level where ``calibration/spectral`` has it
    (:mod:`~spectralize.nodes.calibration.matched_level_qe`: the response's level-dependent
    error cancels instead of rippling from band to band). Dark subtracted (negative values
    kept, never clipped), linearised with the spectral response, per second, divided by the
    quantum efficiency at the shot's wavelength (so in units of the measured illuminant,
    matching ``C``) and resampled onto the RGB pixel grid with
    :func:`~spectralize.nodes.calibration.registration.register_frames`. Lazy (dask), after
    one pass over the shots for their mean levels.

    Parameters
    ----------
    raw_spectral
        Group ``raw/spectral``: ``counts`` (shot, y, x) [DN], per-shot ``wavelength``,
        ``exposure_time`` and (optionally) ``filter_size``.
    dark
        Group ``dark``, a mean frame for every exposure time of the shots.
    oecf_spectral
        Group ``calibration/oecf_spectral`` (the spectral camera's response).
    spectral
        Group ``calibration/spectral`` (``quantum_efficiency`` per band).
    registration
        Group ``registration`` (``shift`` [px]).
    filter_size
        Filter size ``s_i`` [px] of every shot when ``raw/spectral`` has no ``filter_size``
        coord.
    order
        Spline order of the registration resampling.
    led_power
        Put each shot on the scale of the RGB image it pairs with (:func:`led_power_gain`):
        a band shot lit by LED ``l + 1`` pairs with the RGB image lit by LED ``l``.

    Returns
    -------
    xarray.Dataset
        Group ``bands``: ``radiance`` (shot, y, x) float32 [1]; per-shot coords of
        raw/spectral plus ``filter_size`` [px].

    Raises
    ------
    CalibrationError
        A dark frame missing for a shot's exposure time, a shot wavelength without QE.
    SchemaError
        No filter size (neither the coord nor the parameter).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 3 and 5.
    """
    if "filter_size" in raw_spectral.coords:
        sizes = raw_spectral["filter_size"]
    elif filter_size is not None:
        sizes = xr.full_like(raw_spectral["exposure_time"], float(filter_size))
    else:
        raise SchemaError(
            "cannot calibrate bands:",
            [
                Problem(
                    "raw/spectral:filter_size",
                    "a per-shot coord [px] or the filter_size parameter",
                    "nothing",
                )
            ],
        )
    wavelengths = np.asarray(raw_spectral["wavelength"].values, dtype=float)
    q = spectral["quantum_efficiency"].load()
    grid = np.asarray(q["wavelength"].values, dtype=float)
    idx = np.array([int(np.argmin(np.abs(grid - w))) for w in wavelengths], dtype=int)
    missing = (
        np.flatnonzero(np.abs(grid[idx] - wavelengths) > 1e-6)
        if grid.size
        else np.arange(wavelengths.size)
    )
    if missing.size:
        raise CalibrationError(
            f"calibration/spectral:quantum_efficiency has no band at {wavelengths[missing]} nm "
            f"(shots of raw/spectral); it covers {grid.tolist()} nm"
        )
    q_shot = xr.DataArray(np.asarray(q.values, dtype=float)[idx], dims="shot")
    if not np.all(q_shot.values > 0):
        raise CalibrationError(
            "calibration/spectral:quantum_efficiency is not positive at "
            f"{wavelengths[~(q_shot.values > 0)].tolist()} nm"
        )
    # shot by shot: every float64 step (dark subtraction, the response's lookup) holds one
    # frame per thread, not the stored chunk of shots (a float64 copy of every shot, of which
    # the lookup makes several); written in the shots' own chunks, at most WRITE_SHOTS float32
    # shots a chunk
    counts = raw_spectral["counts"]
    write_shots = min(counts.chunks[0][0] if counts.chunks is not None else WRITE_SHOTS, WRITE_SHOTS)
    counts = frame_chunks(counts, ("shot",))
    signal = band_signal(raw_spectral.assign(counts=counts), dark, response=oecf_spectral)
    flat = from_calibration(spectral, "spectral")
    if flat is not None:  # flat field: each shot over its band's map (before registration)
        signal = flat.divide(signal, flat.rows(wavelengths, "raw/spectral wavelength"))
    matched = "qe_by_level" in spectral and spectral.attrs.get("matched_levels", True)
    if matched:  # Q of the white reference at each shot's own level (one pass over the shots)
        q_shot = xr.DataArray(
            matched_quantum_efficiency(
                spectral[["qe_by_level", "qe_level"]].load(),
                wavelengths,
                shot_levels(signal),
                q_shot.values,
            ),
            dims="shot",
        )
    gain = led_power_gain(raw_spectral) if led_power else np.ones(wavelengths.size)
    radiance = (signal * xr.DataArray(gain, dims="shot") / q_shot).astype(np.float32)
    radiance = register_frames(radiance, registration["shift"], order=order)
    radiance = radiance.chunk({"shot": write_shots})
    keep = [c for c in raw_spectral.coords if raw_spectral[c].dims == ("shot",)]
    radiance = radiance.drop_vars([c for c in radiance.coords if c not in keep])
    radiance = radiance.assign_attrs(
        units="1",
        long_name="relative band radiance (units of "
        "the measured illuminant), registered to the RGB camera",
    )
    coords = {c: raw_spectral[c] for c in keep}
    coords["filter_size"] = (
        "shot",
        np.asarray(sizes.values, dtype=float),
        {"units": "px", "long_name": "Gaussian filter size s_i (eq. 3)"},
    )
    return xr.Dataset(
        {"radiance": radiance},
        coords=coords,
        attrs={
            "quantum_efficiency": "white reference at the shot's own level" if matched else "per band",
            "registration_shift_px": [float(v) for v in registration["shift"].values],
            "negative_values": "kept (noise below the dark level)",
            "flat_field": "the band's, from the white reference" if flat is not None else "none",
            "led_power": "scaled to the paired RGB image's LED (calibration/led_power.csv)"
            if led_power and "led_power" in raw_spectral.coords
            else "not scaled (no LED power table)",
        },
    )
