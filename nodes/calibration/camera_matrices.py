"""``C`` of every RGB camera from its own HDR RGB of the colour checker.

- :data:`CAMERA_MATRIX_METHODS`: how ``C`` is fitted (smooth lobes or a second-difference
  penalty).
- :func:`fit_camera_matrices`: each camera's RGB exposure series of the chart merged to HDR
  through its own response, patch means against patch reflectance times the measured
  illuminant (and the white reference as one more patch), one ``C`` per camera; cameras
  without chart frames borrow the ``C`` of a camera of the same model.
- :func:`camera_table`: per camera ``C``, the map of its HDR RGB onto the paired camera's and
  its own chart cross-validation.

References
----------
Fast Capture of Spectral Image Series, section 4 and eq. 1 (matrix ``C``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import NamedTuple

import numpy as np
import xarray as xr

from spectralize.nodes.calibration.camera_lobes import lobe_camera_matrix
from spectralize.nodes.calibration.camera_smooth import camera_matrix, cross_validated_smoothness
from spectralize.nodes.calibration.chart_patches import eroded_labels, patch_means
from spectralize.nodes.calibration.cross_validation import cross_validate
from spectralize.nodes.calibration.exposure_series import check_bit_depth, frame_flags
from spectralize.nodes.calibration.flat_field_maps import FlatField
from spectralize.nodes.calibration.hdr import merge_hdr
from spectralize.nodes.calibration.rgb_transform import rgb_transform
from spectralize.schemas import CalibrationError

__all__ = [
    "CAMERA_MATRIX_METHODS",
    "target_cameras",
    "CameraFitSettings",
    "CameraFit",
    "CameraFits",
    "fit_camera_matrices",
    "method_settings",
    "camera_table",
    "camera_saturation",
]

CAMERA_MATRIX_METHODS = {
    "lobes": lobe_camera_matrix,
    "smooth": camera_matrix,
}
"""How :func:`~.calibrate_spectral` fits ``C``: a non-negative sum of smooth lobes
(:func:`~spectralize.nodes.calibration.camera_lobes.lobe_camera_matrix`, the default) or
second-difference-penalised non-negative least squares (:func:`~.camera_matrix`)."""


def target_cameras(target: xr.Dataset) -> list[int]:
    """The raw/rgb camera indices of a calibration target's RGB series, in its ``camera`` order."""
    if "camera" in target["rgb_counts"].dims:
        return [int(v) for v in target["camera"].values]
    return [int(target.attrs.get("rgb_camera", 0))]


class CameraFitSettings(NamedTuple):
    """How :func:`fit_camera_matrices` fits ``C`` of every camera (the spectral
    calibration's parameters of the same names)."""

    method: str
    """A key of :data:`CAMERA_MATRIX_METHODS`."""
    ridge: float | None
    """``"lobes"``: the ridge of :func:`~.lobe_camera_matrix` (None: cross-validated)."""
    weak_light: float
    """``"lobes"``: the weak-light weight of :func:`~.lobe_camera_matrix`."""
    smoothness: float | None
    """``"smooth"``: the smoothness of :func:`~.camera_matrix` (None: cross-validated by
    :func:`~.cross_validated_smoothness`)."""
    nonnegative: bool
    """``"smooth"``: constrain ``C >= 0``."""
    white_patch: bool
    """Fit ``C`` to the white reference as one more patch."""
    patch_margin: int
    """Pixels removed at every patch border before patch means."""


class CameraFit(NamedTuple):
    """``C`` of one RGB camera and what it was fitted to (:func:`fit_camera_matrices`)."""

    cm: xr.Dataset
    """The fit: ``camera_matrix`` (channel, wavelength) and the fit's own variables and attrs."""
    measured: xr.DataArray
    """The camera's HDR RGB of the chart's patches (patch, channel)."""
    fit_spectra: xr.DataArray
    """The spectra ``C`` was fitted to (patch, wavelength), the white reference's included."""
    cv_scores: xr.DataArray | None
    """Leave-one-patch-out scores over ``smoothness`` when the smoothness was chosen."""
    smoothness: float | None
    """The smoothness of a ``"smooth"`` fit (given or chosen)."""


class CameraFits(NamedTuple):
    """:func:`fit_camera_matrices`: ``C`` of every RGB camera with chart frames."""

    fits: dict[int, CameraFit]
    """Per camera index with its own chart frames, its fit."""
    names_of: dict[int, str]
    """Per camera index, its name."""
    lender_of: dict[int, int]
    """Per camera without chart frames, the camera of the same model whose ``C`` it borrows."""
    reference: int
    """The camera whose ``C`` is the group's ``camera_matrix``: the paired one, or its lender."""
    paired: int
    """The RGB camera paired with the spectral camera (``rgb_camera`` attr)."""


