"""Registration of the spectral camera to the RGB camera it pairs with (paper sec. 3, 4).

The spectral camera sits at 45 degrees, 15 degrees in azimuth from the RGB camera at the
same elevation, and the sample rotates in 15 degree steps: after rotation ``r + 1`` the
spectral camera sees what the RGB camera saw at rotation ``r``. What is left is a small,
fixed misregistration, estimated once per run from long-exposure registration shots (many
LEDs on, good SNR), and applied to every band shot: an integer search for the shift at which
a mix of the RGB channels best explains the band shot, then sub-pixel phase correlation
against that mix. The result is checked (:func:`registration_warnings`): a wrong correlation
peak, a periodic target's ambiguity, rotation pairs that disagree.

Convention: ``spectral(p) = rgb(p - shift)``; registering a spectral frame means resampling
it at ``p + shift``.
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.schemas import SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "estimate_shift",
    "channel_mix_search",
    "estimate_pair_shift",
    "pair_rotations",
    "estimate_registration",
    "registration_warnings",
    "register_frames",
]

PEAK_DISTANCE_WARNING = 1.5
"""A pair's sub-pixel shift more than this many pixels [px] from the integer shift of its
channel mix search (farther than a neighbouring integer shift) lies on another correlation
peak than the best channel mix's: warned."""

ALIAS_DISTANCE_WARNING = 1.5
"""A pair whose lowest unexplained share over the whole search lies more than this many
pixels [px] from the (nearest) minimum taken is ambiguous, a periodic target: warned."""

PAIR_SPREAD_WARNING = 1.0
"""A pair's shift more than this many pixels [px] from the run's shift: the pairs disagree."""


def estimate_shift(
    reference: np.ndarray, moving: np.ndarray, *, upsample_factor: int = 50, refinements: int = 2
) -> tuple[np.ndarray, float]:
    """Sub-pixel translation of ``moving`` relative to ``reference`` by phase correlation.

    Both images are made zero-mean and Hann-windowed, so their different brightness and the
    image borders do not disturb the peak, and the cross-power spectrum is phase-normalised
    (classic phase correlation), which weighs edges over the materials' different contrast in
    one band and in RGB. The two shots differ in band and in lighting (the LEDs do not rotate
    with the sample), which limits any intensity-based method. The paper's
    Gaussian filters make the reconstruction robust to such sub-pixel residuals. The window
    pulls the estimate towards zero for larger shifts, so the estimate is refined: ``moving``
    is shifted back by what was found and the (now small) remainder estimated again,
    ``refinements`` times.

    Parameters
    ----------
    reference, moving
        2-D images of equal shape.
    upsample_factor
        Precision of the estimate: 1/upsample_factor px (upsampled DFT around the peak).
    refinements
        Extra estimates on the back-shifted image.

    Returns
    -------
    shift : ndarray, shape (2,)
        (dy, dx) in px with ``moving(p) = reference(p - shift)``.
    error : float
        Phase-correlation error (0: perfect match, 1: no match).

    Raises
    ------
    SchemaError
        Images of different shapes or not 2-D.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 and 4 (registration shots).
    .. [2] M. Guizar-Sicairos, S. T. Thurman, J. R. Fienup, "Efficient subpixel image
       registration algorithms", Optics Letters 33(2), 2008 (upsampled DFT).
    """
    from scipy import ndimage
    from skimage.filters import window
    from skimage.registration import phase_cross_correlation

    if reference.shape != moving.shape or reference.ndim != 2:
        raise SchemaError(
            "cannot estimate a shift:",
            [Problem("moving", f"a 2-D image of shape {reference.shape}", f"shape {moving.shape}")],
        )
    hann = window("hann", reference.shape)
    ref = (reference - reference.mean()) * hann
    total = np.zeros(2)
    error = 1.0
    current = np.asarray(moving, dtype=float)
    for _ in range(1 + refinements):
        mov = (current - current.mean()) * hann
        found, error, _ = phase_cross_correlation(
            ref, mov, upsample_factor=upsample_factor, normalization="phase"
        )
        # skimage returns the shift registering `moving` onto `reference`: minus ours
        total -= np.asarray(found, dtype=float)
        current = ndimage.shift(np.asarray(moving, dtype=float), -total, order=3, mode="nearest")
    return total, float(error)


