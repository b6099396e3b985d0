"""Checks of a calibration node's result against what a sane gantry gives.

A calibration that went wrong rarely raises: a response fitted to clamped codes, a camera
matrix fitted through it, a ``Q`` from saturated band shots are all finite arrays of the
right shape, and the run goes on to reconstruct spectra from them. These checks look at the
result as a physicist would (the chart cross-check of paper Fig. 4, a response that rises
through its codes, ``C`` of the shape of RGB sensitivities, ``Q`` without band-to-band
ripple) and name, with the number, the likely cause. Each returns warnings (plain sentences);
the flow prints them, and ``spectralize run --strict`` stops on them before the
reconstruction.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration"), eq. 5 and Fig. 4.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import xarray as xr

__all__ = [
    "CROSS_CHECK_WARNING",
    "NEAR_WHITE_DN",
    "RIPPLE_WARNING",
    "UNEVEN_WARNING",
    "GRADIENT_WARNING",
    "CORNER_RANGE",
    "flat_field_warnings",
    "oecf_rgb_warnings",
    "spectral_warnings",
    "result_warnings",
]

CROSS_CHECK_WARNING = 0.09
"""A camera's chart cross-check (mean relative error over the patches) above this warns:
three times the level the report flags (a sane gantry stays under that)."""

NEAR_WHITE_DN = 5
"""Codes within this many DN of a camera's largest chart code count as piled up there."""

NEAR_WHITE_SHARE = 0.01
"""A share of a camera's longest chart exposure piled up under its largest code (not the
top code) above this points at a white level below the top code."""

RIPPLE_WARNING = 0.2
"""``Q`` whose median relative second difference from band to band exceeds this warns."""

UNEVEN_WARNING = 0.03
"""A white reference deviating locally from its smooth flat field by more than this (and more
than its noise gives) warns: a shadow or a smudge on the target, which the flat field would
otherwise write into every image."""

GRADIENT_WARNING = 0.03
"""A flat field whose odd part about the frame centre exceeds this warns: a lens falloff is
even about its axis, a tilted or unevenly lit target is not."""

CORNER_RANGE = (0.6, 1.05)
"""A flat field's corners outside this range warn: below it, corners that get little of the
centre's light (their signal and the fit's extrapolation there are poor); above it, corners
brighter than the centre (not a lens: a hot spot or flare on the target)."""


def _camera_names(group: xr.Dataset, n: int) -> list[str]:
    if "camera_name" in group.coords or "camera_name" in group:
        return [str(v) for v in group["camera_name"].values]
    return [str(k) for k in range(n)]


def oecf_rgb_warnings(oecf_rgb: xr.Dataset, names: list[str] | None = None) -> list[str]:
    """Warnings on ``calibration/oecf_rgb``: per camera and channel, a response that is not
    finite, falls between the black level and the saturation, or does not rise through its
    codes (no more at the code under saturation than at the mid code)."""
    response = oecf_rgb["response"].transpose("camera", "channel", "code")
    values = np.asarray(response.values, dtype=float)
    cameras = [int(c) for c in response["camera"].values]
    names = names or [str(c) for c in cameras]
    top = values.shape[-1] - 1
    blacks = _per_camera(oecf_rgb, "black_level", len(cameras), 0)
    sats = _per_camera(oecf_rgb, "saturation", len(cameras), top)
    mid = top // 2
    found = []
    for k, camera in enumerate(cameras):
        for c, channel in enumerate(response["channel"].values.tolist()):
            f = values[k, c, blacks[k] + 1 : sats[k]]
            where = f"camera {names[k] if k < len(names) else camera}, channel {channel}"
            if not np.all(np.isfinite(f)):
                found.append(
                    f"{where}: the response is not finite between its black level and saturation"
                )
            elif f.size > 1 and np.any(np.diff(f) < -1e-9 * np.abs(f).max()):
                found.append(f"{where}: the response falls between its black level and saturation")
            elif f.size > 1 and not f[-1] > values[k, c, mid]:
                found.append(
                    f"{where}: the response at code {sats[k] - 1} ({f[-1]:.3g}) is not above the "
                    f"mid code's ({values[k, c, mid]:.3g}): a white level below the top code?"
                )
    return found


def _per_camera(group: xr.Dataset, name: str, n: int, default: int) -> list[int]:
    if name in group.data_vars and group[name].dims == ("camera",):
        return [int(v) for v in group[name].values]
    return [int(group.attrs.get(name, default))] * n


def _near_white(colour_checker: xr.Dataset, camera: int, depth: int) -> tuple[int, float] | None:
    """``(largest code, share of the longest chart exposure within NEAR_WHITE_DN of it)`` of
    ``camera``'s chart frames; None without them."""
    if "rgb_counts" not in colour_checker or "camera" not in colour_checker["rgb_counts"].dims:
        return None
    cameras = [int(v) for v in colour_checker["camera"].values]
    if camera not in cameras:
        return None
    pos = cameras.index(camera)
    counts = colour_checker["rgb_counts"].isel(camera=pos)
    times = np.asarray(colour_checker["rgb_exposure_time"].isel(camera=pos).values, dtype=float)
    longest = np.asarray(counts.isel(rgb_exposure=int(np.argmax(times))).values)
    top = int(longest.max())
    return top, float(np.mean(longest >= top - NEAR_WHITE_DN))


