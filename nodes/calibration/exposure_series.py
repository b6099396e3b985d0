"""Checks shared by every method that reads an exposure series (paper section 4).

Robertson's recovery, its low-SNR extension, the HDR merge and the calibration nodes all read
series of integer frames taken at several exposure times. What makes such a series usable is
checked here, once:

- :func:`check_bit_depth`: the ADC bit depth, an integer in 8..16 (eq. 5 clamps to it);
- :func:`check_integer`: raw pixel values are integers (DN);
- :func:`check_exposure_times`: positive, finite and strictly increasing along the series;
- :func:`warn_if_geometric`: equal exposure-time ratios leave the response ambiguous;
- :func:`frame_extremes`, :func:`frame_flags`, :func:`check_frames`: frames entirely saturated
  or entirely dark carry no information;
- :func:`saturated_frames`: frames with at least one pixel at the ADC's maximum code;
- :func:`target_spectral_series`: the per-band exposure series of a calibration target,
  lazy in chunks of one frame (:func:`frame_chunks`);
- :func:`refused`, :func:`raise_first`, :func:`target_series_refusals`: the checks as the
  nodes' value checks (``Node.check``) return them, and as the node functions raise them.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("Calibration") and eq. 5.
.. [2] M. D. Grossberg, S. K. Nayar, "Determining the camera response from images: what is
   knowable?", IEEE TPAMI 25(11), 2003.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence

import dask
import numpy as np
import xarray as xr

from spectralize.schemas import CalibrationError, SchemaError, SpectralizeError
from spectralize.schemas.errors import Problem

__all__ = [
    "check_bit_depth",
    "counts_array",
    "check_integer",
    "check_exposure_times",
    "warn_if_geometric",
    "frame_extremes",
    "frame_flags",
    "raise_for_frames",
    "check_frames",
    "saturated_frames",
    "target_spectral_series",
    "frame_chunks",
    "refused",
    "raise_first",
    "target_series_refusals",
]

_LISTED = 5  # problems listed one by one in an error; the rest are counted


def check_bit_depth(value: object, *, where: str) -> int:
    """The ADC bit depth ``value`` as an int, or a :class:`SchemaError` naming ``where``.

    Parameters
    ----------
    value
        ``attrs["bit_depth"]`` (or a keyword argument); ``None`` when it is unknown.
    where
        The array or attribute it belongs to, e.g. ``"raw/rgb.attrs['bit_depth']"``.

    Returns
    -------
    int
        The bit depth, 8..16.

    Raises
    ------
    SchemaError
        When the bit depth is unknown, not an integer, or outside 8..16.
    """
    if value is None:
        raise SchemaError(
            f"{where}: the bit depth is unknown",
            [
                Problem(
                    where,
                    "an ADC bit depth 8..16 (attrs['bit_depth'] or the keyword bit_depth=...)",
                    "nothing",
                )
            ],
        )
    try:
        depth = int(value)  # type: ignore[call-overload]
        ok = depth == value and 8 <= depth <= 16
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise SchemaError(
            f"{where}: the bit depth is invalid",
            [Problem(where, "an ADC bit depth, an integer in 8..16", repr(value))],
        )
    return depth


def counts_array(data: xr.Dataset | xr.DataArray, name: str = "counts") -> xr.DataArray:
    """Variable ``name`` of a Dataset (group attrs merged into its attrs), or the DataArray."""
    if isinstance(data, xr.Dataset):
        if name not in data.data_vars:
            raise SchemaError(
                "cannot use the exposure series:",
                [
                    Problem(
                        f"variable {name!r}",
                        "a data variable of the series",
                        f"variables {sorted(map(str, data.data_vars))}",
                    )
                ],
            )
        array = data[name]
        return array.assign_attrs({**data.attrs, **array.attrs})
    return data


def check_integer(counts: xr.DataArray, where: str) -> None:
    """Raise a :class:`SchemaError` unless the pixel values are integers (raw DN)."""
    if not np.issubdtype(counts.dtype, np.integer):
        raise SchemaError(
            f"{where}: pixel values must be integers (raw DN)",
            [Problem(where, "integer pixel values [DN]", f"dtype {counts.dtype}")],
        )


def check_exposure_times(times: xr.DataArray, series_dim: str, where: str) -> None:
    """Exposure times: positive, finite, strictly increasing along ``series_dim``.

    Raises
    ------
    CalibrationError
        Naming the unsorted or duplicate values, their positions and the fix.
    """
    ordered = times.transpose(..., series_dim)
    values = np.asarray(ordered.values, dtype=np.float64)
    bad = np.argwhere(~(np.isfinite(values) & (values > 0)))
    if bad.size:
        labels = [", ".join(f"{d}={i}" for d, i in zip(ordered.dims, at, strict=True)) for at in bad]
        found = [float(values[tuple(at)]) for at in bad]
        raise CalibrationError(
            f"{where}: exposure_time must be positive and finite; {len(bad)} value(s) are not, "
            f"the first at {labels[0]}: {found[0]:g} s. Fix the capture's exposure times",
            [
                Problem(f"{where}:exposure_time[{label}]", "a positive, finite time [s]", f"{value:g}")
                for label, value in zip(labels[:_LISTED], found[:_LISTED], strict=True)
            ]
            + ([f"... and {len(bad) - _LISTED} more"] if len(bad) > _LISTED else []),
        )
    rows = values.reshape(-1, values.shape[-1])
    for row_index, row in enumerate(rows):
        steps = np.diff(row)
        if np.any(steps <= 0):
            bad = int(np.argmax(steps <= 0))
            label = f" (image {row_index})" if rows.shape[0] > 1 else ""
            kind = "duplicate" if steps[bad] == 0 else "unsorted"
            raise CalibrationError(
                f"{where}: exposure_time{label} must be strictly increasing along "
                f"{series_dim!r}; found {kind} values {row[bad]} then {row[bad + 1]} at "
                f"positions {bad}, {bad + 1} of {row.tolist()}; sort the series by exposure "
                "time (e.g. ds.sortby('exposure_time')) and drop repeated exposures"
            )


def warn_if_geometric(times: xr.DataArray, series_dim: str, where: str) -> None:
    """Warn when every exposure-time ratio is the same (response not identifiable [2]_)."""
    values = np.asarray(times.transpose(..., series_dim).values, dtype=np.float64)
    rows = values.reshape(-1, values.shape[-1])
    ratios = np.unique(np.round(np.log(rows[:, 1:] / rows[:, :-1]), 2))
    if ratios.size == 1:
        warnings.warn(
            f"{where}: every exposure-time ratio is {math.exp(ratios[0]):.3g}; the response is "
            "then determined only up to a factor periodic in log exposure (Grossberg & Nayar "
            "2003) and only noise decides it. Use exposure times with unequal ratios "
            "(e.g. 1, 3, 8, 25, 60) or several series with different ratios",
            RuntimeWarning,
            stacklevel=3,
        )


def frame_extremes(
    counts: xr.DataArray, pixel_dims: Sequence[str]
) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Smallest and largest value, and each frame's smallest and largest value.

    Returns
    -------
    tuple
        ``(lo, hi, frame_min, frame_max)``: the two arrays over the frame dims (the dims of
        ``counts`` not in ``pixel_dims``, in their order). One pass over the data (numpy or
        dask); thresholds are applied afterwards, so a data-dependent one costs no second pass.
    """
    pixel_dims = [d for d in counts.dims if d in pixel_dims]
    if counts.chunks is None:  # numpy: two reductions, no xarray/dask overhead
        axes = tuple(counts.get_axis_num(pixel_dims))
        # pixel dims last and flattened (one copy when they are not already last): numpy
        # reduces a contiguous last axis many times faster than axes in the middle
        values = np.ascontiguousarray(np.moveaxis(counts.values, axes, tuple(range(-len(axes), 0))))
        values = values.reshape(values.shape[: values.ndim - len(axes)] + (-1,))
        frame_min, frame_max = values.min(axis=-1), values.max(axis=-1)
    else:
        frame_min, frame_max = dask.compute(counts.min(pixel_dims).data, counts.max(pixel_dims).data)
    frame_min, frame_max = np.asarray(frame_min), np.asarray(frame_max)
    return int(frame_min.min()), int(frame_max.max()), frame_min, frame_max


