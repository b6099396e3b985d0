"""Spectral calibration (paper section 4): the ``calibrate_spectral`` node.

:func:`calibrate_spectral` measures the quantum efficiency ``Q`` of the spectral camera, the
camera matrix ``C`` of every RGB camera and the cross-validation of paper Fig. 4 from the
``raw/white_reference`` and ``raw/colour_checker`` groups. Each step is a module of its own:

=====================  ====================================================================
module                 step
=====================  ====================================================================
``band_shots``         band signal: dark-subtracted, linearised band shots per second
``flat_field``         every camera's flat field (lens falloff) from its white-reference
                       frames: per RGB camera and channel, per band
``white_reference``    ``Q`` per band, the measured illuminant ``L`` on the bands, ``Q`` per
                       level of the white reference's exposure series
``camera_smooth``      ``C`` by a second-difference penalty (``camera_lobes``: by smooth
                       lobes, the default)
``camera_matrices``    ``C`` of every RGB camera from its own HDR RGB of the chart
``chart_patches``      the chart's patch labels and patch means
``cross_validation``   the spectral capture of the chart through ``C`` against the measured
                       RGB (Fig. 4)
=====================  ====================================================================

References
----------
Fast Capture of Spectral Image Series, section 4 ("Calibration", Figs. 3 and 4) and eq. 5.
M. A. Robertson, S. Borman, R. L. Stevenson, Journal of Electronic Imaging 12(2), 2003
(the OECF used for linearisation).
"""

from __future__ import annotations

from typing import Annotated

import xarray as xr
from pydantic import Field

from spectralize.engine import Choices
from spectralize.nodes.calibration.camera_lobes import WEAK_LIGHT_WEIGHT
from spectralize.nodes.calibration.camera_matrices import (
    CAMERA_MATRIX_METHODS,
    CameraFit,
    CameraFitSettings,
    camera_table,
    fit_camera_matrices,
    method_settings,
)
from spectralize.nodes.calibration.cross_validation import checker_patch_spectra, cross_validate
from spectralize.nodes.calibration.flat_field import (
    flat_field_variables,
    rgb_flat_field,
    spectral_flat_field,
)
from spectralize.nodes.calibration.white_reference import (
    WhiteReferenceCalibration,
    calibrate_white_reference,
)