def _rgb_series(
    target: xr.Dataset, group: str, camera: int | None = None, saturation: int | None = None
) -> xr.Dataset:
    """One camera's RGB exposure series of a target (default: the paired camera's) as a
    one-image raw/rgb Dataset (usable exposures: not every value at or above ``saturation``,
    default the top code, nor every value dark)."""
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
    saturation = 2**depth - 1 if saturation is None else saturation
    _, _, not_saturated, not_dark = frame_flags(counts, ("y", "x"), black_level=0, saturation=saturation)
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


def _white_rgb(
    white_reference: xr.Dataset,
    response: xr.DataArray,
    attrs: Mapping,
    group: str,
    margin: float = 0.1,
    camera: int | None = None,
    saturation: int | None = None,
    flat_field: FlatField | None = None,
) -> xr.DataArray:
    """HDR RGB (channel,) of the white reference: median over the frame less a border of
    ``margin`` of its size (hot pixels and the target's edge do not move a median); codes at
    or above ``saturation`` (default the response's) saturated; divided by the camera's
    ``flat_field`` where given."""
    raw = _rgb_series(white_reference, group, camera, saturation).drop_vars("camera")
    hdr = merge_hdr(
        raw,
        response.assign_attrs(dict(attrs) | response.attrs),
        saturation=saturation,
        flat_field=flat_field,
    )["radiance"].isel(image=0)
    ny, nx = hdr.sizes["y"], hdr.sizes["x"]
    dy, dx = int(margin * ny), int(margin * nx)
    centre = hdr.isel(y=slice(dy, ny - dy), x=slice(dx, nx - dx))
    return (
        centre.median(("y", "x"))
        .compute()
        .drop_vars([c for c in centre.coords if c != "channel"], errors="ignore")
    )


def camera_saturation(oecf_rgb: xr.Dataset, camera: int) -> int | None:
    """The first saturated code of ``camera`` in ``calibration/oecf_rgb`` (its ``saturation``
    over ``camera``, below the camera's white level); None where the group has none (the
    response's own attrs decide)."""
    if "saturation" not in oecf_rgb.data_vars or "camera" not in oecf_rgb["saturation"].dims:
        return None
    per_camera = oecf_rgb["saturation"]
    cameras = per_camera["camera"].values.tolist()
    return int(per_camera.sel(camera=camera if camera in cameras else cameras[0]))


def _bare(data: xr.DataArray, keep: str) -> xr.DataArray:
    """``data`` without coords other than ``keep``."""
    return data.drop_vars([c for c in data.coords if c != keep])