def frame_flags(
    counts: xr.DataArray, pixel_dims: Sequence[str], *, black_level: float, saturation: float
) -> tuple[int, int, np.ndarray, np.ndarray]:
    """Smallest and largest value, and per frame whether it is not entirely saturated/dark.

    Returns
    -------
    tuple
        ``(lo, hi, not_saturated, not_dark)``: the two bool arrays over the frame dims (see
        :func:`frame_extremes`). A frame is entirely saturated when every value is
        ``>= saturation``, entirely dark when every value is ``<= black_level``.
    """
    lo, hi, frame_min, frame_max = frame_extremes(counts, pixel_dims)
    return lo, hi, frame_min < saturation, frame_max > black_level


def raise_for_frames(
    lo: int,
    hi: int,
    not_saturated: np.ndarray,
    not_dark: np.ndarray,
    *,
    frame_dims: Sequence[str],
    black_level: float,
    saturation: float,
    max_code: int,
    where: str,
    times: xr.DataArray | None = None,
) -> None:
    """Raise for values beyond the bit depth and frames entirely saturated or dark.

    The arguments are :func:`frame_flags`'s results; ``frame_dims`` names the axes of the
    flag arrays, ``times`` (over some of them) gives the exposure time in the message.
    """
    if lo < 0 or hi > max_code:
        raise CalibrationError(
            f"{where}: pixel values must lie in [0, {max_code}] for the bit "
            f"depth, found [{lo}, {hi}]; is bit_depth right?"
        )
    for flags, what, name, op, bound, expected, fix in (
        (not_saturated, "saturated", "saturation", ">=", saturation, "below", "shorter"),
        (not_dark, "dark", "black_level", "<=", black_level, "above", "longer"),
    ):
        bad = np.argwhere(~np.asarray(flags, dtype=bool))
        if not bad.size:
            continue
        problems: list[Problem | str] = []
        for at in bad[:_LISTED]:
            position = dict(zip(frame_dims, at.tolist(), strict=True))
            t = ""
            if times is not None:
                index = {k: v for k, v in position.items() if k in times.dims}
                t = f" (exposure_time {float(times.isel(index).values):g} s)"
            label = ", ".join(f"{k}={v}" for k, v in position.items())
            problems.append(
                Problem(
                    f"{where}[{label}]",
                    f"a frame with some values {expected} {name} = {bound}",
                    f"every value {op} {bound}{t}",
                )
            )
            if len(problems) == 1:
                first = f"frame {label}{t}"
        if len(bad) > _LISTED:
            problems.append(f"... and {len(bad) - _LISTED} more")
        raise CalibrationError(
            f"{where}: {first} is entirely {what} ({op} {name} = {bound}): it carries no "
            "information; "
            f"{len(bad)} such frame(s) in all. Use {fix} exposures (or drop these frames)",
            problems,
        )


