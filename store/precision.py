"""Float arrays stored at the precision their schema declares, and the checks of it on disk.

An array whose :class:`~spectralize.schemas.ArraySpec` declares a
:class:`~spectralize.schemas.Precision` (the reconstructed cube's ``radiance``) is written with
every finite value rounded to that many mantissa bits (:func:`round_mantissa`, bit rounding
as numcodecs' ``BitRound``, ties to even), or with ``along`` to one quantum per spectrum
(:func:`round_to_peak`), and compressed by :data:`PRECISION_COMPRESSORS`
(Blosc: zstd on the bit planes, which stores the zeroed trailing bits for almost nothing).
The rounding happens before zarr sees the values, so the array's codec chain has only codecs
of the zarr 3 specification and any zarr 3 reader decodes it; the array's attrs state the
bits kept and the relative bound (:attr:`~spectralize.schemas.Precision.attrs`).

The run store rounds where it writes the finished array: before a whole write, and while it
packs the regions of a resumable one (:func:`~.staging.pack_staged`), so regions staged by
an interrupted write, by whatever version staged them, are rounded alike: one array never
mixes precisions. :func:`precision_problems` checks a finished group: the codec chain of each
array is lossless (or bit rounding no coarser than stated), and its values carry no more
precision than its attrs state (rounding them again changes nothing: a sample of chunks, or
every value when deep). An array
stored without the attrs (a store written before its schema declared a precision) was stored
losslessly: it meets every bound and is valid.

References
----------
.. [1] Fast Capture of Spectral Image Series (the reconstructed radiance, sec. 5).
.. [2] Klöwer, M., Razinger, M., Dominguez, J. J., Düben, P. D. and Palmer, T. N.:
   Compressing atmospheric data into its real information content. Nature Computational
   Science 1, 713-724 (2021).
"""

from __future__ import annotations

import json
from collections.abc import Hashable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr
from zarr.codecs import BloscCodec

from spectralize.schemas import GroupSchema, Precision, Problem, StoreError

__all__ = [
    "PRECISION_COMPRESSORS",
    "LOSSLESS_CODECS",
    "round_mantissa",
    "round_to_peak",
    "round_precision",
    "excess_precision",
    "declared_precisions",
    "apply_precision",
    "precision_encoding",
    "codec_problems",
    "precision_problems",
]

PRECISION_COMPRESSORS = (BloscCodec(cname="zstd", clevel=5, shuffle="bitshuffle", blocksize=4 * 2**20),)
"""Compressors of a rounded float array: zstd on Blosc's bit planes (zarr 3 codecs), in
blocks of up to a tile's chunk (zstd's context spans a tile, not Blosc's default block)."""

LOSSLESS_CODECS = frozenset(
    {
        "bytes",
        "transpose",
        "sharding_indexed",
        "zstd",
        "blosc",
        "gzip",
        "crc32c",
        "numcodecs.zstd",
        "numcodecs.blosc",
        "numcodecs.gzip",
        "numcodecs.zlib",
        "numcodecs.lz4",
        "numcodecs.bz2",
        "numcodecs.lzma",
        "numcodecs.shuffle",
        "numcodecs.crc32",
        "numcodecs.crc32c",
        "numcodecs.adler32",
        "numcodecs.fletcher32",
    }
)
"""Codecs that give back the bytes they were given (any others may lose precision)."""

_BIT_ROUND = "numcodecs.bitround"  # lossy, bounded: accepted when it keeps the bits stated
_SAMPLE_CHUNKS = 2  # chunks of each rounded array a check without ``deep`` reads: first, last