def _cross_check_cause(
    camera: int, colour_checker: xr.Dataset | None, oecf_rgb: xr.Dataset | None, depth: int
) -> str:
    """The likely cause of a failed chart cross-check, as a phrase."""
    near = None if colour_checker is None else _near_white(colour_checker, camera, depth)
    if near is not None:
        code, share = near
        if code < 2**depth - 1 and share > NEAR_WHITE_SHARE:
            level = ""
            if oecf_rgb is not None and "white_level" in oecf_rgb.data_vars:
                per = oecf_rgb["white_level"]
                if camera in per["camera"].values.tolist():
                    level = f" (white level used: {int(per.sel(camera=camera))} DN)"
            return (
                f"{100 * share:.0f} % of its longest chart exposure's codes within "
                f"{NEAR_WHITE_DN} DN of {code}{level}: a white level below the top code? "
                "(capture.toml rgb.white_level_dn)"
            )
    return "its response (calibration/oecf_rgb) or its chart label image does not fit its frames?"


def spectral_warnings(
    spectral: xr.Dataset,
    *,
    colour_checker: xr.Dataset | None = None,
    oecf_rgb: xr.Dataset | None = None,
) -> list[str]:
    """Warnings on ``calibration/spectral``.

    - Per RGB camera, a chart cross-check (``camera_mean_relative_error``, else the group's
      ``mean_relative_error``) above :data:`CROSS_CHECK_WARNING`, with its likely cause
      (:func:`_cross_check_cause`: the chart's codes piled up under a white level, else the
      response or the label image).
    - ``C`` not of the physical shape of RGB sensitivities: a channel without positive
      weight, or the channels' peaks not in the order B, G, R in wavelength.
    - ``Q`` rippling from band to band (median relative second difference above
      :data:`RIPPLE_WARNING`): band shots saturated or under-exposed?
    """
    found = []
    depth = int(
        (colour_checker.attrs.get("rgb_bit_depth") if colour_checker is not None else None)
        or (oecf_rgb.attrs.get("bit_depth") if oecf_rgb is not None else None)
        or 16
    )
    if "camera_mean_relative_error" in spectral:
        errors = np.asarray(spectral["camera_mean_relative_error"].values, dtype=float)
        cameras = (
            [int(v) for v in spectral["camera"].values]
            if "camera" in spectral.coords
            else list(range(errors.size))
        )
    else:
        errors = np.array([float(spectral.attrs.get("mean_relative_error", np.nan))])
        cameras = [int(spectral.attrs.get("rgb_camera", 0))]
    names = _camera_names(spectral, len(cameras))
    for k, error in enumerate(errors.tolist()):
        if error > CROSS_CHECK_WARNING:
            cause = _cross_check_cause(cameras[k], colour_checker, oecf_rgb, depth)
            found.append(f"camera {names[k]}: chart cross-check {100 * error:.0f} %, {cause}")
    found += _matrix_shape_warnings(spectral)
    found += flat_field_warnings(spectral)
    q = np.asarray(spectral["quantum_efficiency"].values, dtype=float)
    if q.size >= 5 and np.all(q > 0):
        ripple = float(np.median(np.abs(np.diff(q, 2)) / q[1:-1]))
        if ripple > RIPPLE_WARNING:
            found.append(
                f"Q ripples from band to band (median relative second difference "
                f"{100 * ripple:.0f} %): band shots saturated or under-exposed?"
            )
    return found


def flat_field_warnings(spectral: xr.Dataset) -> list[str]:
    """Warnings on the flat fields of ``calibration/spectral`` (RGB cameras per camera, the
    spectral camera over its bands), each with the measured non-uniformity:

    - the white reference not even: a local deviation from the smooth map above
      :data:`UNEVEN_WARNING` and above what its noise gives (a shadow, a smudge);
    - a gradient: the map's odd part about the frame centre above :data:`GRADIENT_WARNING`
      (a tilted or unevenly lit target);
    - corners outside :data:`CORNER_RANGE`.
    """
    found = []
    if "flat_field_rgb_unevenness" in spectral:
        names = _camera_names(spectral, spectral.sizes["camera"])
        for k, name in enumerate(names):
            found += _flat_warnings(spectral.isel(camera=k), "flat_field_rgb", f"camera {name}")
    if "flat_field_unevenness" in spectral:
        found += _flat_warnings(spectral, "flat_field", "the spectral camera")
    return found