def check_frames(
    counts: xr.DataArray,
    frame_dims: Sequence[str],
    *,
    black_level: float,
    saturation: float,
    max_code: int,
    where: str,
    times: xr.DataArray | None = None,
) -> None:
    """No value beyond the bit depth, no frame entirely saturated or entirely dark.

    Raises
    ------
    CalibrationError
        Naming the first such frame (its position and exposure time) and how many there are.
    """
    frame_dims = [d for d in counts.dims if d in frame_dims]
    pixel_dims = [d for d in counts.dims if d not in frame_dims]
    flags = frame_flags(counts, pixel_dims, black_level=black_level, saturation=saturation)
    raise_for_frames(
        *flags,
        frame_dims=frame_dims,
        black_level=black_level,
        saturation=saturation,
        max_code=max_code,
        where=where,
        times=times,
    )


def saturated_frames(
    counts: xr.DataArray, depth: int, pixel_dims: Sequence[str] = ("y", "x")
) -> np.ndarray:
    """Per frame, whether any pixel is at the ADC's maximum code ``2**depth - 1``.

    Returns
    -------
    numpy.ndarray
        bool over the dims of ``counts`` not in ``pixel_dims``, in their order.
    """
    return np.asarray(counts.max(tuple(pixel_dims)).values) >= 2**depth - 1


