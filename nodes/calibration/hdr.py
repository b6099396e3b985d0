"""HDR merge of RGB exposure series with a recovered response (Robertson et al. 2003).

For every pixel and channel the relative radiance is Robertson's maximum-likelihood estimate

``x = sum_t w(I_t) t f(I_t) / sum_t w(I_t) t^2``

over the exposures ``t`` of the series, with ``f`` the camera response (pixel value ->
relative exposure, :mod:`spectralize.nodes.calibration.oecf`) and ``w`` the weighting function, which is
0 for saturated and under-exposed samples. The merge runs blockwise over dask chunks of
``(image, y, x)``; a lazy input gives a lazy output.

References
----------
M. A. Robertson, S. Borman, R. L. Stevenson, "Estimation-theoretic approach to dynamic range
enhancement using multiple exposures", Journal of Electronic Imaging 12(2), 219-228, 2003.

Fast Capture of Spectral Image Series, sections 4 and 5 ("The RGB-LDR images are recombined
to form HDR images using Robertson's algorithm").
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import dask
import numpy as np
import xarray as xr

from spectralize.nodes.calibration.exposure_series import (
    check_bit_depth,
    check_exposure_times,
    raise_for_frames,
    refused,
)
from spectralize.nodes.calibration.flat_field_maps import FlatField
from spectralize.nodes.calibration.oecf.response import response_at_codes
from spectralize.nodes.calibration.oecf.weighting import Weighting, weighting_function
from spectralize.schemas import CalibrationError, SchemaError, SpectralizeError
from spectralize.schemas.errors import Problem

__all__ = [
    "merge_hdr",
    "merge_robertson",
    "merge_hdr_refusals",
    "camera_levels",
    "raise_for_camera_frames",
]

_DIMS = ("image", "exposure", "y", "x", "channel")


def merge_robertson(
    counts: np.ndarray,
    exposure_times: np.ndarray,
    response: np.ndarray,
    weights: np.ndarray,
    *,
    black_level: int | np.ndarray,
    saturation: int | np.ndarray,
) -> np.ndarray:
    """Robertson's radiance estimate for one block (numpy core).

    Parameters
    ----------
    counts
        Integer pixel values ``(..., exposure)``.
    exposure_times
        Exposure times [s], broadcastable to ``counts``.
    response
        ``f(code)`` with codes on the last axis, broadcastable to ``counts[..., :1]``.
    weights
        ``w(code)``: ``(n_codes,)``, or with codes on the last axis broadcastable to
        ``counts[..., :1]`` (one weighting per camera); 0 at saturated and under-exposed codes.
    black_level, saturation
        Codes ``<= black_level`` are under-exposed, codes ``>= saturation`` saturated [DN]:
        ints, or arrays broadcastable to ``counts[..., 0]`` (each image its camera's levels).

    Returns
    -------
    numpy.ndarray
        float32 relative radiance ``counts.shape[:-1]``. Where no sample has weight, the best
        bound: all saturated -> ``f(saturation) / t_min`` (a lower bound); all under-exposed
        -> ``f(black_level) / t_max`` (an upper bound); saturated in short exposures and
        dark in long ones cannot happen for a static scene, there the lower bound from the
        shortest saturated exposure is used.

    Notes
    -----
    Domain: integer codes ``0 .. n_codes-1``. Range: non-negative relative radiance for a
    non-negative response.

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003, eq. 7 (radiance estimate).
    """
    c = counts.astype(np.intp)
    t = np.broadcast_to(np.asarray(exposure_times, dtype=np.float64), c.shape)
    f = np.take_along_axis(response, c, axis=-1)
    weights = np.asarray(weights)
    w = weights[c] if weights.ndim == 1 else np.take_along_axis(weights, c, axis=-1)
    num = (w * t * f).sum(axis=-1)
    den = (w * t * t).sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = num / den
    missing = ~(den > 0)
    if missing.any():
        black = np.broadcast_to(np.asarray(black_level, dtype=np.intp), c.shape[:-1])
        sat = np.broadcast_to(np.asarray(saturation, dtype=np.intp), c.shape[:-1])
        saturated = c >= sat[..., None]
        t_sat = np.where(saturated, t, np.inf).min(axis=-1)
        t_dark = np.where(c <= black[..., None], t, 0.0).max(axis=-1)
        f_sat = np.take_along_axis(response, sat[..., None], axis=-1)[..., 0]
        f_dark = np.take_along_axis(response, np.maximum(black, 0)[..., None], axis=-1)[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = np.where(saturated.any(axis=-1), f_sat / t_sat, f_dark / t_dark)
        x = np.where(missing, bound, x)
    return x.astype(np.float32)


def _merge_block(
    counts: np.ndarray,
    exposure_times: np.ndarray,
    camera_index: np.ndarray,
    *,
    tables: np.ndarray,
    weights: np.ndarray,
    black_levels: np.ndarray,
    saturations: np.ndarray,
) -> np.ndarray:
    """:func:`merge_robertson` on a block ``(image, y, x, channel, exposure)`` whose images
    take their camera's response ``tables (camera, channel, code)``, weights
    ``(camera, code)`` and levels ``(camera,)``; ``camera_index`` (image, 1, 1, 1) is the
    row of each image's camera. The tables stay per camera (the block's images index them),
    so the memory does not grow with the image count."""
    index = np.asarray(camera_index).reshape(camera_index.shape[0], -1)[:, 0]
    return merge_robertson(
        counts,
        exposure_times,
        tables[index][:, None, None, :, :],
        weights[index][:, None, None, None, :],
        black_level=black_levels[index][:, None, None, None],
        saturation=saturations[index][:, None, None, None],
    )


BLOCK_BYTES = 4 * 2**20
"""Counts merged per task (whole images: at least one): smaller image chunks are joined up to
it, larger ones (a shard of a full run's small frames) split, so that a task's float64
temporaries stay a small multiple of it whatever the chunks read."""


def _image_block(counts: xr.DataArray) -> tuple[int, ...]:
    """Image chunks of ``counts`` joined or split to :data:`BLOCK_BYTES` (a chunk's whole
    frame only: frames split in y or x keep their chunks)."""
    chunks = dict(zip(counts.dims, counts.chunks or (), strict=True))
    image = chunks["image"]
    if any(len(chunks[d]) > 1 for d in ("y", "x")):
        return image
    per_image = counts.dtype.itemsize * counts.size // max(counts.sizes["image"], 1)
    most = max(1, BLOCK_BYTES // max(per_image, 1))
    joined: list[int] = []
    for size in image:
        if joined and joined[-1] + size <= most:
            joined[-1] += size
            continue
        while size > most:
            joined.append(most)
            size -= most
        if size:
            joined.append(size)
    return tuple(joined)


def _validate(raw: xr.Dataset, where: str) -> xr.DataArray:
    if not isinstance(raw, xr.Dataset) or "counts" not in raw.data_vars:
        found = sorted(map(str, raw.data_vars)) if isinstance(raw, xr.Dataset) else type(raw)
        raise SchemaError(
            f"{where}: raw/rgb breaks the contract",
            [Problem("raw/rgb:counts", "the raw/rgb group with variable 'counts'", str(found))],
        )
    counts = raw["counts"]
    problems = []
    if set(counts.dims) != set(_DIMS):
        problems.append(Problem("raw/rgb:counts", f"dims {_DIMS}", f"dims {counts.dims}"))
    if not np.issubdtype(counts.dtype, np.integer):
        problems.append(Problem("raw/rgb:counts", "integer DN", f"dtype {counts.dtype}"))
    if "exposure_time" not in raw.coords:
        problems.append(Problem("raw/rgb:exposure_time", "a coord (image, exposure) [s]", "nothing"))
    elif set(raw["exposure_time"].dims) != {"image", "exposure"}:
        problems.append(
            Problem(
                "raw/rgb:exposure_time", "dims (image, exposure)", f"dims {raw['exposure_time'].dims}"
            )
        )
    if problems:
        raise SchemaError(f"{where}: raw/rgb breaks the contract", problems)
    return counts.transpose(*_DIMS)


def _response_table(
    response: xr.Dataset | xr.DataArray, counts: xr.DataArray, n_codes: int, where: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The response at integer codes 0..n_codes-1 per camera, and each image's camera.

    Returns
    -------
    tuple
        ``(tables, index, cameras)``: ``tables`` (camera, channel, code) float64; ``index``
        (image,) the row of ``tables`` each image uses; ``cameras`` the camera labels of the
        rows (``None`` for a response without a ``camera`` dim: one row serves every image).
    """
    table = response["response"] if isinstance(response, xr.Dataset) else response
    if "code" not in table.dims or set(table.dims) - {"camera", "channel", "code"}:
        raise SchemaError(
            f"{where}: the response breaks the contract",
            [Problem("response", "dims ([camera,] [channel,] code)", f"dims {table.dims}")],
        )
    if table.attrs.get("dark_subtracted"):
        raise CalibrationError(
            f"{where}: the response is over dark-subtracted values (low-SNR/combined); the HDR "
            "merge needs a response over raw codes from recover_oecf"
        )
    codes = np.asarray(table["code"].values)
    if not (codes.size == n_codes and np.array_equal(codes, np.arange(n_codes))):
        table = response_at_codes(table, np.arange(n_codes))
    if "channel" in table.dims:
        missing = sorted(set(counts["channel"].values.tolist()) - set(table["channel"].values.tolist()))
        if missing:
            raise CalibrationError(
                f"{where}: response has no channel(s) {missing}; it has "
                f"{table['channel'].values.tolist()}"
            )
        table = table.sel(channel=counts["channel"].values)
    else:
        table = table.expand_dims(channel=counts.sizes["channel"])
    cameras = None
    if "camera" in table.dims:
        if "camera" not in counts.coords:
            raise SchemaError(
                f"{where}: the response is per camera",
                [Problem("raw/rgb:camera", "a coord camera (image,)", "nothing")],
            )
        cameras = np.asarray(table["camera"].values)
        rows = {value: i for i, value in enumerate(cameras.tolist())}
        per_image = np.asarray(counts["camera"].values).tolist()
        missing = sorted(set(per_image) - set(rows))
        if missing:
            raise CalibrationError(
                f"{where}: no response for camera(s) {missing}; responses exist for {cameras.tolist()}"
            )
        index = np.array([rows[c] for c in per_image], dtype=np.intp)
    else:
        table = table.expand_dims(camera=1)
        index = np.zeros(counts.sizes["image"], dtype=np.intp)
    values = np.asarray(table.transpose("camera", "channel", "code").values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise CalibrationError(f"{where}: the response contains NaN or inf")
    return values, index, cameras


CameraLevels = int | Mapping[int, int] | xr.DataArray
"""A level [DN] for every camera (an int), or per camera: ``{camera: level}`` or a DataArray
over ``camera``."""


def camera_levels(
    given: CameraLevels | None,
    response: xr.Dataset | xr.DataArray,
    cameras: np.ndarray | None,
    name: str,
    default: int,
    where: str,
) -> np.ndarray:
    """``name`` (``"black_level"`` or ``"saturation"``) per row of the response tables.

    ``given`` decides when set (an int overrides every camera); else the response group's
    variable ``name`` over ``camera`` [DN] (``calibration/oecf_rgb``), else its attrs
    ``black_levels`` (one per camera, in the order of its ``camera`` coord) for the black
    level, else the attr ``name``, else ``default``.

    Returns
    -------
    numpy.ndarray
        int64 ``(len(cameras),)``, or ``(1,)`` when ``cameras`` is None.
    """
    n = 1 if cameras is None else len(cameras)
    table = response["response"] if isinstance(response, xr.Dataset) else response
    attrs = {**(response.attrs if isinstance(response, xr.Dataset) else {}), **table.attrs}
    per_camera: xr.DataArray | None = None
    if given is not None and not isinstance(given, Mapping | xr.DataArray):
        return np.full(n, int(given), dtype=np.int64)
    if isinstance(given, xr.DataArray):
        per_camera = given
    elif isinstance(given, Mapping):
        per_camera = xr.DataArray(
            [int(v) for v in given.values()], dims="camera", coords={"camera": list(given)}
        )
    elif isinstance(response, xr.Dataset) and name in response.data_vars:
        per_camera = response[name]
    elif name == "black_level" and attrs.get("black_levels") is not None and "camera" in table.dims:
        per_camera = xr.DataArray(
            np.asarray(attrs["black_levels"], dtype=np.int64),
            dims="camera",
            coords={"camera": table["camera"].values},
        )
    if per_camera is None:
        return np.full(n, int(attrs.get(name, default)), dtype=np.int64)
    if per_camera.dims == ():
        return np.full(n, int(per_camera), dtype=np.int64)
    if per_camera.dims != ("camera",):
        raise SchemaError(
            f"{where}: the {name} breaks the contract",
            [Problem(name, "a level per camera, dims (camera,) [DN]", f"dims {per_camera.dims}")],
        )
    if cameras is None:
        values = np.unique(np.asarray(per_camera.values))
        if values.size != 1:
            raise CalibrationError(
                f"{where}: {name} differs per camera ({values.tolist()}) but the response has no "
                "camera dim: give one response per camera, or one level"
            )
        return np.full(n, int(values[0]), dtype=np.int64)
    known = set(np.asarray(per_camera["camera"].values).tolist())
    missing = sorted(set(cameras.tolist()) - known)
    if missing:
        raise CalibrationError(
            f"{where}: no {name} for camera(s) {missing}; it is given for {sorted(known)}"
        )
    return np.asarray(per_camera.sel(camera=cameras).values).astype(np.int64)


def merge_hdr(
    raw_rgb: xr.Dataset,
    response: xr.Dataset | xr.DataArray,
    *,
    black_level: CameraLevels | None = None,
    saturation: CameraLevels | None = None,
    weighting: Weighting | None = None,
    chunks: Mapping[str, int] | None = None,
    flat_field: FlatField | None = None,
) -> xr.Dataset:
    """Merge LDR exposure series into relative HDR radiance (Robertson's estimator).

    Parameters
    ----------
    raw_rgb
        Group ``raw/rgb``: ``counts`` (image, exposure, y, x, channel) uint16 [DN] with
        coord ``exposure_time`` (image, exposure) [s], strictly increasing per image, and
        ``attrs["bit_depth"]`` (8..16). Per-image coords are carried over.
    response
        From :func:`spectralize.nodes.calibration.oecf.recover_oecf`: ``response`` over raw codes with
        dims ``([camera,] [channel,] code)``, or the group ``calibration/oecf_rgb`` (a Dataset
        with ``response`` and the levels per camera). With a ``camera`` dim each image uses
        its camera's response; without ``channel`` one response serves every channel.
    black_level, saturation
        Samples at or below ``black_level`` or at or above ``saturation`` get weight 0 [DN].
        An int holds for every camera; ``{camera: level}`` or a DataArray over ``camera``
        per camera; ``None``: per camera from the response group (:func:`camera_levels`:
        its ``black_level``/``saturation`` variables over ``camera``, else its attrs), else
        ``0`` and ``2**bit_depth - 1``. Each image's codes are weighted with its own
        camera's levels (cameras of other models have other black offsets).
    weighting
        Weighting (see :func:`spectralize.nodes.calibration.oecf.weighting_function`); default the
        response's attr, else ``"gaussian"``.
    chunks
        Dask chunk sizes for ``image``, ``y``, ``x`` when ``raw_rgb`` is not already chunked;
        default ``{"image": 1, "y": 512, "x": 512}``. ``exposure`` and ``channel`` are never
        split.
    flat_field
        Each camera's flat field (:func:`~spectralize.nodes.calibration.flat_field.
        rgb_flat_field`): each image's radiance is divided by its camera's map (a map of one
        camera: by it, for every image). ``None``: no flat field.

    Returns
    -------
    xarray.Dataset
        Group ``hdr``: ``radiance`` (image, y, x, channel) float32, units ``"1"`` (relative
        radiance, in units of the response's normalisation per second of exposure), plus the
        per-image coords of ``raw_rgb``. Dask-backed (lazy) if ``raw_rgb`` was, else
        computed. Attrs: ``method``, ``black_level`` and ``saturation`` (an int when every
        camera has the same, else one per camera of ``level_cameras``), ``weighting``,
        ``n_saturated``, ``n_underexposed``, ``n_unresolved`` (pixel-channels without any
        weighted sample: saturated in every exposure, dark in every exposure, other).

    Raises
    ------
    SchemaError
        ``raw_rgb`` or ``response`` breaks the contract (dims, dtype, missing coords).
    CalibrationError
        Exposure times not strictly increasing (unsorted or duplicate) or not positive,
        values beyond the bit depth, a frame entirely saturated or entirely dark, a response
        missing for a channel or camera, a response over dark-subtracted values.

    Warns
    -----
    RuntimeWarning
        When pixels have no weighted sample: they get the best bound (a lower bound
        ``f(saturation)/t_min`` where saturated everywhere, an upper bound
        ``f(black_level)/t_max`` where dark everywhere); never silently clipped.

    Notes
    -----
    Domain: integer codes ``0 .. 2**bit_depth - 1``. Range: relative radiance ``x`` such
    that ``f(I) ~ x t``; non-negative for a non-negative response.

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003, eq. 7 (radiance estimate).
    .. [2] Fast Capture of Spectral Image Series, section 5.
    """
    where = "merge_hdr"
    counts = _validate(raw_rgb, where)
    depth = check_bit_depth(
        raw_rgb.attrs.get("bit_depth", counts.attrs.get("bit_depth")), where="raw/rgb.attrs['bit_depth']"
    )
    n_codes = 2**depth
    table_da = response["response"] if isinstance(response, xr.Dataset) else response
    attrs = {**(response.attrs if isinstance(response, xr.Dataset) else {}), **table_da.attrs}
    kind: Weighting = attrs.get("weighting", "gaussian") if weighting is None else weighting
    times = raw_rgb["exposure_time"].transpose("image", "exposure")
    check_exposure_times(times, "exposure", f"{where}: raw/rgb")
    tables, index, cameras = _response_table(response, counts, n_codes, where)
    blacks = camera_levels(black_level, response, cameras, "black_level", 0, where)
    sats = camera_levels(saturation, response, cameras, "saturation", n_codes - 1, where)
    for row, (black, sat) in enumerate(zip(blacks.tolist(), sats.tolist(), strict=True)):
        if not 0 <= black < sat <= n_codes - 1:
            label = "" if cameras is None else f" (camera {cameras[row]})"
            raise CalibrationError(
                f"{where}: need 0 <= black_level < saturation <= {n_codes - 1}, "
                f"got black_level={black}, saturation={sat}{label}"
            )
    weights = np.stack(
        [
            weighting_function(np.arange(n_codes), black_level=b, saturation=s, kind=kind)
            for b, s in zip(blacks.tolist(), sats.tolist(), strict=True)
        ]
    )

    lazy = counts.chunks is not None
    if not lazy:
        size = dict(chunks or {"image": 1, "y": 512, "x": 512})
        counts = counts.chunk({**size, "exposure": -1, "channel": -1})
    else:
        counts = counts.chunk({"exposure": -1, "channel": -1})
    # Small frames (a full run's geometry with tiny frames): chunks of one image make one
    # task per image and step; merge whole blocks of images instead (the estimate is per
    # pixel, so the blocks do not change a value), and give the radiance the chunks of the
    # input back (the flow reads raw/rgb by shard: hdr is written shard by shard, in chunks
    # of at most layout.CHUNK_BYTES on disk, which a batch of sets reads a few of).
    image_chunks = counts.chunks[counts.get_axis_num("image")]
    counts = counts.chunk({"image": _image_block(counts)})
    blocks = {"image": counts.chunks[0]}
    row = xr.DataArray(index, dims="image").chunk(blocks)

    # One pass for the checks and the counts that go into attrs (none when the node's value
    # check has just made it for the same series and levels)
    frame_min, frame_max, n_sat, n_dark, n_none = series_summary(
        raw_rgb["counts"], blacks[index], sats[index]
    )
    frame_dims = ("image", "exposure", "channel")
    raise_for_camera_frames(
        frame_min,
        frame_max,
        frame_dims=frame_dims,
        black_levels=blacks[index],
        saturations=sats[index],
        max_code=n_codes - 1,
        where=f"{where}: raw/rgb:counts",
        times=times,
    )
    n_sat, n_dark, n_none = int(n_sat), int(n_dark), int(n_none)
    n_other = n_none - n_sat - n_dark
    if n_none:
        warnings.warn(
            f"{where}: {n_none} pixel-channel(s) have no weighted sample: {n_sat} saturated in "
            f"every exposure (given the lower bound f(saturation)/t_min), {n_dark} dark in every "
            f"exposure (given the upper bound f(black_level)/t_max), {n_other} other; add "
            "shorter/longer exposures to resolve them",
            RuntimeWarning,
            stacklevel=2,
        )

    t = times.astype(np.float64).chunk(blocks)
    radiance = xr.apply_ufunc(
        _merge_block,
        counts,
        t,
        row,
        input_core_dims=[["exposure"], ["exposure"], []],
        output_core_dims=[[]],
        kwargs={"tables": tables, "weights": weights, "black_levels": blacks, "saturations": sats},
        dask="parallelized",
        output_dtypes=[np.float32],
    ).transpose("image", "y", "x", "channel")
    if flat_field is not None:  # flat field: each image over its camera's map (eq. 5, Q F(p))
        rows = np.zeros(counts.sizes["image"], dtype=int)
        if len(flat_field.keys) > 1:
            rows = flat_field.rows(np.asarray(raw_rgb["camera"].values), "raw/rgb camera")
        radiance = flat_field.divide(radiance, rows)
    if not lazy:
        radiance = radiance.compute()
    else:
        radiance = radiance.chunk({"image": image_chunks})
    radiance.attrs = {"units": "1", "long_name": "relative RGB radiance"}
    coords = {
        k: v
        for k, v in raw_rgb.coords.items()
        if "exposure" not in v.dims and set(v.dims) <= {"image", "channel"}
    }
    out = xr.Dataset(
        {"radiance": radiance.drop_vars([c for c in radiance.coords if c not in coords])},
        coords=coords,
        attrs={
            "method": "robertson2003",
            "bit_depth": int(depth),
            **_level_attrs(blacks, sats, cameras),
            "weighting": kind,
            "n_saturated": n_sat,
            "n_underexposed": n_dark,
            "n_unresolved": n_other,
            "flat_field": "each camera's white reference" if flat_field is not None else "none",
        },
    )
    return out


_SUMMARY: dict[tuple, tuple] = {}
"""The last lazy series :func:`series_summary` summarised (one entry): the node's value check
and the node's function, called one after the other on the same raw/rgb, read it once."""


def series_summary(
    counts: xr.DataArray, black_levels: np.ndarray, saturations: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """One pass over raw/rgb's ``counts``: what the merge checks and counts.

    Parameters
    ----------
    counts
        ``(image, exposure, y, x, channel)`` in any order, numpy or dask.
    black_levels, saturations
        (image,) each image's camera's levels [DN].

    Returns
    -------
    tuple
        ``(frame_min, frame_max, n_saturated, n_underexposed, n_no_sample)``: each frame's
        extremes over ``(image, exposure, channel)`` and the pixel-channels saturated in every
        exposure, at or below the black level in every exposure, and without any weighted
        sample. Dask input is reduced per block of images (:data:`BLOCK_BYTES`), a few tasks
        per block, not per image; the result is kept for the next call with the same dask
        array and levels (the node's function after its value check), so raw/rgb is read
        once for both.
    """
    key = None
    if counts.chunks is not None:
        key = (counts.data.name, black_levels.tobytes(), saturations.tobytes())
        if key in _SUMMARY:
            return _SUMMARY[key]
    counts = counts.transpose(*_DIMS)
    if counts.chunks is not None:
        counts = counts.chunk({"exposure": -1, "channel": -1})
        counts = counts.chunk({"image": _image_block(counts)})
        blocks = {"image": counts.chunks[0]}
        black = xr.DataArray(black_levels, dims="image").chunk(blocks)
        sat = xr.DataArray(saturations, dims="image").chunk(blocks)
    else:
        black = xr.DataArray(black_levels, dims="image")
        sat = xr.DataArray(saturations, dims="image")
    frame_min, frame_max, n_sat, n_dark, n_none = dask.compute(
        counts.min(["y", "x"]).data,
        counts.max(["y", "x"]).data,
        (counts >= sat).all("exposure").sum().data,
        (counts <= black).all("exposure").sum().data,
        (~((counts > black) & (counts < sat)).any("exposure")).sum().data,
    )
    # frame arrays (image, exposure, channel): the order of _DIMS without y, x
    result = (np.asarray(frame_min), np.asarray(frame_max), int(n_sat), int(n_dark), int(n_none))
    if key is not None:
        _SUMMARY.clear()
        _SUMMARY[key] = result
    return result


def _level_attrs(blacks: np.ndarray, sats: np.ndarray, cameras: np.ndarray | None) -> dict:
    """The hdr group's level attrs: ints when every camera has the same, else lists per camera
    (``level_cameras``)."""
    if np.unique(blacks).size == 1 and np.unique(sats).size == 1:
        return {"black_level": int(blacks[0]), "saturation": int(sats[0])}
    return {
        "black_level": [int(v) for v in blacks],
        "saturation": [int(v) for v in sats],
        "level_cameras": [] if cameras is None else [int(c) for c in cameras],
    }


def raise_for_camera_frames(
    frame_min: np.ndarray,
    frame_max: np.ndarray,
    *,
    frame_dims: Sequence[str],
    black_levels: np.ndarray,
    saturations: np.ndarray,
    max_code: int,
    where: str,
    times: xr.DataArray | None = None,
) -> None:
    """:func:`~spectralize.nodes.calibration.exposure_series.raise_for_frames` with each
    image's own camera's levels.

    ``frame_min``/``frame_max`` are each frame's extremes over ``frame_dims`` (one of them
    ``image``); ``black_levels``/``saturations`` (image,) the levels of each image's camera.
    Values beyond the bit depth first, then entirely saturated frames, then entirely dark
    ones, each for one level at a time (the message names the level the frame was held to).
    """
    axis = list(frame_dims).index("image")
    shape = [1] * frame_min.ndim
    shape[axis] = -1
    lo, hi = int(frame_min.min()), int(frame_max.max())
    everywhere = np.ones(frame_min.shape, dtype=bool)
    black_levels, saturations = np.asarray(black_levels), np.asarray(saturations)
    common = {"frame_dims": frame_dims, "max_code": max_code, "where": where, "times": times}
    for rule in ("saturated", "dark"):
        levels = saturations if rule == "saturated" else black_levels
        for level in np.unique(levels).tolist():
            other = np.broadcast_to((levels != level).reshape(shape), frame_min.shape)
            if rule == "saturated":
                flags = (frame_min < level) | other, everywhere
                bounds = {"black_level": -1, "saturation": level}
            else:
                flags = everywhere, (frame_max > level) | other
                bounds = {"black_level": level, "saturation": max_code + 1}
            raise_for_frames(lo, hi, *flags, **bounds, **common)


def merge_hdr_refusals(
    raw_rgb: xr.Dataset,
    *,
    black_level: CameraLevels | None,
    saturation: CameraLevels | None,
    response: xr.Dataset | None = None,
) -> list[SpectralizeError]:
    """What :func:`merge_hdr` refuses in raw/rgb before merging (its value check).

    The bit depth (8..16); exposure times positive, finite and strictly increasing per image;
    values within the bit depth; no frame entirely saturated (``>= saturation``, default
    ``2**bit_depth - 1``); no frame entirely dark (``<= black_level``). The levels are each
    image's camera's (:func:`camera_levels` from ``response``, the group
    ``calibration/oecf_rgb``, unless given); while the response is not there yet and no black
    level is given, the dark rule waits for it. The same functions :func:`merge_hdr` raises
    from, with its names. One pass over the counts, a few tasks per block of images.
    """
    where = "merge_hdr"
    bits = raw_rgb.attrs.get("bit_depth", raw_rgb["counts"].attrs.get("bit_depth"))
    depth = refused(lambda: check_bit_depth(bits, where="raw/rgb.attrs['bit_depth']"))
    if depth:
        return depth
    top = 2 ** int(bits) - 1  # type: ignore[call-overload]
    counts = raw_rgb["counts"]
    n_image = counts.sizes["image"]
    found: list[SpectralizeError] = []
    blacks, sats = np.full(n_image, -1), np.full(n_image, top)
    if response is not None:
        levels: list[np.ndarray] = []

        def per_image() -> None:
            tables, index, cameras = _response_table(response, counts, top + 1, where)
            for given, name, default, into in (
                (black_level, "black_level", 0, levels),
                (saturation, "saturation", top, levels),
            ):
                into.append(camera_levels(given, response, cameras, name, default, where)[index])

        found += refused(per_image)
        if levels:
            blacks, sats = levels
    else:
        if black_level is not None:
            blacks = _levels_without_response(black_level, raw_rgb, n_image)
        if saturation is not None:
            sats = _levels_without_response(saturation, raw_rgb, n_image)
    times = raw_rgb["exposure_time"].transpose("image", "exposure")
    found += refused(lambda: check_exposure_times(times, "exposure", f"{where}: raw/rgb"))
    if set(counts.dims) != set(_DIMS):
        return found + refused(lambda: _validate(raw_rgb, where))
    frame_min, frame_max, *_ = series_summary(counts, blacks, sats)
    return found + refused(
        lambda: raise_for_camera_frames(
            frame_min,
            frame_max,
            frame_dims=("image", "exposure", "channel"),
            black_levels=blacks,
            saturations=sats,
            max_code=top,
            where=f"{where}: raw/rgb:counts",
            times=times,
        )
    )


def _levels_without_response(given: CameraLevels, raw_rgb: xr.Dataset, n_image: int) -> np.ndarray:
    """Per image, levels given as an int or per camera (raw/rgb's ``camera`` coord)."""
    if not isinstance(given, Mapping | xr.DataArray):
        return np.full(n_image, int(given))
    per_camera = (
        dict(given)
        if isinstance(given, Mapping)
        else dict(zip(given["camera"].values.tolist(), given.values.tolist(), strict=True))
    )
    return np.array([int(per_camera[c]) for c in raw_rgb["camera"].values.tolist()])
