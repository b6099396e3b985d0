"""Node declarations: :class:`Node`, its :class:`Parameters` and :class:`Choices` from a table.

A node's parameters are the keyword-only arguments of its function: :class:`Node` derives a
frozen pydantic model from the annotated signature, so defaults, types and constraints are
written once, where the science is. A parameter whose values are the keys of a method table
(solvers, baselines, response models, recipes) is annotated with :class:`Choices`, and a typo
then fails when the parameters are parsed, which :func:`~spectralize.engine.check_graph`
does before anything runs.

A node may declare a value check (:attr:`Node.check`): what its function would refuse in its
inputs' values before computing (unsorted exposure times, frames entirely saturated). The
node calls it before its function, and ``spectralize validate --flow`` calls the same hook on a
store, so a store that passes validation is not refused by the flow for its values.
"""

from __future__ import annotations

import inspect
import re
import typing
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import xarray as xr
from pydantic import BaseModel, ConfigDict, ValidationError, create_model
from pydantic.fields import FieldInfo
from pydantic_core import PydanticCustomError, core_schema

from spectralize.schemas import (
    GROUP_SCHEMAS,
    NodeDeclarationError,
    ParameterError,
    Problem,
    SchemaError,
    SpectralizeError,
    validate_dataset,
)

__all__ = [
    "Parameters",
    "Choices",
    "Node",
    "ValueCheck",
    "parameters_from_signature",
    "choices_of",
]

ValueCheck = Callable[[Mapping[str, xr.Dataset], "Parameters"], Sequence[SpectralizeError]]
"""A node's value check: ``check(inputs, parameters) -> refusals``.

``inputs`` are the node's input groups by argument (lazy; only those that exist: ``validate``
calls it on a store where the groups an earlier step makes may be missing, and the check then
checks what it can), ``parameters`` its parsed :class:`Parameters`. It returns every error the
node's function would raise for those values before computing (empty: accepted). Pure and
cheap: it reads only what it needs.
"""


class Parameters(BaseModel):
    """Base of every node's parameter model: frozen, typed, unknown keys are an error."""

    model_config = ConfigDict(frozen=True, extra="forbid")


@dataclass(frozen=True, eq=False)
class Choices:
    """Annotation marker: the parameter's value must be a key of ``table``.

    Use it as ``Annotated[str, Choices(SOLVER_METHODS)]``. The table is read when a value is
    validated, so methods registered into it later are accepted too. An invalid value gives
    a validation error that lists the allowed keys; ``None`` passes (for ``str | None``
    parameters whose ``None`` means "the default of something else").

    Attributes
    ----------
    table
        The method table (``{name: implementation}``).
    name
        What the table holds, for messages (``"solver method"``; optional).
    """

    table: Mapping[str, Any]
    name: str = ""

    @property
    def allowed(self) -> tuple[str, ...]:
        """The allowed values, sorted."""
        return tuple(sorted(self.table))

    def _check(self, value: Any) -> Any:
        if value is None or (isinstance(value, str) and value in self.table):
            return value
        allowed = ", ".join(map(repr, self.allowed)) or "none (the table is empty)"
        kind = f" ({self.name})" if self.name else ""
        raise PydanticCustomError(
            "choice", "one of: {allowed}{kind}", {"allowed": allowed, "kind": kind}
        )

    def __get_pydantic_core_schema__(self, source: Any, handler: Any) -> core_schema.CoreSchema:
        return core_schema.no_info_after_validator_function(self._check, handler(source))

    def __get_pydantic_json_schema__(self, schema: Any, handler: Any) -> dict[str, Any]:
        json_schema = handler(schema)
        json_schema["enum"] = list(self.allowed)
        return json_schema


def choices_of(info: FieldInfo) -> tuple[str, ...] | None:
    """The allowed values of a parameter field (from :class:`Choices` or a ``Literal``)."""
    pending: list[Any] = [*info.metadata, info.annotation]
    while pending:  # walk Annotated metadata, unions and Optional
        item = pending.pop(0)
        if isinstance(item, Choices):
            return item.allowed
        if typing.get_origin(item) is typing.Literal:
            return tuple(str(value) for value in typing.get_args(item))
        pending += getattr(item, "__metadata__", ())
        pending += typing.get_args(item)
    return None