def _flat_warnings(group: xr.Dataset, prefix: str, who: str) -> list[str]:
    """:func:`flat_field_warnings` of one camera: its measures over channels or bands."""

    def worst(name: str, score) -> tuple[float, str]:
        values = group[f"{prefix}_{name}"]
        flat = np.asarray(values.values, dtype=float).ravel()
        if not np.isfinite(flat).any():
            return np.nan, ""
        i = int(np.nanargmax(score(flat)))
        label = ""
        if values.dims:
            dim = values.dims[0]
            label = (
                f" (channel {values[dim].values.ravel()[i]})"
                if dim == "channel"
                else (f" (worst band {float(values[dim].values.ravel()[i]):g} nm)")
            )
        return float(flat[i]), label

    found = []
    floor = np.asarray(group[f"{prefix}_unevenness_floor"].values, dtype=float)
    uneven = np.asarray(group[f"{prefix}_unevenness"].values, dtype=float)
    excess = np.where(np.abs(uneven) > np.maximum(UNEVEN_WARNING, floor), np.abs(uneven), 0.0)
    if np.nanmax(excess, initial=0.0) > 0:
        value, label = worst("unevenness", lambda v: np.where(np.isfinite(v), excess.ravel(), -1))
        kind = "dip" if value < 0 else "bright spot"
        found.append(
            f"{who}: the white reference is not even: a local {kind} of {100 * abs(value):.1f} % "
            f"the smooth lens falloff cannot explain{label} (a shadow or a smudge on the target?)"
        )
    value, label = worst("gradient", lambda v: np.nan_to_num(v, nan=-1.0))
    if value > GRADIENT_WARNING:
        found.append(
            f"{who}: the white reference has a gradient of +-{100 * value:.1f} % across the frame"
            f"{label}, which a lens falloff (even about its axis) cannot make (a tilted or "
            "unevenly lit target?)"
        )
    value, label = worst("corner", lambda v: np.nan_to_num(np.abs(v - 1.0), nan=-1.0))
    low, high = CORNER_RANGE
    if np.isfinite(value) and not low <= value <= high:
        found.append(
            f"{who}: the flat field is {value:.2f} in a corner{label} (expected {low}..{high}): "
            + (
                "a falloff this strong leaves the corners poorly measured"
                if value < low
                else "corners brighter than the centre are no lens falloff (flare on the target?)"
            )
        )
    return found


def _matrix_shape_warnings(spectral: xr.Dataset) -> list[str]:
    """``C`` (each camera's, else the group's) without positive weight in a channel, or with
    its channels' peaks out of the order B < G < R in wavelength."""
    if "camera_matrices" in spectral:
        matrices = spectral["camera_matrices"].transpose("camera", "channel", "wavelength")
    else:
        matrices = spectral["camera_matrix"].transpose("channel", "wavelength").expand_dims(camera=1)
    names = _camera_names(spectral, matrices.sizes["camera"])
    channels = [str(c) for c in matrices["channel"].values]
    wavelength = np.asarray(matrices["wavelength"].values, dtype=float)
    found = []
    for k, c in enumerate(np.asarray(matrices.values, dtype=float)):
        who = f"camera {names[k]}" if matrices.sizes["camera"] > 1 else "C"
        empty = [channels[i] for i in range(len(channels)) if not np.nanmax(c[i]) > 0]
        if empty:
            found.append(f"{who}: C has no positive weight in channel(s) {', '.join(empty)}")
            continue
        peaks = dict(zip(channels, wavelength[np.nanargmax(c, axis=1)].tolist(), strict=True))
        if {"R", "G", "B"} <= set(peaks) and not peaks["B"] < peaks["G"] < peaks["R"]:
            found.append(
                f"{who}: C's channel peaks at B {peaks['B']:g}, G {peaks['G']:g}, R {peaks['R']:g} "
                "nm, not in the order of RGB sensitivities: a response or chart that does not fit?"
            )
    return found


def result_warnings(
    node: str, inputs: Mapping[str, xr.Dataset], outputs: Mapping[str, xr.Dataset]
) -> list[str]:
    """The warnings on the result of calibration node ``node`` (empty for other nodes):
    ``inputs`` by argument name, ``outputs`` by group name."""
    if node == "recover_rgb_oecf" and "calibration/oecf_rgb" in outputs:
        raw = inputs.get("raw_rgb")
        names = list(raw.attrs.get("camera_names") or []) if raw is not None else []
        oecf = outputs["calibration/oecf_rgb"]
        cameras = [int(c) for c in oecf["camera"].values]
        labels = [names[c] if c < len(names) else str(c) for c in cameras]
        return oecf_rgb_warnings(oecf, labels)
    if node == "estimate_registration" and "registration" in outputs:
        from spectralize.nodes.calibration.registration import registration_warnings

        return registration_warnings(outputs["registration"])
    if node == "calibrate_spectral" and "calibration/spectral" in outputs:
        return spectral_warnings(
            outputs["calibration/spectral"],
            colour_checker=inputs.get("colour_checker"),
            oecf_rgb=inputs.get("oecf_rgb"),
        )
    return []