def _window_sums(image: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Sum of ``image`` over the window of ``shape`` at every offset that fits (summed-area
    table)."""
    table = np.zeros((image.shape[0] + 1, image.shape[1] + 1))
    table[1:, 1:] = image.cumsum(axis=0).cumsum(axis=1)
    h, w = shape
    return table[h:, w:] - table[:-h, w:] - table[h:, :-w] + table[:-h, :-w]


def _window_correlations(values: np.ndarray, channels: np.ndarray) -> np.ndarray:
    """(channel, offset y, offset x): ``sum_p channels_k(p) values(p + offset)`` for every
    offset at which the (k, h, w) ``channels`` fit inside ``values`` (one FFT of ``values``;
    the circular correlation does not wrap at these offsets)."""
    from scipy import fft

    height, width = values.shape
    h, w = channels.shape[1:]
    spectrum = fft.rfft2(values)
    kernels = fft.rfft2(channels, s=(height, width), axes=(1, 2))
    full = fft.irfft2(spectrum * kernels.conj(), s=(height, width), axes=(1, 2))
    return full[:, : height - h + 1, : width - w + 1]


def _nearest_minimum(unexplained: np.ndarray) -> tuple[int, int]:
    """Index of the lowest value of the smallest window about the centre (zero shift) whose
    lowest value is not on its edge (the whole map's lowest if no window has one inside)."""
    centre = (unexplained.shape[0] - 1) // 2
    for radius in range(1, centre + 1):
        window = unexplained[
            centre - radius : centre + radius + 1, centre - radius : centre + radius + 1
        ]
        wy, wx = np.unravel_index(int(np.argmin(window)), window.shape)
        if 0 < wy < 2 * radius and 0 < wx < 2 * radius:
            return centre - radius + int(wy), centre - radius + int(wx)
    iy, ix = np.unravel_index(int(np.argmin(unexplained)), unexplained.shape)
    return int(iy), int(ix)


def channel_mix_search(
    reference: np.ndarray, moving: np.ndarray, *, max_shift: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Integer shift whose best linear mix of the reference channels explains ``moving`` best.

    A band shot is not the sum of the RGB channels: materials that are alike in RGB differ in
    one band, and on a periodic target (stripes, checks) such a change of contrast moves the
    phase-correlation peak by a period's fraction or onto a neighbouring period. For every
    integer shift ``s`` within ``max_shift`` the least-squares fit
    ``moving(p + s) = sum_c a_c rgb_c(p) + b`` over the reference's interior is solved (its
    residual from cross-correlations of ``moving`` with the centred channels, one FFT per
    channel for all shifts); the shift with the smallest unexplained share of the variance
    and its mix are returned. A periodic target explains the band about as well one period
    away; the misregistration is small, so the shift taken is the minimum nearest to zero:
    that of the smallest window around zero whose lowest value lies inside it, not on its
    edge (:func:`_nearest_minimum`).

    Parameters
    ----------
    reference
        (y, x, channel) image.
    moving
        (y, x) image of the same height and width.
    max_shift
        Largest shift searched [px] per axis (reduced where the image is too small).

    Returns
    -------
    shift : ndarray, shape (2,)
        Integer (dy, dx) with ``moving(p) = reference(p - shift)``.
    mix : ndarray, shape (channel,)
        The channel weights at that shift.
    unexplained : ndarray, shape (2 m + 1, 2 m + 1)
        Residual variance over the variance of ``moving`` per searched shift (m the margin).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 and 4 (registration shots).
    """
    height, width = moving.shape
    margin = max(int(min(np.ceil(max_shift), (min(height, width) - 8) // 4)), 0)
    inner = np.asarray(reference, dtype=np.float64)[margin : height - margin, margin : width - margin]
    channels = np.moveaxis(inner - inner.mean(axis=(0, 1)), -1, 0)  # centred: the constant apart
    gram = np.einsum("kyx,lyx->kl", channels, channels)
    eigenvalues, vectors = np.linalg.eigh(gram)
    keep = eigenvalues > eigenvalues.max() * 1e-12  # collinear channels count once
    whiten = vectors[:, keep] / np.sqrt(eigenvalues[keep])
    values = np.asarray(moving, dtype=np.float64)
    values = values - values.mean()
    count = inner.shape[0] * inner.shape[1]
    total = _window_sums(values, inner.shape[:2])
    variance = _window_sums(values**2, inner.shape[:2]) - total**2 / count
    variance = np.maximum(variance, np.finfo(float).tiny)
    correlations = _window_correlations(values, channels)
    explained = (np.einsum("kj,kyx->jyx", whiten, correlations) ** 2).sum(axis=0)
    unexplained = np.clip(1.0 - explained / variance, 0.0, None)
    iy, ix = _nearest_minimum(unexplained)
    shift = np.array([iy - margin, ix - margin], dtype=float)
    mix = whiten @ (whiten.T @ correlations[:, iy, ix])
    return shift, mix, unexplained


def estimate_pair_shift(
    reference: np.ndarray, moving: np.ndarray, *, upsample_factor: int, max_shift: float
) -> tuple[np.ndarray, float, float, float]:
    """Shift of a spectral shot against its RGB shot: channel mix search, then phase correlation.

    :func:`channel_mix_search` finds the integer shift and the mix of the RGB channels that
    best explain the band; :func:`estimate_shift` of the band against that mix, started from
    the integer shift, gives the sub-pixel remainder.

    Parameters
    ----------
    reference
        (y, x, channel) RGB shot.
    moving
        (y, x) spectral shot.
    upsample_factor
        Sub-pixel precision 1/upsample_factor px.
    max_shift
        Largest shift searched [px].

    Returns
    -------
    shift : ndarray, shape (2,)
        (dy, dx) in px with ``moving(p) = reference(p - shift)``.
    unexplained : float
        Share of the band's variance the best channel mix leaves unexplained at the integer
        shift (0: a perfect fit).
    peak_distance : float
        Distance [px] of the sub-pixel shift from the integer shift: above
        :data:`PEAK_DISTANCE_WARNING` the correlation found another peak.
    alias_distance : float
        Distance [px] of the search's lowest value from the integer shift taken (0 when they
        are one): above :data:`ALIAS_DISTANCE_WARNING` the shift is ambiguous.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 and 4.
    """
    from scipy import ndimage

    coarse, mix, unexplained = channel_mix_search(reference, moving, max_shift=max_shift)
    mixed = np.asarray(reference, dtype=np.float64) @ mix
    started = ndimage.shift(np.asarray(moving, dtype=float), -coarse, order=0, mode="nearest")
    remainder, _ = estimate_shift(mixed, started, upsample_factor=upsample_factor)
    margin = (unexplained.shape[0] - 1) // 2
    lowest = np.asarray(np.unravel_index(int(np.argmin(unexplained)), unexplained.shape)) - margin
    return (
        coarse + remainder,
        float(unexplained[int(coarse[0]) + margin, int(coarse[1]) + margin]),
        float(np.linalg.norm(remainder)),
        float(np.linalg.norm(lowest - coarse)),
    )


def pair_rotations(
    rotation_angle: np.ndarray, *, azimuth_offset: float = 15.0, tolerance: float = 1e-3
) -> list[tuple[int, int]]:
    """Pairs (rgb rotation index, spectral rotation index) that see the same content.

    The spectral camera at rotation angle ``a + azimuth_offset`` sees what the RGB camera saw
    at ``a`` (angles modulo 360).

    Parameters
    ----------
    rotation_angle
        Sample rotation per rotation step [degree].
    azimuth_offset
        Azimuth between the spectral camera and its RGB camera [degree].
    tolerance
        Largest angle difference accepted as the same rotation [degree].

    Returns
    -------
    list of tuple of int
        ``(rgb index, spectral index)`` per pair.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (gantry, 15 degree steps).
    """
    angles = np.asarray(rotation_angle, dtype=float) % 360.0
    pairs = []
    for i, angle in enumerate(angles):
        target = (angle + azimuth_offset) % 360.0
        distance = np.abs((angles - target + 180.0) % 360.0 - 180.0)
        j = int(np.argmin(distance))
        if distance[j] <= tolerance:
            pairs.append((i, j))
    return pairs


def estimate_registration(
    registration: xr.Dataset,
    *,
    azimuth_offset: Annotated[
        float, Field(description="azimuth between the spectral camera and its RGB camera [degree]")
    ] = 15.0,
    upsample_factor: Annotated[
        int, Field(ge=1, le=1000, description="1/precision of the shift [px]")
    ] = 50,
    max_shift: Annotated[float, Field(gt=0, description="largest plausible misregistration [px]")] = 8.0,
) -> xr.Dataset:
    """Estimate the fixed misregistration of the spectral camera from registration shots.

    Every pair of a spectral shot at rotation ``r + 1`` and the RGB shot at rotation ``r``
    (:func:`pair_rotations`) gives one estimate (:func:`estimate_pair_shift`: against the mix
    of the RGB channels that best explains the band, not their sum); the run's shift is their
    median and the residual is each pair's distance from it. :func:`registration_warnings`
    checks the result.

    Parameters
    ----------
    registration
        Group ``raw/registration``: ``rgb_counts`` (rotation, y, x, channel) and
        ``spectral_counts`` (rotation, y, x), coord ``rotation_angle`` [degree].
    azimuth_offset
        Azimuth between the spectral camera and the RGB camera it pairs with [degree].
    upsample_factor
        Sub-pixel precision 1/upsample_factor px.
    max_shift
        Largest shift searched; pairs whose estimate exceeds this many pixels are reported
        as failed.

    Returns
    -------
    xarray.Dataset
        Group ``registration``: ``shift`` (axis) [px], ``pair_shift`` (pair, axis) [px],
        ``residual`` (pair) [px], ``unexplained`` (pair), ``peak_distance`` (pair) [px],
        ``alias_distance`` (pair) [px], ``plausible`` (pair), ``rgb_rotation`` /
        ``spectral_rotation`` (pair).

    Raises
    ------
    SchemaError
        No pair of rotations sees the same content, or no pair gives a plausible shift.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 and 4.
    """
    pairs = pair_rotations(registration["rotation_angle"].values, azimuth_offset=azimuth_offset)
    if not pairs:
        angles = registration["rotation_angle"].values.tolist()
        raise SchemaError(
            "cannot estimate the registration:",
            [
                Problem(
                    "raw/registration:rotation_angle",
                    f"two rotations {azimuth_offset:g} degree apart (spectral after RGB)",
                    f"angles {angles}",
                )
            ],
        )
    rgb = registration["rgb_counts"]
    spectral = registration["spectral_counts"]
    shifts, unexplained, peak_distance, alias_distance = [], [], [], []
    for i, j in pairs:
        reference = rgb.isel(rotation=i).transpose("y", "x", "channel").astype(np.float64).values
        moving = spectral.isel(rotation=j).astype(np.float64).values
        shift, share, distance, alias = estimate_pair_shift(
            reference, moving, upsample_factor=upsample_factor, max_shift=max_shift
        )
        shifts.append(shift)
        unexplained.append(share)
        peak_distance.append(distance)
        alias_distance.append(alias)
    shifts_arr = np.asarray(shifts)
    plausible = np.all(np.abs(shifts_arr) <= max_shift, axis=1)
    if not plausible.any():
        raise SchemaError(
            "cannot estimate the registration:",
            [
                Problem(
                    "raw/registration",
                    f"shifts within {max_shift:g} px",
                    f"shifts {shifts_arr.round(2).tolist()} (do the shots show the same content?)",
                )
            ],
        )
    combined = np.median(shifts_arr[plausible], axis=0)
    residual = np.linalg.norm(shifts_arr - combined, axis=1)
    px = {"units": "px"}
    return xr.Dataset(
        {
            "shift": (
                "axis",
                combined,
                {**px, "long_name": "misregistration: spectral(p) = rgb(p - shift)"},
            ),
            "pair_shift": (("pair", "axis"), shifts_arr, {**px, "long_name": "shift per pair"}),
            "residual": (
                "pair",
                residual,
                {**px, "long_name": "distance of a pair's shift from the run's shift"},
            ),
            "unexplained": (
                "pair",
                np.asarray(unexplained),
                {"units": "1", "long_name": "band variance the best RGB channel mix leaves"},
            ),
            "peak_distance": (
                "pair",
                np.asarray(peak_distance),
                {**px, "long_name": "sub-pixel shift's distance from the channel mix search's"},
            ),
            "alias_distance": (
                "pair",
                np.asarray(alias_distance),
                {**px, "long_name": "distance of the search's lowest value from the shift taken"},
            ),
            "plausible": ("pair", plausible, {"long_name": f"shift within {max_shift:g} px"}),
        },
        coords={
            "axis": ("axis", np.array(["y", "x"], dtype=object)),
            "rgb_rotation": ("pair", np.array([registration["rotation"].values[i] for i, _ in pairs])),
            "spectral_rotation": (
                "pair",
                np.array([registration["rotation"].values[j] for _, j in pairs]),
            ),
        },
        attrs={
            "method": "channel mix search, then phase correlation (scikit-image) against the "
            "mix, Hann window, refined, median over pairs",
            "upsample_factor": upsample_factor,
            "azimuth_offset": azimuth_offset,
            "residual_rms": float(np.sqrt(np.mean(residual[plausible] ** 2))),
        },
    )


def registration_warnings(registration: xr.Dataset) -> list[str]:
    """The warnings on a ``registration`` group: what makes its shift untrustworthy.

    A pair whose sub-pixel shift left its channel mix search's integer shift by more than
    :data:`PEAK_DISTANCE_WARNING` found another correlation peak (a periodic target, a band
    whose contrast no channel mix gives); a pair whose search has its lowest value farther
    than :data:`ALIAS_DISTANCE_WARNING` from the shift taken is ambiguous; pairs that
    disagree with the run's shift by more than :data:`PAIR_SPREAD_WARNING`, or give no
    plausible shift, see different content.

    Parameters
    ----------
    registration
        Group ``registration`` (:func:`estimate_registration`).

    Returns
    -------
    list of str
        One message per kind of problem, with the pairs and the numbers.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 and 4.
    """
    labels = [
        f"{a}->{b}"
        for a, b in zip(
            registration["rgb_rotation"].values.tolist(),
            registration["spectral_rotation"].values.tolist(),
            strict=True,
        )
    ]
    out = []
    if "peak_distance" in registration:
        far = np.asarray(registration["peak_distance"].values, dtype=float)
        bad = [f"{labels[k]} {far[k]:.2f} px" for k in np.flatnonzero(far > PEAK_DISTANCE_WARNING)]
        if bad:
            out.append(
                f"registration: the phase-correlation peak lies more than "
                f"{PEAK_DISTANCE_WARNING:g} px from the best channel mix's shift in pair(s) "
                f"{', '.join(bad)} (a periodic target or a band no RGB mix resembles): the "
                "shift may be a wrong peak"
            )
    if "alias_distance" in registration:
        alias = np.asarray(registration["alias_distance"].values, dtype=float)
        bad = [f"{labels[k]} {alias[k]:.2f} px" for k in np.flatnonzero(alias > ALIAS_DISTANCE_WARNING)]
        if bad:
            out.append(
                "registration: another shift explains the band as well or better, in pair(s) "
                f"{', '.join(bad)} away from the one taken (a periodic target): the nearest "
                "to zero was taken, the shift may be off by a period"
            )
    plausible = np.asarray(registration["plausible"].values, dtype=bool)
    residual = np.asarray(registration["residual"].values, dtype=float)
    spread = [
        f"{labels[k]} {residual[k]:.2f} px"
        for k in np.flatnonzero(plausible & (residual > PAIR_SPREAD_WARNING))
    ]
    if spread:
        out.append(
            f"registration: pair(s) {', '.join(spread)} from the run's shift (more than "
            f"{PAIR_SPREAD_WARNING:g} px): the rotation pairs disagree"
        )
    if not plausible.all():
        failed = [labels[k] for k in np.flatnonzero(~plausible)]
        out.append(f"registration: no plausible shift in pair(s) {', '.join(failed)}")
    return out


def _shift_frames(frames: np.ndarray, shift: tuple[float, float], order: int) -> np.ndarray:
    from scipy import ndimage

    out = np.empty_like(frames, dtype=np.float32)
    for index in np.ndindex(frames.shape[:-2]):
        # registered(p) = spectral(p + shift): ndimage.shift(x, t)(p) = x(p - t) with t = -shift
        out[index] = ndimage.shift(
            frames[index].astype(np.float32), (-shift[0], -shift[1]), order=order, mode="nearest"
        )
    return out


def register_frames(frames: xr.DataArray, shift: xr.DataArray, *, order: int = 1) -> xr.DataArray:
    """Resample spectral frames onto the RGB pixel grid, lazily per chunk.

    Parameters
    ----------
    frames
        Spectral frames with trailing dims (y, x), e.g. band radiance (shot, y, x).
    shift
        ``shift`` (axis) [px] from :func:`estimate_registration`.
    order
        Spline order of the resampling (1: bilinear; it slightly smooths the noise, which the
        reconstruction's Gaussian filters do anyway).

    Returns
    -------
    xarray.DataArray
        float32 frames with ``registered(p) = frames(p + shift)``; border pixels repeat the
        nearest valid pixel.

    Raises
    ------
    SchemaError
        Frames whose trailing dims are not (y, x).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4.
    """
    dy, dx = (float(shift.sel(axis=a)) for a in ("y", "x"))
    if tuple(frames.dims[-2:]) != ("y", "x"):
        raise SchemaError(
            "cannot register frames:",
            [Problem(frames.name or "frames", "trailing dims ('y', 'x')", f"dims {frames.dims}")],
        )
    out = xr.apply_ufunc(
        _shift_frames,
        frames,
        kwargs={"shift": (dy, dx), "order": order},
        input_core_dims=[["y", "x"]],
        output_core_dims=[["y", "x"]],
        dask="parallelized",
        output_dtypes=[np.float32],
    )
    return out.assign_attrs({**frames.attrs, "registration_shift_px": [dy, dx]})