def method_settings(
    method: str, fit: CameraFit, *, ridge: float | None, nonnegative: bool
) -> dict[str, object]:
    """The chosen settings of ``C``'s fit ``fit`` by ``method``, for the group's attrs: the
    ``ridge`` given (or chosen) per channel, the lobe widths and the weak-light penalty, or
    the smoothness (given or chosen by leaving each patch out) and ``nonnegative``."""
    cm, smoothness, cv_scores = fit.cm, fit.smoothness, fit.cv_scores
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
    settings: CameraFitSettings,
    flat_field: FlatField | None = None,
) -> CameraFit:
    """``C`` of one RGB camera from its own HDR RGB of the chart (and the white reference),
    through its own response and patch label image, divided by its ``flat_field`` (the map
    of this camera alone) where given."""
    method, ridge, weak_light, smoothness, nonnegative, white_patch, patch_margin = settings
    group = "raw/colour_checker"
    saturation = camera_saturation(oecf_rgb, camera)
    rgb_raw = _rgb_series(colour_checker, group, camera, saturation)
    response = oecf_rgb["response"]
    if "camera" in response.dims:
        response = response.sel(
            camera=camera if camera in response["camera"].values.tolist() else response["camera"][0]
        )
    hdr = merge_hdr(
        rgb_raw.drop_vars("camera"),
        response.assign_attrs(oecf_rgb.attrs | response.attrs),
        saturation=saturation,
        flat_field=flat_field,
    )
    index = colour_checker["patch_index"]
    if "rgb_patch_index" in colour_checker:
        index = colour_checker["rgb_patch_index"].isel(
            camera=target_cameras(colour_checker).index(camera)
        )
    labels = eroded_labels(np.asarray(index.values), patch_margin)
    measured = patch_means(hdr["radiance"].isel(image=0), labels).compute()
    spectra = (colour_checker["patch_reflectance"] * colour_checker["illuminant"]).load()
    spectra = spectra.assign_coords(patch=measured["patch"].values).transpose("patch", "wavelength")
    fit_rgb, fit_spectra = measured, spectra
    if white_patch:
        white_rgb = _white_rgb(
            white_reference,
            response,
            oecf_rgb.attrs,
            "raw/white_reference",
            camera=camera,
            saturation=saturation,
            flat_field=flat_field,
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
    return CameraFit(cm, measured, fit_spectra, cv_scores, smoothness)


def fit_camera_matrices(
    white_reference: xr.Dataset,
    colour_checker: xr.Dataset,
    oecf_rgb: xr.Dataset,
    settings: CameraFitSettings,
    flat_field: FlatField | None = None,
) -> CameraFits:
    """``C`` of every RGB camera from its own HDR RGB of the colour checker.

    Each camera's RGB exposure series of the chart is merged to HDR through its own response
    (:func:`~spectralize.nodes.calibration.hdr.merge_hdr`), averaged over its own patch label
    image less ``settings.patch_margin`` pixels at the borders, and fitted against the
    patches' reflectance times the measured illuminant; with ``settings.white_patch`` the
    white reference's HDR RGB (median over the frame less a border of a tenth of its size)
    against its reflectance times the illuminant is one more patch. ``settings`` (a
    :class:`CameraFitSettings`) names the method, a key of :data:`CAMERA_MATRIX_METHODS`,
    and its settings: ``ridge`` and ``weak_light`` are those of
    :func:`~spectralize.nodes.calibration.camera_lobes.lobe_camera_matrix`, ``smoothness``
    (``None``: chosen by :func:`~.cross_validated_smoothness`) and ``nonnegative`` those of
    :func:`~.camera_matrix`. Cameras named in ``calibration_borrowed`` (no chart frames of
    their own) borrow the ``C`` of a camera of the same model. With ``flat_field`` (each
    camera's, :func:`~spectralize.nodes.calibration.flat_field.rgb_flat_field`) the chart's
    and the white reference's HDR RGB are divided by the camera's map, as the scene's are.

    Raises
    ------
    CalibrationError
        An RGB series without a usable exposure, naming the group and the camera.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 1.
    """
    cameras = target_cameras(colour_checker)
    paired = int(colour_checker.attrs.get("rgb_camera", cameras[0]))
    fits = {
        k: _fit_camera(
            k,
            white_reference,
            colour_checker,
            oecf_rgb,
            settings,
            None if flat_field is None else flat_field.only(k),
        )
        for k in cameras
    }
    names_of, lender_of = _camera_names(colour_checker, cameras)
    reference = paired if paired in fits else lender_of[paired]
    return CameraFits(fits, names_of, lender_of, reference, paired)


def camera_table(
    fitted: CameraFits, patch_spectra: xr.DataArray, colour_checker: xr.Dataset
) -> xr.Dataset:
    """``C``, the map onto the reference camera's RGB and the chart cross-validation per camera.

    Every camera of ``fitted`` (those with chart frames and those that borrow a lender's
    ``C``): its ``C``, the 3 x 3 map of its HDR RGB onto the reference camera's
    (:func:`~spectralize.nodes.calibration.rgb_transform.rgb_transform` over the reference's
    fit spectra), the cross-validation of its own measured RGB against ``patch_spectra``
    through its ``C`` (:func:`~.cross_validate`), where its ``C`` came from, and its model
    (``raw/colour_checker``'s ``camera_models`` attr).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4, eq. 1 and Fig. 4.
    """
    fits, lender_of, names_of = fitted.fits, fitted.lender_of, fitted.names_of
    reference = fitted.reference
    fit_spectra = fits[reference].fit_spectra
    cameras = sorted(set(fits) | set(lender_of))
    c_ref = np.asarray(fits[reference].cm["camera_matrix"].values, float)
    matrices, transforms, errors, sources = [], [], [], []
    for k in cameras:
        own = fits[k if k in fits else lender_of[k]]
        cm = own.cm["camera_matrix"]
        matrices.append(np.asarray(cm.values, float))
        transforms.append(rgb_transform(cm.values, c_ref, np.asarray(fit_spectra.values, float)))
        errors.append(np.asarray(cross_validate(own.measured, patch_spectra, cm)["relative_error"]))
        sources.append(
            "own chart frames"
            if k in fits
            else f"borrowed from {names_of[lender_of[k]]} (same model in capture.toml rgb.models)"
        )
    channel = fits[reference].cm["camera_matrix"]["channel"].values
    wavelength = fits[reference].cm["camera_matrix"]["wavelength"].values
    models = [str(m) for m in colour_checker.attrs.get("camera_models", [])]
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
    ).assign_coords(
        camera_model=("camera", np.asarray([models[k] if k < len(models) else "" for k in cameras]))
    )
