"""The white level of an RGB camera: the code its raw values clip at.

Eq. 5 of the paper clamps a camera's values to its code range. Many raw formats clip below
the top code ``2**bit_depth - 1``: the sensor or the raw converter saturates at a *white
level* a little under it. A saturated sample then reads the white level, not the top code,
and a test "saturated = the top code" takes it for a valid one: the response recovery fits
clamped samples as if they were exposures, and the HDR merge and the targets' series weight
them.

:func:`white_level` finds the level from the data as raw converters do: a pile-up of values at
one code below the top, the largest observed, in the longest exposures (where saturation
gathers every bright pixel onto one code). :func:`saturation_code` turns a white level into
the first saturated code (the level less its noise), which the response fit, the HDR merge
and the targets' series use.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration") and eq. 5.
.. [2] D. Coffin, dcraw (the raw converter): a camera's ``maximum``, the white level, read
   from the raw file or from the data's largest value.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import xarray as xr

from spectralize.schemas import CalibrationError

__all__ = [
    "WhiteLevelEvidence",
    "CameraWhiteLevel",
    "white_level",
    "camera_white_levels",
    "white_level_variables",
    "saturation_code",
    "white_margin",
    "MIN_PILE_SHARE",
    "PILE_RATIO",
]

MIN_PILE_SHARE = 1e-4
"""Least share of the pooled values at the largest code for a pile-up (a highlight of a few
pixels in a large frame is no evidence)."""

MIN_PILE_PIXELS = 16
"""Least number of values at the largest code for a pile-up."""

PILE_RATIO = 8.0
"""A pile-up holds at least this many times the mean count per code of the
:data:`BASELINE_CODES` codes under it: the largest code of unclipped data is a tail, with
fewer values than the codes below it."""

BASELINE_CODES = 16
"""Codes under the largest one whose mean count is the pile-up's baseline."""

WHITE_MARGIN_FRACTION = 0.002
"""The noise margin under a white level, as a fraction of the code range (at least 3 DN)."""


class WhiteLevelEvidence(NamedTuple):
    """What :func:`white_level` saw: the largest code and how many values sit on it."""

    max_code: int
    """The largest observed code [DN]."""
    at_max: int
    """Values at exactly that code."""
    values: int
    """Values looked at."""
    baseline: float
    """Mean count per code of the :data:`BASELINE_CODES` codes under the largest."""

    @property
    def share(self) -> float:
        """Share of the values at the largest code."""
        return self.at_max / max(self.values, 1)


def white_level(codes: np.ndarray, bit_depth: int) -> tuple[int | None, WhiteLevelEvidence]:
    """The white level of integer ``codes`` (the longest exposures of one camera and channel).

    A pile-up at the largest observed code ``m`` below the top code: at least
    :data:`MIN_PILE_PIXELS` values and a share :data:`MIN_PILE_SHARE` of them at exactly
    ``m``, :data:`PILE_RATIO` times the mean count per code of the codes under it, and ``m``
    in the upper half of the code range (a white level is near the top). None when ``m`` is
    the top code (saturation there is the usual test) or there is no pile-up (nothing
    clipped, or nothing reached the white level).

    Parameters
    ----------
    codes
        Integer values [DN], any shape.
    bit_depth
        ADC bit depth (the top code is ``2**bit_depth - 1``).

    Returns
    -------
    tuple
        ``(level, evidence)``: the white level [DN] or None, and
        :class:`WhiteLevelEvidence`.

    Raises
    ------
    CalibrationError
        Codes that are not integers in ``0 .. 2**bit_depth - 1``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 5 (the clamp to the code range).
    """
    values = np.asarray(codes).ravel()
    top = 2 ** int(bit_depth) - 1
    if values.size == 0:
        return None, WhiteLevelEvidence(-1, 0, 0, 0.0)
    if not np.issubdtype(values.dtype, np.integer) or values.min() < 0 or values.max() > top:
        found = f"dtype {values.dtype}, range [{values.min()}, {values.max()}]"
        raise CalibrationError(
            f"white_level: codes must be integers in [0, {top}] (bit depth {bit_depth}); {found}"
        )
    counts = np.bincount(values, minlength=top + 1)
    m = int(np.flatnonzero(counts)[-1])
    below = counts[max(m - BASELINE_CODES, 0) : m]
    evidence = WhiteLevelEvidence(
        m, int(counts[m]), int(values.size), float(below.mean()) if below.size else 0.0
    )
    if m >= top or m < 2 ** (int(bit_depth) - 1):
        return None, evidence
    enough = evidence.at_max >= max(MIN_PILE_PIXELS, MIN_PILE_SHARE * values.size)
    if not enough or evidence.at_max < PILE_RATIO * max(evidence.baseline, 1.0):
        return None, evidence
    return m, evidence


def white_margin(bit_depth: int) -> int:
    """The noise margin under a white level [DN]: :data:`WHITE_MARGIN_FRACTION` of the code
    range, at least 3 DN."""
    return max(3, round(WHITE_MARGIN_FRACTION * 2 ** int(bit_depth)))


def saturation_code(level: int | None, bit_depth: int) -> int:
    """The first saturated code of a camera of white level ``level``.

    The top code ``2**bit_depth - 1`` when there is no white level under it (``None`` or the
    top code): only the top code is saturated, as before. Else the white level less its noise
    margin (:func:`white_margin`): every code at or above it is saturated.
    """
    top = 2 ** int(bit_depth) - 1
    if level is None or int(level) >= top:
        return top
    return max(int(level) - white_margin(bit_depth), 1)