def round_mantissa(values: np.ndarray, keepbits: int) -> np.ndarray:
    """``values`` rounded to ``keepbits`` explicit mantissa bits, to nearest, ties to even.

    Every finite normal value ``x`` becomes ``x'`` with ``|x' - x| <= 2 ** -(keepbits + 1)
    |x|`` (half a unit in the last kept bit). Zeros stay zeros; NaN and inf, and the finite
    values that would round past the largest float, keep their bits. Rounding is
    idempotent: rounded values come back unchanged.

    Parameters
    ----------
    values
        A float array (float16, float32 or float64).
    keepbits
        Mantissa bits kept, 0 to the dtype's (a value of the dtype's or more: no rounding).

    Returns
    -------
    numpy.ndarray
        A new array of the same dtype and shape.

    Raises
    ------
    StoreError
        For values that are not floats, or a negative ``keepbits``.

    References
    ----------
    .. [1] Klöwer et al. (2021), Compressing atmospheric data into its real information
       content (bit rounding).
    """
    values = np.asarray(values)
    if values.dtype.kind != "f" or keepbits < 0:
        raise StoreError.single(
            "precision", "float values and keepbits >= 0", f"dtype {values.dtype}, keepbits {keepbits}"
        )
    mantissa = int(np.finfo(values.dtype).nmant)
    if keepbits >= mantissa:
        return values.copy()
    unsigned = np.dtype(f"u{values.dtype.itemsize}").type
    drop = mantissa - keepbits
    # in place on one copy (a shard row at a time when packing: few temporaries)
    rounded = np.array(values, order="C", copy=True)
    bits = rounded.view(unsigned)
    last_kept = bits >> unsigned(drop)
    last_kept &= unsigned(1)  # ties go to the even neighbour
    bits += unsigned((1 << (drop - 1)) - 1)
    bits += last_kept
    del last_kept
    bits &= unsigned(~((1 << drop) - 1) & ((1 << (8 * values.dtype.itemsize)) - 1))
    # NaN/inf, and finite values that rounded past the largest float, keep their bits
    keep = np.isfinite(rounded)
    keep &= np.isfinite(values)
    np.logical_not(keep, out=keep)
    if keep.any():
        rounded[keep] = values[keep]
    return rounded


def round_to_peak(values: np.ndarray, keepbits: int, axis: int) -> np.ndarray:
    """``values`` rounded to one quantum per spectrum along ``axis``: half a unit in the last
    of ``keepbits`` mantissa bits of the spectrum's peak (a scale to integers per spectrum).

    The peak ``max |x|`` along ``axis`` (finite values) is rounded to ``keepbits`` bits,
    :math:`\\hat p`, and every value to the nearest multiple (ties to even) of
    :math:`q = 2^{e - 1 - k}`, :math:`2^{e-1} \\le \\hat p < 2^e`: the peak is stored as
    :func:`round_mantissa` stores it, every value within :math:`2^{-(k+1)} \\hat p` of the
    computed one, and rounding again changes nothing. NaN/inf keep their bits, as do the
    values of spectra whose quantum underflows.
    """
    values = np.asarray(values)
    if values.dtype.kind != "f" or keepbits < 0:
        raise StoreError.single(
            "precision", "float values and keepbits >= 0", f"dtype {values.dtype}, keepbits {keepbits}"
        )
    finite = np.isfinite(values)
    if values.size == 0:
        return values.copy()
    peak = round_mantissa(np.where(finite, np.abs(values), 0).max(axis=axis, keepdims=True), keepbits)
    _, exponent = np.frexp(peak)
    quantum = np.ldexp(np.ones((), values.dtype), exponent - 1 - keepbits).astype(values.dtype)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        rounded = np.rint(values / quantum) * quantum
    keep = ~finite | (quantum == 0) | ~np.isfinite(rounded)
    if keep.any():
        rounded[keep] = values[keep]
    return rounded.astype(values.dtype, copy=False)


def round_precision(values: np.ndarray, keepbits: int, axis: int | None = None) -> np.ndarray:
    """:func:`round_mantissa` (``axis`` ``None``) or :func:`round_to_peak` along ``axis``."""
    return round_mantissa(values, keepbits) if axis is None else round_to_peak(values, keepbits, axis)