__all__ = ["calibrate_spectral"]


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

    - Flat fields: each RGB camera's (one map for its channels) from its HDR of the white reference
      (:func:`~.rgb_flat_field`), the spectral camera's per band from the white reference's
      band series (:func:`~.spectral_flat_field`); every target below is divided by its
      camera's map before ``Q`` and ``C`` are fitted, as the scene's images and band shots
      are (``hdr_merge``, ``calibrate_bands``).
    - ``Q`` per band: the white reference's longest unsaturated exposure of each band,
      linearised with the spectral response, per second, divided by the target reflectance
      times the measured illuminant (:func:`~.calibrate_white_reference`).
    - ``C``: the colour checker's RGB exposure series merged to HDR with the RGB response
      (:func:`~spectralize.nodes.calibration.hdr.merge_hdr`), patch means, against patch
      reflectance times the measured illuminant; with ``white_patch`` the white reference's
      HDR RGB (median over the frame less a border of a tenth of its size) against its
      reflectance times the illuminant is one more patch, the one spectrum a chart of
      pigments lacks (flat). By default ``C`` is a non-negative sum of smooth lobes
      (:func:`~spectralize.nodes.calibration.camera_lobes.lobe_camera_matrix`, the ridge
      chosen per channel by leaving each patch out in turn, held to zero by ``weak_light``
      where the targets had little light): a second-difference penalty
      (``camera_matrix_method="smooth"``, :func:`~.camera_matrix`) extrapolates linearly
      where the light is weak and lets a row keep rising to the end of the bands.
    - Cross-validation: the spectral camera's capture of the checker (longest unsaturated
      exposure per band, band signal / Q, patch means) through ``C`` against the measured
      HDR RGB (:func:`~.checker_patch_spectra`, :func:`~.cross_validate`); and the same
      per RGB camera through its own ``C`` (:func:`~.fit_camera_matrices`,
      :func:`~.camera_table`).

    Returns
    -------
    xarray.Dataset
        Group ``calibration/spectral``: ``quantum_efficiency`` (wavelength) [1],
        ``illuminant`` (wavelength) [1] (the measured illuminant ``L`` on the band
        wavelengths, :func:`~.measured_illuminant_on_bands`: a white diffuser's band radiance),
        ``camera_matrix`` (channel, wavelength) [1], ``measured_rgb`` / ``predicted_rgb``
        (patch, channel) [1], ``relative_error`` (patch) [1], ``patch_spectra`` (patch,
        wavelength) [1] (from the spectral camera), ``qe_snr`` (wavelength) [1],
        ``ridge_cv`` (ridge_candidate, channel) or ``smoothness_cv`` (smoothness) [1] (the
        cross-validation scores, when chosen), ``qe_by_level`` and ``qe_level`` (the white
        reference's level table), and per RGB camera (``camera``) the variables of
        :func:`~.camera_table`. Attrs ``mean_relative_error``,
        ``max_relative_error``, ``worst_patch``, ``c_relative_rms_residual``, the flat fields
        (:func:`~.flat_field_variables`: ``flat_field_rgb`` (camera, channel, flat_term) and
        ``flat_field`` (wavelength, flat_term) Legendre coefficients with their noise floor
        and evenness measures) and the chosen
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
    rgb_flat, rgb_fits = rgb_flat_field(white_reference, oecf_rgb)
    band_flat, band_fits = spectral_flat_field(white_reference, dark, oecf_spectral)
    white = calibrate_white_reference(
        white_reference, dark, oecf_spectral, min_snr=min_snr, flat_field=band_flat
    )
    fitted = fit_camera_matrices(
        white_reference,
        colour_checker,
        oecf_rgb,
        CameraFitSettings(
            camera_matrix_method, ridge, weak_light, smoothness, nonnegative, white_patch, patch_margin
        ),
        flat_field=rgb_flat,
    )
    fit = fitted.fits[fitted.reference]
    patch_spectra = checker_patch_spectra(
        colour_checker,
        dark,
        oecf_spectral,
        white.quantum_efficiency["quantum_efficiency"],
        white.levels if matched_levels else None,
        patch_margin=patch_margin,
        patch=fit.measured["patch"].values,
        flat_field=band_flat,
    )
    table = cross_validate(fit.measured, patch_spectra, fit.cm)
    per_camera = camera_table(fitted, patch_spectra, colour_checker)
    settings = {
        "camera_matrix_method": camera_matrix_method,
        **method_settings(camera_matrix_method, fit, ridge=ridge, nonnegative=nonnegative),
        "white_patch": bool(white_patch),
        "matched_levels": bool(matched_levels),
        "patch_margin": int(patch_margin),
        "rgb_camera": fitted.paired,
    }
    out = _spectral_group(white, fit, patch_spectra, table, settings)
    out = out.merge(per_camera.assign_coords(patch=out["patch"].values))
    flats = flat_field_variables(
        rgb_flat,
        rgb_fits,
        band_flat,
        band_fits,
        [int(k) for k in out["camera"].values],
        fitted.lender_of,
    )
    out = out.merge(flats.assign_coords(channel=white_reference["channel"].values))
    out.attrs.update(flats.attrs)
    if "patch_name" in colour_checker.coords:
        names = [str(v) for v in colour_checker["patch_name"].values]
        out = out.assign_coords(patch_name=("patch", names))
    out["wavelength"].attrs.update(units="nm", long_name="band centre wavelength")
    return out


def _spectral_group(
    white: WhiteReferenceCalibration,
    fit: CameraFit,
    patch_spectra: xr.DataArray,
    table: xr.Dataset,
    settings: dict[str, object],
) -> xr.Dataset:
    """The ``calibration/spectral`` group of the paired camera, before the per-camera table:
    ``Q`` and ``L`` of the white reference, ``C``, the cross-validation ``table`` and the
    patch spectra, with the fit's ``settings`` in the attrs."""
    q, cm = white.quantum_efficiency["quantum_efficiency"], fit.cm
    unit = {"units": "1"}
    out = xr.Dataset(
        {
            "quantum_efficiency": q.assign_attrs(
                **unit,
                long_name="relative quantum efficiency Q (band signal per unit of the "
                "measured illuminant)",
            ),
            "qe_snr": white.quantum_efficiency["snr"].assign_attrs(
                **unit, long_name="per-pixel SNR of the white reference"
            ),
            "illuminant": white.illuminant,
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
            **settings,
            "units_note": "band radiance relative to the measured illuminant; C maps it to "
            "HDR units (RGB = C @ spectrum)",
        },
    )
    out["qe_by_level"] = white.levels["qe_by_level"]
    out["qe_level"] = white.levels["qe_level"]
    if fit.cv_scores is not None:
        out["smoothness_cv"] = fit.cv_scores
    if "ridge_cv" in cm:
        out["ridge_cv"] = cm["ridge_cv"]
    keep = ("wavelength", "channel", "patch", "smoothness", "ridge_candidate")
    return out.drop_vars([c for c in out.coords if c not in keep])