_SECTION = re.compile(
    r"^\s*Parameters\s*\n\s*-{3,}\s*\n(?P<body>.*?)(?:\n\s*\n\s*\w[\w ]*\n\s*-{3,}|\Z)", re.S | re.M
)


def _docstring_descriptions(function: Callable[..., Any]) -> dict[str, str]:
    """First line of each entry of the numpydoc ``Parameters`` section of ``function``."""
    doc = inspect.getdoc(function) or ""
    match = _SECTION.search(doc)
    if not match:
        return {}
    found: dict[str, str] = {}
    names: list[str] = []
    for line in match.group("body").splitlines():
        if line and not line[0].isspace():
            names = [n.strip() for n in line.split(":")[0].split(",") if n.strip()]
            for name in names:
                found.setdefault(name, "")
        elif line.strip() and names:
            for name in names:
                if not found[name]:
                    found[name] = line.strip()
            names = [n for n in names if not found[n]]
    return {name: text for name, text in found.items() if text}


def _camel(name: str) -> str:
    return "".join(part.title() for part in name.split("_")) or "Node"


def parameters_from_signature(
    function: Callable[..., Any],
    *,
    exclude: typing.Iterable[str] = (),
    name: str | None = None,
) -> type[Parameters]:
    """Derive a frozen :class:`Parameters` model from ``function``'s keyword-only arguments.

    Each keyword-only argument (not in ``exclude``, the node's inputs) becomes a field with
    the argument's annotation and default; ``Annotated[T, Field(...)]`` and
    ``Annotated[T, Choices(table)]`` metadata are honoured; an argument without a default is
    a required parameter. A field's description, where ``Field`` gives none, is the first
    line of the argument's entry in the function's numpydoc ``Parameters`` section.

    Raises
    ------
    NodeDeclarationError
        When an annotation cannot be resolved.
    """
    target = inspect.unwrap(function)
    label = name or getattr(function, "__qualname__", repr(function))
    try:
        hints = typing.get_type_hints(target, include_extras=True)
    except Exception as error:  # a forward reference that does not resolve
        raise NodeDeclarationError.single(
            f"parameters of {label}",
            "annotations that resolve in the function's module",
            f"{type(error).__name__}: {error}",
        ) from None
    descriptions = _docstring_descriptions(target)
    excluded = set(exclude)
    fields: dict[str, Any] = {}
    for parameter in inspect.signature(function).parameters.values():
        if parameter.kind is not parameter.KEYWORD_ONLY or parameter.name in excluded:
            continue
        annotation = hints.get(parameter.name, Any)
        default = ... if parameter.default is parameter.empty else parameter.default
        has_description = any(
            isinstance(m, FieldInfo) and m.description for m in getattr(annotation, "__metadata__", ())
        )
        text = descriptions.get(parameter.name)
        if text and not has_description:
            fields[parameter.name] = (annotation, FieldInfo(default=default, description=text))
        else:
            fields[parameter.name] = (annotation, default)
    model_name = f"{_camel(name or str(getattr(target, '__name__', 'node')))}Parameters"
    model = create_model(model_name, __base__=Parameters, __module__=target.__module__, **fields)
    model.__doc__ = (
        f"Parameters of :func:`{target.__module__}.{target.__qualname__}` "
        "(derived from its keyword-only arguments)."
    )
    return model


