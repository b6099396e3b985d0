"""Band-filtered shots of the spectral camera: the first step of everything spectral.

- :func:`band_signal`: dark-subtracted, linearised (OECF) signal per second of exposure of
  band-filtered frames (eq. 5 solved for ``x Q``).
- :func:`longest_unsaturated_shots`: from a calibration target's (wavelength, exposure)
  series, one shot per band, the longest exposure without a saturated pixel.
- :func:`checked_shots`, :func:`dark_for_shots`, :func:`linearise`, :func:`shot_levels`,
  :func:`saturated_by_band`, :func:`band_batches`, :func:`series_pieces`,
  :func:`computed_in_batches`: the pieces
  :mod:`~.white_reference` and :mod:`~.cross_validation` share.

References
----------
Fast Capture of Spectral Image Series, section 4 ("Calibration"), eq. 5 and Fig. 2.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import dask
import numpy as np
import xarray as xr

from spectralize.nodes.calibration import exposure_series
from spectralize.nodes.calibration.dark import dark_frames_at
from spectralize.nodes.calibration.exposure_series import (
    frame_chunks,
    saturated_frames,
    target_spectral_series,
)
from spectralize.nodes.calibration.oecf.response import apply_response
from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "band_signal",
    "checked_shots",
    "dark_for_shots",
    "linearise",
    "shot_levels",
    "computed_in_batches",
    "band_batches",
    "series_pieces",
    "saturated_by_band",
    "longest_unsaturated",
    "shot_frames",
    "longest_unsaturated_shots",
]


def checked_shots(data: xr.Dataset | xr.DataArray, where: str) -> xr.DataArray:
    """The ``counts`` (shot, y, x) of band shots, checked against the raw/spectral contract.

    Raises
    ------
    SchemaError
        Not one variable (shot, y, x) with coords ``exposure_time`` and ``wavelength`` over
        ``shot``, every problem listed.
    CalibrationError
        An exposure time that is not positive and finite.
    """
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


def dark_for_shots(
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
    # one frame of a large sensor, thousands of small ones): no (shot, y, x) copy of the
    # dark frames is made, and a run of small frames is not one piece per shot
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
    counts = checked_shots(shots, where)
    mean, _ = dark_for_shots(dark, counts, where)
    return linearise(counts, mean, response, where)


def linearise(
    counts: xr.DataArray, mean: xr.DataArray, response: xr.Dataset | xr.DataArray | None, where: str
) -> xr.DataArray:
    """``f(I - dark) / t`` (or ``(f(I) - f(dark)) / t``) of shots ``counts`` and their dark
    frames ``mean``, as :func:`band_signal` describes; raises :class:`CalibrationError` for a
    response that is not monochrome (code,)."""
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


def shot_levels(signal: xr.DataArray) -> np.ndarray:
    """(shot,) mean linearised level ``f(I - dark)`` of band shots, from :func:`band_signal`."""
    return np.asarray((signal * signal["exposure_time"]).mean(("y", "x")).values, dtype=np.float64)


def computed_in_batches(arrays: Sequence[xr.DataArray], batches: Sequence[slice]) -> list[xr.DataArray]:
    """``arrays`` (one per band) computed, those of each batch of ``batches``
    (:func:`band_batches`) in one computation: a batch's reads and reductions are done before
    the next batch's are read; each array's numbers are those of its own computation."""
    out: list[xr.DataArray] = []
    for part in batches:
        out.extend(dask.compute(*arrays[part]))
    return out


def shot_frames(counts: xr.DataArray, picks: np.ndarray, depth: int, group: str) -> xr.DataArray:
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


def band_batches(counts: xr.DataArray, dim: str = "wavelength") -> list[slice]:
    """The bands of a (wavelength, ...) series that are read and reduced together: as many
    whole bands (every frame of each) as fit in
    :data:`~spectralize.nodes.calibration.exposure_series.FRAME_CHUNK_BYTES` as float64, at
    least one. A large sensor's series goes one band at a time (one computation over the
    series would read the stored tiles of every band ahead of their reductions, which split
    each tile into its exposures' frames); the bands of small frames go in one computation
    instead of one each (a computation's scheduling costs more than reducing a small band).
    ``dim``: the series' band dim (``"shot"`` for band shots, one per band).
    """
    per_band = 8 * math.prod(size for name, size in counts.sizes.items() if name != dim)
    step = max(1, exposure_series.FRAME_CHUNK_BYTES // max(per_band, 1))
    n = counts.sizes[dim]
    return [slice(start, min(start + step, n)) for start in range(0, n, step)]


def series_pieces(
    counts: xr.DataArray, exposures: Sequence[int]
) -> Iterator[tuple[slice, list[int], xr.DataArray]]:
    """The frames ``exposures`` of a (wavelength, spectral_exposure, y, x) series, in pieces
    that vectorised reductions take whole.

    Each batch of :func:`band_batches` is read in one computation; its frames are handed out
    as many exposures at a time as fit in
    :data:`~spectralize.nodes.calibration.exposure_series.FRAME_CHUNK_BYTES` as float64 over
    the batch's bands (at least one): a small sensor's whole series at once, a large one's
    one frame at a time (a band's series and one float64 frame in memory).

    Yields
    ------
    tuple
        ``(bands, positions, shots)``: the batch's band slice, the positions in
        ``exposures`` of the piece's exposures and their frames (wavelength,
        spectral_exposure, y, x), in memory, without coords but ``exposure_time`` [s] over
        ``spectral_exposure``.
    """
    times = np.asarray(counts["spectral_exposure_time"].values, dtype=np.float64)
    picks = [int(e) for e in exposures]
    frame = 8 * counts.sizes["y"] * counts.sizes["x"]
    for bands in band_batches(counts):
        series = counts.isel(wavelength=bands).drop_vars(list(counts.coords)).load()
        per_piece = exposure_series.FRAME_CHUNK_BYTES // (frame * series.sizes["wavelength"])
        step = max(1, per_piece)
        for start in range(0, len(picks), step):
            positions = list(range(start, min(start + step, len(picks))))
            chosen = [picks[i] for i in positions]
            shots = series.isel(spectral_exposure=chosen).assign_coords(
                exposure_time=("spectral_exposure", times[chosen])
            )
            yield bands, positions, shots


def saturated_by_band(counts: xr.DataArray, depth: int) -> np.ndarray:
    """:func:`~.saturated_frames` of a (wavelength, exposure, y, x) series, the bands of each
    of :func:`band_batches` in one computation: the frames of a batch are read and reduced
    before the next batch's."""
    return np.concatenate(
        [saturated_frames(counts.isel(wavelength=part), depth) for part in band_batches(counts)]
    )


def longest_unsaturated(counts: xr.DataArray, depth: int, group: str) -> np.ndarray:
    """Per band, the index of the longest exposure without a saturated pixel."""
    top = ~saturated_by_band(counts, depth)  # (wavelength, exp)
    bad = np.flatnonzero(~top.any(axis=1))
    if bad.size:
        wl = counts["wavelength"].values[bad].tolist()
        raise CalibrationError(
            f"{group}:spectral_counts: every exposure of band(s) {wl} nm has saturated pixels "
            f"(value {2**depth - 1}); add shorter exposures"
        )
    return np.asarray([int(np.flatnonzero(row)[-1]) for row in top])


def longest_unsaturated_shots(target: xr.Dataset, group: str) -> tuple[xr.DataArray, int, xr.DataArray]:
    """A calibration target's band series and, per band, its longest unsaturated exposure.

    Returns
    -------
    tuple
        The (wavelength, spectral_exposure, y, x) series and its bit depth
        (:func:`~.target_spectral_series`), and
        the (shot, y, x) band shots of :func:`shot_frames`, one per band.

    Raises
    ------
    CalibrationError
        A band saturated at every exposure (:func:`longest_unsaturated`), naming the group.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4.
    """
    counts, depth = target_spectral_series(target, group)
    picks = longest_unsaturated(counts, depth, group)
    return counts, depth, shot_frames(counts, picks, depth, group)