def target_spectral_series(target: xr.Dataset, group: str) -> tuple[xr.DataArray, int]:
    """``spectral_counts`` (wavelength, spectral_exposure, y, x) of a calibration target.

    Parameters
    ----------
    target
        Group ``raw/white_reference`` or ``raw/colour_checker`` (checked against its schema
        by the engine).
    group
        Its name, for messages.

    Returns
    -------
    tuple
        The counts, lazy (dask) in chunks of one frame (one band and exposure, the whole
        ``y``, ``x``), with coord ``spectral_exposure_time`` (float, [s]), and the spectral
        camera's bit depth (``attrs["spectral_bit_depth"]``, checked 8..16). Nothing is read
        here: the callers reduce the series chunk by chunk (per-frame means, maxima), so the
        memory a target series needs is a few frames, not bands x exposures x frame (at
        2048^2, gigabytes of uint16 for 32 bands and 13 exposures).
    """
    depth = check_bit_depth(
        target.attrs.get("spectral_bit_depth"), where=f"{group}.attrs['spectral_bit_depth']"
    )
    counts = target["spectral_counts"].transpose("wavelength", "spectral_exposure", "y", "x")
    counts = counts.assign_coords(
        spectral_exposure_time=(
            "spectral_exposure",
            np.asarray(target["spectral_exposure_time"].values, float),
        )
    )
    return frame_chunks(counts, ("wavelength", "spectral_exposure")), depth


FRAME_CHUNK_BYTES = 32 * 2**20
"""Float64 bytes of frames one chunk of :func:`frame_chunks` holds at most: one frame at
2048^2 px, thousands of small ones (a full run of 32 x 32 px frames in tens of tasks instead
of one per frame)."""


def frame_chunks(array: xr.DataArray, frame_dims: Sequence[str]) -> xr.DataArray:
    """``array`` as dask chunks of whole frames (whole ``y``, ``x``): as many frames along
    the first of ``frame_dims`` as fit in :data:`FRAME_CHUNK_BYTES` as float64 (at least
    one), 1 along the others.

    Numpy-backed input is wrapped without a copy; every computation on the result then
    holds a few frames at a time instead of the whole stack (a float64 stack of 32 bands at
    2048^2 is more than a node's memory budget).
    """
    dims = [d for d in frame_dims if d in array.dims]
    frame = 8 * math.prod(array.sizes[d] for d in array.dims if d not in dims)
    chunks: dict[str, int] = {d: 1 for d in dims}
    if dims:
        chunks[dims[0]] = max(1, FRAME_CHUNK_BYTES // max(frame, 1))
    chunks |= {d: -1 for d in ("y", "x") if d in array.dims}
    return array.chunk(chunks)


def refused(*checks: Callable[[], object]) -> list[SpectralizeError]:
    """Run each check; the errors they raise, in order (empty: every check passed)."""
    found: list[SpectralizeError] = []
    for check in checks:
        try:
            check()
        except SpectralizeError as error:
            found.append(error)
    return found


def raise_first(errors: Sequence[SpectralizeError]) -> None:
    """Raise the first of ``errors`` (a node function refusing what its value check found)."""
    if errors:
        raise errors[0]


def target_series_refusals(target: xr.Dataset, group: str, node: str) -> list[SpectralizeError]:
    """The exposure times of a calibration target's RGB and band series (paper section 4).

    ``rgb_exposure_time`` along ``rgb_exposure`` and ``spectral_exposure_time`` along
    ``spectral_exposure``, where the group has them: positive, finite and strictly increasing
    (:func:`check_exposure_times`), named ``"<node>: <group>"``.
    """
    where = f"{node}: {group}"
    return refused(
        *(
            lambda name=name, dim=dim: check_exposure_times(target[name].transpose(..., dim), dim, where)
            for name, dim in (
                ("rgb_exposure_time", "rgb_exposure"),
                ("spectral_exposure_time", "spectral_exposure"),
            )
            if name in target.variables
        )
    )