@dataclass(frozen=True)
class Node:
    """Declaration of one node.

    Attributes
    ----------
    name
        Unique node name (``"dark_average"``).
    function
        Pure function: ``function(**inputs, **parameters) -> Dataset | {group: Dataset}``.
        Its input arguments receive lazy :class:`xarray.Dataset` objects.
    inputs
        Function argument -> schema name of the group it reads (also the default group).
        Before the function runs, each input is checked against its schema's structure.
    outputs
        Schema names of the groups it writes (also the default group names).
    parameters
        Parameter model (subclass of :class:`Parameters`); each field is a keyword of
        ``function``. Leave it out (the base :class:`Parameters`) to derive it from the
        function's keyword-only arguments (:func:`parameters_from_signature`).
    version
        Bump it when the results change: it is part of every output's fingerprint.
    description
        One line for ``spectralize nodes``.
    chunks
        Output group -> chunk size per dim on disk.
    resumable_along
        Output group -> dim along which it is written region by region (resumable).
    read_by_shard
        Input arguments the flow reads in dask chunks of whole shards
        (:meth:`~spectralize.store.RunStore.shard_chunks`): for a node that streams a whole
        group, so that a full run of small frames is a task per shard, not per image.
    check
        The node's value check (:data:`ValueCheck`), run before its function and by
        ``spectralize validate --flow``; ``None``: the schemas' checks only.
    """

    name: str
    function: Callable[..., Any]
    inputs: Mapping[str, str]
    outputs: tuple[str, ...]
    parameters: type[Parameters] = Parameters
    version: str = "1"
    description: str = ""
    chunks: Mapping[str, Mapping[str, int]] = field(default_factory=dict)
    resumable_along: Mapping[str, str] = field(default_factory=dict)
    read_by_shard: tuple[str, ...] = ()
    check: ValueCheck | None = None

    def __post_init__(self) -> None:
        problems: list[Problem] = []
        label = f"node {self.name!r}"
        try:
            signature = inspect.signature(self.function)
        except (TypeError, ValueError):
            signature = None
        if self.parameters is Parameters:
            if signature is None:
                raise NodeDeclarationError.single(
                    f"{label} parameters",
                    "a function with an inspectable signature, or parameters=<a Parameters model>",
                    repr(self.function),
                )
            object.__setattr__(
                self,
                "parameters",
                parameters_from_signature(self.function, exclude=self.inputs, name=self.name),
            )
        if signature is not None:
            accepts_any = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
            names = set(signature.parameters)
            function = getattr(self.function, "__qualname__", repr(self.function))
            for argument in self.inputs:
                if argument not in names and not accepts_any:
                    problems.append(
                        Problem(
                            f"{label} input {argument!r}",
                            f"an argument of {function}",
                            "no such argument",
                        )
                    )
            for argument in self.parameters.model_fields:
                if argument not in names and not accepts_any:
                    problems.append(
                        Problem(
                            f"{label} parameter {argument!r}",
                            f"a keyword of {function}",
                            "no such keyword",
                        )
                    )
        if not self.outputs:
            problems.append(Problem(f"{label} outputs", "at least one output", "none"))
        for group in list(self.chunks) + list(self.resumable_along):
            if group not in self.outputs:
                problems.append(
                    Problem(
                        f"{label} chunks/resumable_along {group!r}",
                        f"one of the outputs {list(self.outputs)}",
                        "not an output",
                    )
                )
        for argument in self.read_by_shard:
            if argument not in self.inputs:
                problems.append(
                    Problem(
                        f"{label} read_by_shard {argument!r}",
                        f"one of the inputs {list(self.inputs)}",
                        "not an input",
                    )
                )
        if problems:
            raise NodeDeclarationError(f"node {self.name!r} is declared wrongly:", problems)

    def parse_parameters(self, values: Mapping[str, Any] | Parameters | None = None) -> Parameters:
        """Validate ``values`` into this node's frozen parameter model.

        Raises
        ------
        ParameterError
            Listing every unknown key (with the known ones) and every invalid value (for a
            :class:`Choices` parameter: with the allowed values).
        """
        if isinstance(values, self.parameters):
            return values
        values = dict(values or {})
        try:
            return self.parameters(**values)
        except ValidationError as error:
            known = ", ".join(self.parameters.model_fields) or "none"
            problems = []
            for item in error.errors():
                key = ".".join(str(p) for p in item["loc"]) or "?"
                if item["type"] == "extra_forbidden":
                    problems.append(
                        Problem(f"{self.name}.{key}", f"one of: {known}", "an unknown parameter")
                    )
                else:
                    problems.append(Problem(f"{self.name}.{key}", item["msg"], repr(item.get("input"))))
            raise ParameterError(f"invalid parameters for node {self.name!r}:", problems) from None

    def check_inputs(self, inputs: Mapping[str, xr.Dataset]) -> None:
        """Check each input against the structure of the schema declared for it.

        Structural only on lazy data (names, dims, dtypes, units, attrs; values only of
        coordinates and small in-memory arrays), so it costs no dask computation. A group of
        another schema that provides the declared one passes: extra variables are allowed.

        Raises
        ------
        SchemaError
            Listing every problem of every input, each naming the node and the argument.
        """
        problems: list[Problem | str] = []
        missing = sorted(set(self.inputs) - set(inputs))
        for argument in missing:
            problems.append(
                Problem(
                    f"node {self.name!r} input {argument!r}",
                    f"a Dataset of schema {self.inputs[argument]!r}",
                    "nothing",
                )
            )
        for argument, schema_name in self.inputs.items():
            if argument not in inputs or schema_name not in GROUP_SCHEMAS:
                continue
            data = inputs[argument]
            if not isinstance(data, xr.Dataset):
                problems.append(
                    Problem(
                        f"node {self.name!r} input {argument!r}",
                        "an xarray.Dataset",
                        type(data).__name__,
                    )
                )
                continue
            problems += validate_dataset(
                data, GROUP_SCHEMAS[schema_name], group=f"{self.name}({argument}: {schema_name})"
            )
        if problems:
            raise SchemaError(
                f"node {self.name!r}: inputs do not follow their declared "
                f"schemas ({len(problems)} problem(s)):",
                problems,
            )

    def refusals(
        self, inputs: Mapping[str, xr.Dataset], parameters: Mapping[str, Any] | Parameters | None = None
    ) -> list[SpectralizeError]:
        """What the node's value check refuses in ``inputs`` (empty when it has none).

        ``inputs`` may lack groups (those an earlier step of a flow makes); the check then
        checks the ones given.
        """
        if self.check is None:
            return []
        return list(self.check(inputs, self.parse_parameters(parameters)))

    def __call__(
        self,
        inputs: Mapping[str, xr.Dataset] | None = None,
        parameters: Mapping[str, Any] | Parameters | None = None,
    ) -> dict[str, xr.Dataset]:
        """Check the inputs, run the node's function and return ``{output schema: Dataset}``.

        Raises
        ------
        ParameterError
            For invalid parameters.
        SchemaError
            For inputs that are missing or break their declared schemas (nothing runs).
        SpectralizeError
            The first refusal of the node's value check (nothing runs); the others are
            noted on it.
        """
        params = self.parse_parameters(parameters)
        inputs = dict(inputs or {})
        self.check_inputs(inputs)
        refused = self.refusals(inputs, params)
        if refused:
            first = refused[0]
            for other in refused[1:]:
                first.add_note(f"and: {other.summary or other}")
            raise first
        result = self.function(**inputs, **params.model_dump())
        if isinstance(result, xr.Dataset):
            if len(self.outputs) != 1:
                raise SpectralizeError.single(
                    f"node {self.name!r} result",
                    f"{{group: Dataset}} for outputs {list(self.outputs)}",
                    f"one Dataset (returned one Dataset but declares outputs {self.outputs})",
                )
            return {self.outputs[0]: result}
        if not isinstance(result, Mapping) or set(result) != set(self.outputs):
            found = sorted(result) if isinstance(result, Mapping) else type(result).__name__
            raise SpectralizeError.single(
                f"node {self.name!r} result", f"{{group: Dataset}} for {list(self.outputs)}", f"{found}"
            )
        return dict(result)

    def describe_parameters(self) -> list[tuple[str, str, Any, str]]:
        """(name, type, default, description) of every parameter."""
        rows = []
        for name, info in self.parameters.model_fields.items():
            annotation = (
                info.annotation.__name__
                if isinstance(info.annotation, type)
                else str(info.annotation).replace("typing.", "")
            )
            default = (
                info.get_default(call_default_factory=True) if not info.is_required() else "(required)"
            )
            rows.append((name, annotation, default, info.description or ""))
        return rows

    def parameter_choices(self) -> dict[str, tuple[str, ...]]:
        """Parameter name -> allowed values, for parameters with a :class:`Choices` table or a
        ``Literal`` type."""
        found = {}
        for name, info in self.parameters.model_fields.items():
            allowed = choices_of(info)
            if allowed is not None:
                found[name] = allowed
        return found
