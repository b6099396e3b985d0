"""Declarative contracts for the groups of a run store and their validation.

A :class:`GroupSchema` names the variables and coordinates a group must have, with their
dims, dtypes, units and value ranges, and the attrs it must carry. :func:`validate_dataset`
checks an :class:`xarray.Dataset` against it and returns *every* problem at once.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import xarray as xr

from .errors import Problem, SchemaError

__all__ = [
    "ArraySpec",
    "GroupSchema",
    "Precision",
    "validate_dataset",
    "validate_values",
    "check_dataset",
]


@dataclass(frozen=True)
class Precision:
    """The precision a float array is stored at: ``keepbits`` mantissa bits (bit rounding).

    The run store rounds every finite value to the nearest float with ``keepbits`` explicit
    mantissa bits (ties to even, as numcodecs' ``BitRound``) before compressing it: the
    trailing mantissa bits become zeros, which compress to almost nothing, while the value
    keeps a relative error of at most half a unit in its last kept bit,

    .. math:: |\\hat x - x| \\le 2^{-(k+1)} |x|,

    :attr:`relative_bound`, for every normal float ``x`` (zeros, NaN and inf are kept as they
    are). With ``along`` (a dim, ``"wavelength"``) the values of each spectrum share one
    quantum instead, half a unit in the last kept bit of the spectrum's peak (a scale to
    integers per spectrum): a band far below its spectrum's peak keeps fewer bits, and

    .. math:: |\\hat x - x| \\le 2^{-(k+1)} \\max_{along} |\\hat x|.

    The bound is stated in the stored array's attrs (:attr:`attrs`). An array without
    those attrs was stored losslessly (before its schema declared a precision): it meets any
    bound, and is valid.

    Attributes
    ----------
    keepbits
        Explicit mantissa bits kept (float32 has 23, float64 52).
    along
        ``None``: the bound is relative to each value. A dim name: relative to the peak of
        the absolute values along that dim (each spectrum's).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series (the reconstructed radiance is known to a
       few percent: sec. 5).
    .. [2] Klöwer, M., Razinger, M., Dominguez, J. J., Düben, P. D. and Palmer, T. N.:
       Compressing atmospheric data into its real information content. Nature
       Computational Science 1, 713-724 (2021).
    """

    keepbits: int
    along: str | None = None

    KEEPBITS_ATTR = "precision_keepbits"
    """Array attr: the mantissa bits kept."""
    BOUND_ATTR = "precision_bound_relative"
    """Array attr: the relative bound ``2 ** -(keepbits + 1)`` of every stored value."""
    ALONG_ATTR = "precision_relative_to_peak_along"
    """Array attr, with ``along`` only: the dim whose peak the bound is relative to."""

    @property
    def relative_bound(self) -> float:
        """Largest relative error of a stored (normal) value: ``2 ** -(keepbits + 1)``."""
        return 2.0 ** -(self.keepbits + 1)

    @property
    def attrs(self) -> dict[str, int | float | str]:
        """The attrs the store stamps on an array it rounded."""
        along = {} if self.along is None else {self.ALONG_ATTR: self.along}
        return {self.KEEPBITS_ATTR: self.keepbits, self.BOUND_ATTR: self.relative_bound, **along}

    def describe(self) -> str:
        """``"10 mantissa bits (relative error <= 0.0488 %)"``."""
        bound = 100 * self.relative_bound
        if self.along is None:
            return f"{self.keepbits} mantissa bits (relative error <= {bound:.3g} %)"
        return (
            f"{self.keepbits} mantissa bits of each peak along {self.along} "
            f"(error <= {bound:.3g} % of the peak)"
        )

    def meets(self, required: Precision) -> bool:
        """Whether data stored at this precision is stored at ``required`` or finer (a bound
        relative to each value is finer than one relative to its spectrum's peak)."""
        return self.keepbits >= required.keepbits and self.along in (None, required.along)

    @classmethod
    def stated(cls, attrs: Mapping[str, Any]) -> Precision | None:
        """The precision an array's attrs state (``None``: stored losslessly)."""
        keepbits = attrs.get(cls.KEEPBITS_ATTR)
        along = attrs.get(cls.ALONG_ATTR)
        return None if keepbits is None else cls(int(keepbits), None if along is None else str(along))


@dataclass(frozen=True)
class ArraySpec:
    """Contract of one variable or coordinate.

    Attributes
    ----------
    name
        Variable name in the group.
    dims
        Exact dimension names, in order.
    dtype
        Either an exact dtype name (``"uint16"``, ``"float32"``) or a numpy kind
        prefixed by ``"kind:"``: ``"kind:f"`` any float, ``"kind:iu"`` any integer,
        ``"kind:UOT"`` strings (fixed-width, object or numpy StringDType).
    units
        Required value of ``attrs["units"]``; ``None`` when the array has no units.
    long_name
        Human-readable description, written by producers into ``attrs["long_name"]``.
    valid_range
        Inclusive ``(low, high)`` every finite value must lie in; checked on in-memory arrays
        always, on lazy (on-disk) ones when asked (``validate_dataset(..., values=True)``).
    finite
        Whether NaN/inf are forbidden (checked where values are checked).
    precision
        The precision the run store keeps of a float array (:class:`Precision`): its values
        rounded to that many mantissa bits before compression; ``None``: stored losslessly.
    """

    name: str
    dims: tuple[str, ...]
    dtype: str
    units: str | None = None
    long_name: str = ""
    valid_range: tuple[float, float] | None = None
    finite: bool = False
    precision: Precision | None = None

    @property
    def attrs(self) -> dict[str, str]:
        """The CF attrs a producer stamps on the array: ``units`` (where it has units) and
        ``long_name``."""
        return {**({} if self.units is None else {"units": self.units}), "long_name": self.long_name}

    def dtype_ok(self, dtype: np.dtype) -> bool:
        if self.dtype.startswith("kind:"):
            return dtype.kind in self.dtype[5:]
        return dtype == np.dtype(self.dtype)

    def describe_dtype(self) -> str:
        kinds = {
            "f": "float",
            "i": "signed int",
            "u": "unsigned int",
            "U": "str",
            "O": "object",
            "T": "str",
        }
        if self.dtype.startswith("kind:"):
            return " or ".join(dict.fromkeys(kinds.get(k, k) for k in self.dtype[5:]))
        return self.dtype


@dataclass(frozen=True)
class GroupSchema:
    """Contract of one group of a run store.

    Attributes
    ----------
    name
        Schema name, also the default group path in the store (``"raw/dark"``).
    description
        One line for the human-readable table.
    variables
        Data variables that must be present.
    coords
        Coordinates that must be present.
    attrs
        Group attrs that must be present, with a short description each.
    optional_variables
        Variables that may be present; when present they must follow their spec.
    """

    name: str
    description: str
    variables: tuple[ArraySpec, ...]
    coords: tuple[ArraySpec, ...] = ()
    attrs: Mapping[str, str] = field(default_factory=dict)
    optional_variables: tuple[ArraySpec, ...] = ()

    def provides(self, other: GroupSchema) -> bool:
        """Whether data following this schema also follows ``other`` (structural subtyping).

        True when every required variable and coordinate of ``other`` is required here too,
        with the same dims and dtype (and units, where ``other`` names them), and every
        required attr of ``other`` is required
        here. A node that needs only a camera matrix can so read any group that has one.
        """
        if other.name == self.name:
            return True
        mine = {spec.name: spec for spec in self.variables + self.coords}
        for spec in other.variables + other.coords:
            have = mine.get(spec.name)
            if have is None or (have.dims, have.dtype) != (spec.dims, spec.dtype):
                return False
            if spec.units is not None and have.units != spec.units:
                return False
        return set(other.attrs) <= set(self.attrs)

    def spec(self, name: str) -> ArraySpec:
        """The spec of variable or coordinate ``name``, required or optional.

        Raises
        ------
        SchemaError
            For a name the schema does not have, listing those it has.
        """
        specs = (*self.variables, *self.optional_variables, *self.coords)
        for spec in specs:
            if spec.name == name:
                return spec
        raise SchemaError.single(
            f"{self.name}:{name}", f"one of {[spec.name for spec in specs]}", "no such array"
        )

    @property
    def dims(self) -> tuple[str, ...]:
        """All dims named by the schema, in order of first appearance."""
        seen: dict[str, None] = {}
        for spec in self.variables + self.coords:
            seen.update(dict.fromkeys(spec.dims))
        return tuple(seen)


_VALUE_CHECK_LIMIT = 1_000_000  # elements; larger arrays are checked lazily, and only on request


def _first_bad(array: xr.DataArray, bad: np.ndarray) -> str:
    """``"first at image=2, exposure=0: -0.1"`` for the first flagged element."""
    index = tuple(int(i) for i in np.argwhere(bad)[0])
    value = float(np.asarray(array.values)[index])
    where = ", ".join(f"{dim}={i}" for dim, i in zip(array.dims, index, strict=True))
    return f"first at {where}: {value:g}" if where else f"value {value:g}"


def _check_values(where: str, array: xr.DataArray, spec: ArraySpec, *, lazy_ok: bool) -> list[Problem]:
    """NaN/inf and range checks; eager for small or in-memory arrays, with dask otherwise."""
    if not (spec.valid_range or spec.finite) or array.dtype.kind not in "fiu":
        return []
    lazy = getattr(array.variable, "chunks", None) is not None
    if lazy and array.size <= _VALUE_CHECK_LIMIT and lazy_ok:
        array = array.load()
        lazy = False
    problems: list[Problem] = []
    if not lazy and array.size <= _VALUE_CHECK_LIMIT:
        values = np.asarray(array.values, dtype=float)
        nonfinite = ~np.isfinite(values)
        if spec.finite and nonfinite.any():
            problems.append(
                Problem(
                    where,
                    "finite values",
                    f"{int(nonfinite.sum())} NaN/inf value(s) ({_first_bad(array, nonfinite)})",
                )
            )
        if spec.valid_range is not None:
            low, high = spec.valid_range
            with np.errstate(invalid="ignore"):
                outside = ~nonfinite & ((values < low) | (values > high))
            if outside.any():
                finite = values[~nonfinite]
                problems.append(
                    Problem(
                        where,
                        f"values in [{low:g}, {high:g}]",
                        f"range [{finite.min():g}, {finite.max():g}] ({int(outside.sum())} value(s) "
                        f"outside, {_first_bad(array, outside)})",
                    )
                )
        return problems
    if not lazy_ok:
        return []
    # dask only here: every command that imports the schemas would otherwise pay for
    # importing dask.array
    import dask
    import dask.array as da

    data = array.data.astype(float) if lazy else array.variable.chunk().data.astype(float)
    finite_mask = da.isfinite(data)
    nonfinite_count = (~finite_mask).sum()
    low_seen = da.where(finite_mask, data, np.inf).min()
    high_seen = da.where(finite_mask, data, -np.inf).max()
    outside_count = (
        (finite_mask & ((data < spec.valid_range[0]) | (data > spec.valid_range[1]))).sum()
        if spec.valid_range is not None
        else da.zeros((), dtype=int)
    )
    nonfinite_count, low_seen, high_seen, outside_count = dask.compute(
        nonfinite_count, low_seen, high_seen, outside_count
    )
    if spec.finite and nonfinite_count:
        problems.append(Problem(where, "finite values", f"{int(nonfinite_count)} NaN/inf value(s)"))
    if spec.valid_range is not None and outside_count:
        low, high = spec.valid_range
        problems.append(
            Problem(
                where,
                f"values in [{low:g}, {high:g}]",
                f"range [{low_seen:g}, {high_seen:g}] ({int(outside_count)} value(s) outside)",
            )
        )
    return problems


def _check_array(
    where: str, array: xr.DataArray, spec: ArraySpec, *, values: bool = False
) -> list[Problem]:
    problems: list[Problem] = []
    if tuple(array.dims) != spec.dims:
        problems.append(Problem(where, f"dims {spec.dims}", f"dims {tuple(array.dims)}"))
    if not spec.dtype_ok(array.dtype):
        problems.append(Problem(where, f"dtype {spec.describe_dtype()}", f"dtype {array.dtype}"))
    if spec.units is not None and array.attrs.get("units") != spec.units:
        found = array.attrs.get("units")
        problems.append(
            Problem(
                where,
                f"attrs['units'] == {spec.units!r}",
                "no units attr" if found is None else f"units {found!r}",
            )
        )
    return (
        problems
        + _check_precision(where, array, spec)
        + _check_values(where, array, spec, lazy_ok=values)
    )


def _check_precision(where: str, array: xr.DataArray, spec: ArraySpec) -> list[Problem]:
    """The precision an array's attrs state against its contract (:class:`Precision`).

    No precision attrs: stored losslessly (before the contract declared a precision), valid.
    Stated: both attrs, a bound that is the one of the bits kept, and at least as many bits
    as the contract asks (fewer than the dtype has).
    """
    if spec.precision is None:
        return []
    keys = (Precision.KEEPBITS_ATTR, Precision.BOUND_ATTR)
    present = [key for key in keys if key in array.attrs]
    if not present:
        return []
    if len(present) == 1:
        missing = next(key for key in keys if key not in present)
        return [Problem(f"{where}.attrs", f"attrs {keys[0]!r} and {keys[1]!r}", f"no {missing!r}")]
    keepbits, bound = array.attrs[keys[0]], array.attrs[keys[1]]
    mantissa = np.finfo(array.dtype).nmant if array.dtype.kind == "f" else 0
    if not isinstance(keepbits, int | np.integer) or not (
        spec.precision.keepbits <= keepbits <= mantissa
    ):
        return [
            Problem(
                f"{where}.attrs",
                f"{keys[0]} an integer in [{spec.precision.keepbits}, {mantissa}] "
                f"({spec.precision.describe()} or finer)",
                f"{keepbits!r}",
            )
        ]
    stated = Precision.stated(array.attrs) or Precision(int(keepbits))
    if not stated.meets(spec.precision) or (stated.along is not None and stated.along not in array.dims):
        return [
            Problem(
                f"{where}.attrs",
                f"{Precision.ALONG_ATTR} absent (a bound relative to each value)"
                + ("" if spec.precision.along is None else f" or {spec.precision.along!r}"),
                f"{stated.along!r}",
            )
        ]
    if not isinstance(bound, float | int | np.floating) or not math.isclose(
        float(bound), stated.relative_bound, rel_tol=1e-9
    ):
        return [
            Problem(
                f"{where}.attrs",
                f"{keys[1]} == {stated.relative_bound!r} (2 ** -({keepbits} + 1))",
                f"{bound!r}",
            )
        ]
    return []


def validate_dataset(
    ds: xr.Dataset, schema: GroupSchema, *, group: str | None = None, values: bool = False
) -> list[Problem]:
    """Check ``ds`` against ``schema`` and return every problem found.

    Parameters
    ----------
    ds
        The group's data, in memory or lazy.
    schema
        Its contract.
    group
        Group path used in the messages (default: the schema name).
    values
        Also check the values of lazy (dask-backed, e.g. on-disk) arrays against the ranges
        and NaN/inf rules of the contract: small ones are loaded, large ones are reduced
        with dask chunk by chunk. Without it only in-memory arrays are value-checked (what
        a writer can afford before writing).

    Returns
    -------
    list of Problem
        Empty when the dataset follows the contract.
    """
    label = group or schema.name
    problems: list[Problem] = []
    for spec in schema.variables:
        if spec.name not in ds.data_vars:
            where = f"{label}:{spec.name}"
            if spec.name in ds.coords:
                problems.append(Problem(where, "a data variable", "a coordinate"))
            else:
                problems.append(Problem(where, f"data variable with dims {spec.dims}", "nothing"))
            continue
        problems += _check_array(f"{label}:{spec.name}", ds[spec.name], spec, values=values)
    for spec in schema.optional_variables:
        if spec.name in ds.data_vars:
            problems += _check_array(f"{label}:{spec.name}", ds[spec.name], spec, values=values)
    for spec in schema.coords:
        where = f"{label}:{spec.name}"
        if spec.name not in ds.coords:
            problems.append(Problem(where, f"coordinate with dims {spec.dims}", "nothing"))
            continue
        problems += _check_array(where, ds.coords[spec.name], spec, values=values)
    for key, meaning in schema.attrs.items():
        if key not in ds.attrs:
            problems.append(Problem(f"{label}.attrs", f"attr {key!r} ({meaning})", "nothing"))
    # Every dim of the contract must have one consistent size across arrays (xarray enforces
    # that within a Dataset), and must not be empty.
    for dim in schema.dims:
        if dim in ds.sizes and ds.sizes[dim] == 0:
            problems.append(Problem(f"{label}:{dim}", "a non-empty dimension", "size 0"))
    return problems


def validate_values(ds: xr.Dataset, schema: GroupSchema, *, group: str | None = None) -> list[Problem]:
    """Only the value rules of ``schema`` (NaN/inf, ranges), for every array ``ds`` has.

    Lazy arrays are checked too: small ones loaded, large ones reduced with dask. This is
    what a flow checks of its inputs before a node's numerics run.
    """
    label = group or schema.name
    problems: list[Problem] = []
    for spec in schema.variables + schema.optional_variables + schema.coords:
        if spec.name in ds.variables and tuple(ds[spec.name].dims) == spec.dims:
            problems += _check_values(f"{label}:{spec.name}", ds[spec.name], spec, lazy_ok=True)
    return problems


def check_dataset(ds: xr.Dataset, schema: GroupSchema, *, group: str | None = None) -> None:
    """Raise :class:`SchemaError` listing every problem if ``ds`` breaks ``schema``."""
    problems = validate_dataset(ds, schema, group=group)
    if problems:
        label = group or schema.name
        raise SchemaError(f"group {label!r} does not follow schema {schema.name!r}:", problems)
