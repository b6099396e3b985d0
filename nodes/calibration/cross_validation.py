"""The cross-validation of paper Fig. 4: the spectral camera's capture of the chart through ``C``.

- :func:`predict_rgb`: RGB through the camera matrix, ``R = C S`` (eq. 1).
- :func:`cross_validate`: RGB predicted through ``C`` from a spectral capture of the colour
  checker against the measured RGB, error per patch as a table (the figure is
  :func:`spectralize.nodes.evaluation.figures_calibration.plot_cross_validation`).
- :func:`checker_patch_spectra`: that spectral capture from the ``raw/colour_checker``
  group: band radiance ``f(I - dark) / (t Q)`` per patch.

References
----------
Fast Capture of Spectral Image Series, section 4, eq. 1 and Fig. 4.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from spectralize.nodes.calibration.band_shots import (
    band_batches,
    band_signal,
    computed_in_batches,
    longest_unsaturated_shots,
    shot_levels,
)
from spectralize.nodes.calibration.chart_patches import eroded_labels, patch_means
from spectralize.nodes.calibration.flat_field_maps import FlatField
from spectralize.nodes.calibration.matched_level_qe import matched_quantum_efficiency
from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = ["predict_rgb", "cross_validate", "checker_patch_spectra"]


def predict_rgb(spectra: xr.DataArray, camera_matrix: xr.Dataset | xr.DataArray) -> xr.DataArray:
    """RGB through the camera matrix: ``R = C S`` over wavelength (eq. 1, second term).

    Parameters
    ----------
    spectra
        Spectral radiance with a ``wavelength`` dim (any other dims).
    camera_matrix
        ``C`` (channel, wavelength) from :func:`~.camera_matrix`, on the same wavelengths.

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
        wavelength), e.g. :func:`~.patch_means` of :func:`~.band_signal` / ``Q``.
    camera_matrix
        ``C`` from :func:`~.camera_matrix`.

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


def checker_patch_spectra(
    colour_checker: xr.Dataset,
    dark: xr.Dataset,
    oecf_spectral: xr.Dataset,
    quantum_efficiency: xr.DataArray,
    levels: xr.Dataset | None,
    *,
    patch_margin: int,
    patch: np.ndarray,
    flat_field: FlatField | None = None,
) -> xr.DataArray:
    """Band radiance of every chart patch from the spectral camera's capture of the chart.

    Per band the longest unsaturated exposure of ``raw/colour_checker``'s band series,
    linearised (:func:`~.band_signal`) and divided by ``Q``, averaged over each patch of the
    chart's label image less ``patch_margin`` pixels at its borders
    (:func:`~.eroded_labels`, :func:`~.patch_means`): the spectra :func:`cross_validate` sends
    through ``C``.

    Parameters
    ----------
    colour_checker, dark, oecf_spectral
        Groups ``raw/colour_checker``, ``dark`` and ``calibration/oecf_spectral``.
    quantum_efficiency
        ``Q`` (wavelength) of the white reference.
    levels
        The white reference's level table
        (:func:`~spectralize.nodes.calibration.white_reference.white_level_table`): each shot
        is divided by the ``Q`` of its band at its own signal level
        (:func:`~spectralize.nodes.calibration.matched_level_qe.matched_quantum_efficiency`);
        ``None``: by its band's ``Q``.
    patch_margin
        Pixels removed at every patch border.
    patch
        The ``patch`` coordinate of the result (the measured RGB's).
    flat_field
        The spectral camera's flat field per band
        (:func:`~spectralize.nodes.calibration.flat_field.spectral_flat_field`), by which each
        band's signal is divided (as ``Q`` was measured through it); ``None``: none.

    Returns
    -------
    xarray.DataArray
        (wavelength, patch) band radiance, computed.

    Raises
    ------
    CalibrationError
        A band saturated at every exposure, a dark frame missing (naming
        ``raw/colour_checker:spectral_counts``).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 5 and Fig. 4.
    """
    group = "raw/colour_checker"
    _, _, shots = longest_unsaturated_shots(colour_checker, group)
    try:
        signal = band_signal(shots, dark, response=oecf_spectral)
    except CalibrationError as error:
        raise CalibrationError(f"{group}:spectral_counts: {error}") from None
    if flat_field is not None:  # flat field: each band over its map, as the white's was
        signal = flat_field.divide(signal, flat_field.rows(shots["wavelength"].values, "band"))
    q_shot = quantum_efficiency.sel(wavelength=shots["wavelength"].values).values
    # Batch by batch (band_batches: one band of a large sensor, every band of small ones):
    # each computation reads its bands' shots, linearises them and reduces them before the
    # next batch's are read (one computation over every band of a large sensor would read
    # the bands' frames ahead of their reductions). Each band's numbers are those of the one
    # computation: the same chunks, the same reductions. The patch means stay one graph per
    # band, computed a batch at a time (over several frames at once a patch's pixels would be
    # summed in another order).
    per_band = [signal.isel(shot=[k]) for k in range(signal.sizes["shot"])]
    batches = band_batches(shots, "shot")
    if levels is not None:
        # a batch's levels in one reduction over (y, x): each shot's sum is its own frame's
        means = [shot_levels(signal.isel(shot=part)) for part in batches]
        q_shot = matched_quantum_efficiency(
            levels, shots["wavelength"].values, np.concatenate(means), q_shot
        )
    labels = eroded_labels(np.asarray(colour_checker["patch_index"].values), patch_margin)
    spectra = []
    for shot, q_k in zip(per_band, q_shot, strict=True):
        band_radiance = shot / xr.DataArray([q_k], dims="shot")
        band_radiance = band_radiance.swap_dims(shot="wavelength").drop_vars(
            [c for c in band_radiance.coords if c != "wavelength"]
        )
        spectra.append(patch_means(band_radiance, labels))
    spectra = computed_in_batches(spectra, batches)
    return xr.concat(spectra, dim="wavelength").assign_coords(patch=patch)
