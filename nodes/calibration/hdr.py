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
from collections.abc import Mapping

import dask
import numpy as np
import xarray as xr

from spectralize.nodes.calibration.exposure_series import (
    check_bit_depth,
    check_exposure_times,
    frame_extremes,
    raise_for_frames,
    refused,
)
from spectralize.nodes.calibration.oecf.response import response_at_codes
from spectralize.nodes.calibration.oecf.weighting import Weighting, weighting_function
from spectralize.schemas import CalibrationError, SchemaError, SpectralizeError
from spectralize.schemas.errors import Problem

__all__ = ["merge_hdr", "merge_robertson", "merge_hdr_refusals"]

_DIMS = ("image", "exposure", "y", "x", "channel")


def merge_robertson(
    counts: np.ndarray,
    exposure_times: np.ndarray,
    response: np.ndarray,
    weights: np.ndarray,
    *,
    black_level: int,
    saturation: int,
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
        ``w(code)`` ``(n_codes,)`` (0 at saturated and under-exposed codes).
    black_level, saturation
        Codes ``<= black_level`` are under-exposed, codes ``>= saturation`` saturated.

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
    Domain: integer codes ``0 .. len(weights)-1``. Range: non-negative relative radiance
    for a non-negative response.

    References
    ----------
    .. [1] Robertson, Borman, Stevenson 2003, eq. 7 (radiance estimate).
    """
    c = counts.astype(np.intp)
    t = np.broadcast_to(np.asarray(exposure_times, dtype=np.float64), c.shape)
    f = np.take_along_axis(response, c, axis=-1)
    w = weights[c]
    num = (w * t * f).sum(axis=-1)
    den = (w * t * t).sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = num / den
    missing = ~(den > 0)
    if missing.any():
        saturated = c >= saturation
        t_sat = np.where(saturated, t, np.inf).min(axis=-1)
        t_dark = np.where(c <= black_level, t, 0.0).max(axis=-1)
        f_sat = np.take_along_axis(response, np.full(c.shape[:-1] + (1,), saturation, np.intp), axis=-1)[
            ..., 0
        ]
        f_dark = np.take_along_axis(
            response, np.full(c.shape[:-1] + (1,), max(black_level, 0), np.intp), axis=-1
        )[..., 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = np.where(saturated.any(axis=-1), f_sat / t_sat, f_dark / t_dark)
        x = np.where(missing, bound, x)
    return x.astype(np.float32)


BLOCK_BYTES = 4 * 2**20
"""Counts merged per task at least (whole images, when one image's chunks are smaller)."""


def _image_block(counts: xr.DataArray) -> tuple[int, ...]:
    """Image chunks of ``counts`` joined up to :data:`BLOCK_BYTES` (a chunk's whole frame
    only: frames split in y or x keep their chunks)."""
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
        else:
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
) -> xr.DataArray:
    """The response at integer codes 0..n_codes-1, dims (image, channel, code)."""
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
    if "camera" in table.dims:
        if "camera" not in counts.coords:
            raise SchemaError(
                f"{where}: the response is per camera",
                [Problem("raw/rgb:camera", "a coord camera (image,)", "nothing")],
            )
        cameras = counts["camera"].values
        missing = sorted(set(cameras.tolist()) - set(table["camera"].values.tolist()))
        if missing:
            raise CalibrationError(
                f"{where}: no response for camera(s) {missing}; responses "
                f"exist for {table['camera'].values.tolist()}"
            )
        table = table.sel(camera=xr.DataArray(cameras, dims="image")).drop_vars("camera")
    else:
        table = table.expand_dims(image=counts.sizes["image"])
    table = table.drop_vars([c for c in table.coords if c not in ("code",)])
    values = np.asarray(table.transpose("image", "channel", "code").values, dtype=np.float64)
    if not np.all(np.isfinite(values)):
        raise CalibrationError(f"{where}: the response contains NaN or inf")
    return xr.DataArray(values, dims=("image", "channel", "code"))


def merge_hdr(
    raw_rgb: xr.Dataset,
    response: xr.Dataset | xr.DataArray,
    *,
    black_level: int | None = None,
    saturation: int | None = None,
    weighting: Weighting | None = None,
    chunks: Mapping[str, int] | None = None,
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
        dims ``([camera,] [channel,] code)``. With a ``camera`` dim each image uses its
        camera's response; without ``channel`` one response serves every channel.
    black_level, saturation, weighting
        Weighting (see :func:`spectralize.nodes.calibration.oecf.weighting_function`); defaults are the
        response's attrs, else ``0``, ``2**bit_depth - 1`` and ``"gaussian"``. Samples at or
        below ``black_level`` or at or above ``saturation`` get weight 0.
    chunks
        Dask chunk sizes for ``image``, ``y``, ``x`` when ``raw_rgb`` is not already chunked;
        default ``{"image": 1, "y": 512, "x": 512}``. ``exposure`` and ``channel`` are never
        split.

    Returns
    -------
    xarray.Dataset
        Group ``hdr``: ``radiance`` (image, y, x, channel) float32, units ``"1"`` (relative
        radiance, in units of the response's normalisation per second of exposure), plus the
        per-image coords of ``raw_rgb``. Dask-backed (lazy) if ``raw_rgb`` was, else
        computed. Attrs: ``method``, ``black_level``, ``saturation``, ``weighting``,
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
    attrs = table_da.attrs
    black = int(attrs.get("black_level", 0) if black_level is None else black_level)
    sat = int(attrs.get("saturation", n_codes - 1) if saturation is None else saturation)
    kind: Weighting = attrs.get("weighting", "gaussian") if weighting is None else weighting
    if not 0 <= black < sat <= n_codes - 1:
        raise CalibrationError(
            f"{where}: need 0 <= black_level < saturation <= {n_codes - 1}, "
            f"got black_level={black}, saturation={sat}"
        )
    weights = weighting_function(np.arange(n_codes), black_level=black, saturation=sat, kind=kind)
    times = raw_rgb["exposure_time"].transpose("image", "exposure")
    check_exposure_times(times, "exposure", f"{where}: raw/rgb")
    table = _response_table(response, counts, n_codes, where)

    lazy = counts.chunks is not None
    if not lazy:
        size = dict(chunks or {"image": 1, "y": 512, "x": 512})
        counts = counts.chunk({**size, "exposure": -1, "channel": -1})
    else:
        counts = counts.chunk({"exposure": -1, "channel": -1})
    # Small frames (a full run's geometry with tiny frames): chunks of one image make one
    # task per image and step; merge whole blocks of images instead (the estimate is per
    # pixel, so the blocks do not change a value), and give the radiance the chunks of the
    # input back (one image per chunk on disk, as a set's reads want it).
    image_chunks = counts.chunks[counts.get_axis_num("image")]
    counts = counts.chunk({"image": _image_block(counts)})

    # One pass for the checks and the counts that go into attrs. A pixel-channel saturated
    # (or dark) in every exposure has no weighted sample; "other" ones mix both.
    pixel_dims = ["y", "x"]
    lo, hi, not_sat, not_dark, n_sat, n_dark, n_none = dask.compute(
        counts.min(),
        counts.max(),
        (counts < sat).any(pixel_dims),
        (counts > black).any(pixel_dims),
        (counts >= sat).all("exposure").sum(),
        (counts <= black).all("exposure").sum(),
        (~((counts > black) & (counts < sat)).any("exposure")).sum(),
    )
    frame_dims = ("image", "exposure", "channel")
    raise_for_frames(
        int(lo),
        int(hi),
        not_sat.transpose(*frame_dims).values,
        not_dark.transpose(*frame_dims).values,
        frame_dims=frame_dims,
        black_level=black,
        saturation=sat,
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

    t = times.astype(np.float64).chunk({"image": counts.chunks[0]})
    tab = table.chunk({"image": counts.chunks[0], "code": -1, "channel": -1})
    radiance = xr.apply_ufunc(
        merge_robertson,
        counts,
        t,
        tab,
        input_core_dims=[["exposure"], ["exposure"], ["code"]],
        output_core_dims=[[]],
        kwargs={"weights": weights, "black_level": black, "saturation": sat},
        dask="parallelized",
        output_dtypes=[np.float32],
    ).transpose("image", "y", "x", "channel")
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
            "black_level": black,
            "saturation": sat,
            "weighting": kind,
            "n_saturated": n_sat,
            "n_underexposed": n_dark,
            "n_unresolved": n_other,
        },
    )
    return out


def merge_hdr_refusals(
    raw_rgb: xr.Dataset, *, black_level: int | None, saturation: int | None
) -> list[SpectralizeError]:
    """What :func:`merge_hdr` refuses in raw/rgb before merging (its value check).

    The bit depth (8..16); exposure times positive, finite and strictly increasing per image;
    values within the bit depth; no frame entirely saturated (``>= saturation``, default
    ``2**bit_depth - 1``); no frame entirely dark (``<= black_level``; not checked while the
    response that gives the black level is not there yet: ``black_level=None``). The same
    functions :func:`merge_hdr` raises from, with its names. One pass over the counts.
    """
    where = "merge_hdr"
    bits = raw_rgb.attrs.get("bit_depth", raw_rgb["counts"].attrs.get("bit_depth"))
    depth = refused(lambda: check_bit_depth(bits, where="raw/rgb.attrs['bit_depth']"))
    if depth:
        return depth
    top = 2 ** int(bits) - 1  # type: ignore[call-overload]
    sat = top if saturation is None else int(saturation)
    black = -1 if black_level is None else int(black_level)
    counts = raw_rgb["counts"]
    times = raw_rgb["exposure_time"].transpose("image", "exposure")
    found = refused(lambda: check_exposure_times(times, "exposure", f"{where}: raw/rgb"))
    frame_dims = [d for d in counts.dims if d in ("image", "exposure", "channel")]
    lo, hi, frame_min, frame_max = frame_extremes(
        counts, [d for d in counts.dims if d not in frame_dims]
    )
    return found + refused(
        lambda: raise_for_frames(
            lo,
            hi,
            frame_min < sat,
            frame_max > black,
            frame_dims=frame_dims,
            black_level=black,
            saturation=sat,
            max_code=top,
            where=f"{where}: raw/rgb:counts",
            times=times,
        )
    )