def excess_precision(values: np.ndarray, keepbits: int, axis: int | None = None) -> int:
    """How many of ``values`` carry more precision than stated (rounding changes them):
    more than ``keepbits`` mantissa bits, or (``axis``) finer than their spectrum's quantum."""
    values = np.asarray(values)
    rounded = round_precision(values, keepbits, axis)
    unsigned = np.dtype(f"u{values.dtype.itemsize}")
    return int(
        np.count_nonzero(
            np.ascontiguousarray(rounded).view(unsigned) != np.ascontiguousarray(values).view(unsigned)
        )
    )


def declared_precisions(ds: xr.Dataset, schema: GroupSchema | None) -> dict[str, Precision]:
    """The variables of ``ds`` whose spec in ``schema`` declares a precision."""
    if schema is None:
        return {}
    found: dict[str, Precision] = {}
    for spec in (*schema.variables, *schema.optional_variables, *schema.coords):
        if spec.precision is not None and spec.name in ds.variables:
            if ds[spec.name].dtype.kind != "f":
                raise StoreError.single(
                    f"{schema.name}:{spec.name}",
                    f"a float array ({spec.precision.describe()})",
                    f"dtype {ds[spec.name].dtype}",
                )
            found[spec.name] = spec.precision
    return found


def apply_precision(
    ds: xr.Dataset, precisions: Mapping[str, Precision], *, round_values: bool = True
) -> xr.Dataset:
    """``ds`` with its declared precisions stated in the arrays' attrs (and their values
    rounded, lazily, with ``round_values``); precision attrs of other arrays are removed
    (only the store states a precision, where it rounded)."""
    keys = (Precision.KEEPBITS_ATTR, Precision.BOUND_ATTR, Precision.ALONG_ATTR)
    for name, var in ds.variables.items():
        if name not in precisions and any(key in var.attrs for key in keys):
            var.attrs = {k: v for k, v in var.attrs.items() if k not in keys}
    changed: dict[Hashable, xr.DataArray] = {}
    for name, precision in precisions.items():
        array = ds[name]
        along = [] if precision.along is None else [precision.along]
        if along and (along[0] not in array.dims or array.dims[0] == along[0]):
            raise StoreError.single(
                str(name), f"a dim {along[0]!r} after the first (its spectra)", f"dims {array.dims}"
            )
        if round_values:
            array = xr.apply_ufunc(
                round_precision,
                array,
                input_core_dims=[along],
                output_core_dims=[along],
                kwargs={"keepbits": precision.keepbits, "axis": -1 if along else None},
                dask="parallelized",
                dask_gufunc_kwargs={"allow_rechunk": True},
                output_dtypes=[array.dtype],
                keep_attrs=True,
            ).transpose(*array.dims)
        array.attrs = {**array.attrs, **precision.attrs}
        changed[name] = array
    coords = {k: v for k, v in changed.items() if k in ds.coords}
    data = {k: v for k, v in changed.items() if k not in ds.coords}
    return ds.assign_coords(coords).assign(data)


def precision_encoding(
    precisions: Iterable[str], encoding: dict[str, dict[str, Any]]
) -> dict[str, dict[str, Any]]:
    """Give each rounded variable :data:`PRECISION_COMPRESSORS` (unless ``encoding`` names
    its compressors); returns ``encoding``."""
    for name in precisions:
        encoding.setdefault(name, {}).setdefault("compressors", PRECISION_COMPRESSORS)
    return encoding


def _codecs(meta: Mapping[str, Any]) -> list[Mapping[str, Any]]:
    """Every codec of an array's metadata, those inside a shard's included."""
    found: list[Mapping[str, Any]] = []
    for codec in meta.get("codecs") or []:
        found.append(codec)
        if codec.get("name") == "sharding_indexed":
            found += _codecs(codec.get("configuration") or {})
    return found