LONGEST_TARGET_EXPOSURES = 3
"""Exposures of each calibration target's RGB series (the longest) searched for a pile-up."""


class CameraWhiteLevel(NamedTuple):
    """One RGB camera's white level and where it comes from (:func:`camera_white_levels`)."""

    level: int
    """The white level [DN]; the top code when there is none under it."""
    saturation: int
    """The first saturated code [DN] (:func:`saturation_code`)."""
    source: str
    """``"declared"`` (capture.toml's ``rgb.white_level_dn``), ``"found"`` (a pile-up in the
    data) or ``"top code"`` (neither: only the top code is saturated)."""
    evidence: WhiteLevelEvidence | None
    """The pile-up of the channel the level was found in (``"found"`` only)."""


def _longest_frames(sample: xr.Dataset, targets: Sequence[xr.Dataset], camera: int) -> list[np.ndarray]:
    """A camera's longest exposures, one ``(values, channel)`` array per source: the last
    exposure of each of its images in ``sample`` (raw/rgb's, exposure times increasing), and
    the :data:`LONGEST_TARGET_EXPOSURES` longest of each target's RGB series of it.

    Each source apart: a pile-up is the largest code *of its source*, so codes of one source
    above another's pile-up (a scene unclipped to the top code beside targets that clip under
    it) do not hide it.
    """
    counts = sample["counts"].transpose("image", "exposure", "y", "x", "channel")
    own = np.flatnonzero(np.asarray(sample["camera"].values) == camera)
    longest = np.asarray(counts.isel(image=own, exposure=-1).values)
    channels = longest.shape[-1]
    parts = [longest.reshape(-1, channels)]
    for target in targets:
        rgb = target["rgb_counts"] if "rgb_counts" in target else None
        if rgb is None or "camera" not in rgb.dims or camera not in target["camera"].values:
            continue
        pos = [int(v) for v in target["camera"].values].index(camera)
        times = np.asarray(target["rgb_exposure_time"].isel(camera=pos).values, dtype=float)
        order = np.argsort(times)[-LONGEST_TARGET_EXPOSURES:]
        frames = np.asarray(
            rgb.isel(camera=pos, rgb_exposure=order)
            .transpose("rgb_exposure", "y", "x", "channel")
            .values
        )
        if frames.shape[-1] == channels:
            parts.append(frames.reshape(-1, channels))
    return parts


def camera_white_levels(
    sample: xr.Dataset, targets: Sequence[xr.Dataset], bit_depth: int
) -> dict[int, CameraWhiteLevel]:
    """Each RGB camera's white level: declared, else found in its longest exposures.

    ``sample`` is raw/rgb (or the images of it the response is recovered from) with its attrs;
    its ``white_level_dn`` (one per camera, ``-1``: not given), from capture.toml's
    ``rgb.white_level_dn``, decides where given. Else :func:`white_level` per channel of the
    camera's longest exposures, each source apart (:func:`_longest_frames`: the scene's and
    each calibration target's), the lowest level found over the channels and sources (a
    channel or source that never reaches it shows none).

    Returns
    -------
    dict
        ``{camera: CameraWhiteLevel}`` for every camera of ``sample``.
    """
    top = 2 ** int(bit_depth) - 1
    declared = [int(v) for v in (sample.attrs.get("white_level_dn") or [])]
    out: dict[int, CameraWhiteLevel] = {}
    for camera in np.unique(np.asarray(sample["camera"].values)).tolist():
        camera = int(camera)
        if camera < len(declared) and declared[camera] >= 0:
            level = min(declared[camera], top)
            out[camera] = CameraWhiteLevel(level, saturation_code(level, bit_depth), "declared", None)
            continue
        found = [
            (lvl, ev)
            for codes in _longest_frames(sample, targets, camera)
            for lvl, ev in (white_level(codes[:, k], bit_depth) for k in range(codes.shape[-1]))
            if lvl is not None
        ]
        if not found:
            out[camera] = CameraWhiteLevel(top, top, "top code", None)
            continue
        level, evidence = min(found, key=lambda item: item[0])
        out[camera] = CameraWhiteLevel(level, saturation_code(level, bit_depth), "found", evidence)
    return out


def white_level_variables(
    whites: Mapping[int, CameraWhiteLevel], cameras: Sequence[int]
) -> dict[str, xr.DataArray]:
    """``white_level`` and ``saturation`` over ``camera`` [DN] (in the order ``cameras``) for
    the group ``calibration/oecf_rgb``: the HDR merge and the calibration targets' series
    weight each camera's codes with its own."""
    dn = {"units": "DN"}
    return {
        "white_level": xr.DataArray(
            np.array([whites[c].level for c in cameras], dtype=np.int64),
            dims="camera",
            attrs={
                **dn,
                "long_name": "code the camera's raw values clip at (the top code: none below it)",
            },
        ),
        "saturation": xr.DataArray(
            np.array([whites[c].saturation for c in cameras], dtype=np.int64),
            dims="camera",
            attrs={**dn, "long_name": "saturation: codes at or above it are saturated (weight 0)"},
        ),
    }