def codec_problems(
    meta: Mapping[str, Any], where: str, stated: Precision | None, dtype: np.dtype
) -> list[Problem]:
    """The codecs of an array (its ``zarr.json``) against the precision its attrs state.

    Every codec must be lossless, or numcodecs' bit rounding keeping at least the bits
    stated (all the dtype's when nothing is stated).
    """
    kept = stated.keepbits if stated is not None else int(np.finfo(dtype).nmant)
    problems = []
    for codec in _codecs(meta):
        name = str(codec.get("name"))
        if name in LOSSLESS_CODECS:
            continue
        if name == _BIT_ROUND and int((codec.get("configuration") or {}).get("keepbits", -1)) >= kept:
            continue
        expected = (
            f"lossless codecs or bit rounding to >= {kept} mantissa bits "
            f"({'as its attrs state' if stated else 'no precision stated: lossless'})"
        )
        problems.append(Problem(where, expected, f"codec {json.dumps(dict(codec), default=str)}"))
    return problems


def _sample(array: xr.DataArray, meta: Mapping[str, Any]) -> list[xr.DataArray]:
    """The first and the last chunk of ``array`` along its first dim (a cheap check)."""
    shape = meta["codecs"][0]["configuration"]["chunk_shape"] if _sharded(meta) else None
    chunks = shape or meta["chunk_grid"]["configuration"]["chunk_shape"]
    first_dim = array.dims[0]
    n = array.sizes[first_dim]
    starts = sorted({0, ((n - 1) // int(chunks[0])) * int(chunks[0])})[:_SAMPLE_CHUNKS]
    rest = {dim: slice(0, int(c)) for dim, c in zip(array.dims[1:], chunks[1:], strict=True)}
    return [array.isel({first_dim: slice(s, s + int(chunks[0])), **rest}) for s in starts]


def _sharded(meta: Mapping[str, Any]) -> bool:
    codecs = meta.get("codecs") or [{}]
    return codecs[0].get("name") == "sharding_indexed"


def precision_problems(
    root: Path,
    ds: xr.Dataset,
    schema: GroupSchema,
    group: str,
    *,
    values: bool = True,
    deep: bool = False,
) -> list[Problem]:
    """Check the stored precision of the arrays of a finished group (at ``root``).

    For every array whose spec declares a precision: its codec chain (:func:`codec_problems`),
    and with ``values``, that its values carry no more mantissa bits than its attrs state: a
    sample of chunks (first and last along its first dim), or every value with ``deep``
    (chunk by chunk).
    """
    problems: list[Problem] = []
    for spec in (*schema.variables, *schema.optional_variables, *schema.coords):
        if spec.precision is None or spec.name not in ds.variables:
            continue
        array = ds[spec.name]
        where = f"{group}:{spec.name}"
        try:
            meta = json.loads((root / spec.name / "zarr.json").read_text())
        except (OSError, ValueError) as error:
            problems.append(Problem(where, "readable zarr metadata", str(error)))
            continue
        if array.dtype.kind != "f":
            continue  # the dtype check of the contract reports it
        try:
            stated = Precision.stated(array.attrs)
        except (TypeError, ValueError):
            continue  # the attrs check of the contract reports it
        problems += codec_problems(meta, where, stated, array.dtype)
        if not values or stated is None or array.size == 0:
            continue
        pieces = [array] if deep or array.ndim == 0 else _sample(array, meta)
        axis = None if stated.along is None else array.dims.index(stated.along)
        excess = sum(_excess(piece, stated.keepbits, axis) for piece in pieces)
        if excess:
            checked = "in all" if deep else "in the chunks checked (first and last)"
            problems.append(
                Problem(
                    where,
                    f"values rounded to {stated.describe()}, as its attrs state",
                    f"{excess} value(s) {checked} with more mantissa bits",
                )
            )
    return problems


def _excess(array: xr.DataArray, keepbits: int, axis: int | None) -> int:
    """:func:`excess_precision` of a (lazy) array, chunk by chunk (whole along ``axis``)."""
    data = array.data
    if not hasattr(data, "map_blocks"):
        return excess_precision(np.asarray(data), keepbits, axis)
    if axis is not None:
        data = data.rechunk({axis: -1})
    counts = data.map_blocks(
        lambda block: np.full((1,) * block.ndim, excess_precision(block, keepbits, axis)),
        dtype=np.int64,
        chunks=(1,) * data.ndim,
    )
    return int(counts.sum().compute())
