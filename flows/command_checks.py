"""What the command line checks before it loads Prefect or the engine: answers in milliseconds.

A mistyped store path, flow name or ``--set`` would otherwise be reported only after Prefect
and the science stack load (seconds). These checks need only the standard library and the
cached node catalogue (:func:`.node_listing.node_catalogue`: every node's input groups and
parameter JSON schemas, every flow's nodes), so a wrong command fails at once with the
closest valid names ("did you mean") and short lists of choices. The engine checks
everything again when the flow runs; these checks only refuse what it would refuse.

- the store: a capture folder (``manifest.csv``, ``capture.toml``) is pointed at
  ``spectralize ingest``; a missing path is an error unless the flow makes the store (its
  first nodes read nothing); a directory without ``zarr.json`` is not a store;
- the flow or node name;
- each ``--set``: the parameter's name (node and parameter), its type, bounds and allowed
  values, from the parameter's JSON schema;
- ``--dask-address``: a TCP connection to the scheduler within :data:`DASK_TIMEOUT_S`.
"""

from __future__ import annotations

import difflib
import socket
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from .assignments import UsageError

__all__ = [
    "DASK_TIMEOUT_S",
    "did_you_mean",
    "shortened",
    "check_store",
    "check_flow",
    "check_assignments",
    "check_dask_address",
    "check_run",
]

#: Seconds the command line waits for a dask scheduler to accept a connection.
DASK_TIMEOUT_S = 2.0
_CAPTURE_FILES = ("manifest.csv", "capture.toml")


def did_you_mean(word: str, candidates: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest candidates, or nothing."""
    close = difflib.get_close_matches(word, list(candidates), n=3, cutoff=0.6)
    if not close:
        return ""
    return f"; did you mean {' or '.join(repr(c) for c in close)}?"


def shortened(items: Sequence[str], limit: int = 8) -> str:
    """``a, b, c`` or, past ``limit`` items, the first ones and how many more."""
    items = list(items)
    if len(items) <= limit:
        return ", ".join(items)
    return f"{', '.join(items[:limit])} and {len(items) - limit} more"


def check_store(path: str | Path, *, may_be_missing: bool = False) -> None:
    """Refuse a path that is not a run store (``may_be_missing``: or not there at all).

    Raises
    ------
    UsageError
        For a capture folder (naming ``spectralize ingest``), a missing path, or a
        directory that is not a zarr store.
    """
    path = Path(path)
    if path.is_dir() and any((path / name).is_file() for name in _CAPTURE_FILES):
        raise UsageError(
            f"{str(path)!r} is a capture folder, not a run store; ingest it first: "
            f"spectralize ingest {path} {path.name}.zarr"
        )
    if not path.exists():
        if may_be_missing:
            return
        near = did_you_mean(path.name, (p.name for p in _siblings(path)))
        raise UsageError(f"run store {str(path)!r} does not exist{near}")
    if not path.is_dir() or not (path / "zarr.json").is_file():
        raise UsageError(f"{str(path)!r} is not a run store: not a zarr v3 store (no zarr.json)")


def _siblings(path: Path) -> list[Path]:
    try:
        return [p for p in (path.parent if str(path.parent) else Path(".")).iterdir() if p.is_dir()]
    except OSError:
        return []


def check_flow(name: str, catalogue: Mapping[str, Any]) -> tuple[list[str], list[str]]:
    """The nodes a flow (or a single node) runs and the groups it reads from the store.

    Raises
    ------
    UsageError
        For a name that is neither a flow nor a node, with the closest names.
    """
    flows, nodes = catalogue["flows"], catalogue["nodes"]
    if name in flows:
        return list(flows[name]["nodes"]), list(flows[name]["inputs"])
    if name in nodes:
        return [name], list(nodes[name]["inputs"])
    raise UsageError(
        f"unknown flow or node {name!r}{did_you_mean(name, [*flows, *nodes])} "
        f"(flows: {', '.join(sorted(flows))}; or one of {len(nodes)} nodes: `spectralize nodes`)"
    )


def _kind_text(schema: Mapping[str, Any]) -> str:
    """``an integer >= 1``, ``a number > 0 or null``, ``one of: a, b``."""
    if "anyOf" in schema:
        return " or ".join(_kind_text(option) for option in schema["anyOf"])
    if "enum" in schema:
        return f"one of: {shortened([str(v) for v in schema['enum']])}"
    kind = schema.get("type")
    words = {
        "integer": "an integer",
        "number": "a number",
        "string": "text",
        "boolean": "true or false",
        "null": "null (None)",
        "array": "a list",
        "object": "a mapping",
    }
    text = words.get(kind, "a value") if isinstance(kind, str) else "a value"
    bounds = [
        f"{sign} {schema[key]:g}"
        for key, sign in (
            ("minimum", ">="),
            ("exclusiveMinimum", ">"),
            ("maximum", "<="),
            ("exclusiveMaximum", "<"),
        )
        if isinstance(schema.get(key), int | float)
    ]
    return f"{text} {' and '.join(bounds)}".strip() if bounds else text


def _fits(value: Any, schema: Mapping[str, Any]) -> bool:
    """Whether pydantic (lax mode) would accept ``value`` for ``schema``; ``True`` for what
    this does not know (the engine decides then)."""
    if "anyOf" in schema:
        return any(_fits(value, option) for option in schema["anyOf"])
    if "enum" in schema:
        return value in schema["enum"]
    kind = schema.get("type")
    if kind == "null":
        return value is None
    if kind == "boolean":
        return isinstance(value, bool) or value in (0, 1)
    if kind == "string":
        return isinstance(value, str)
    if kind == "array":
        items = schema.get("items") or {}
        prefix = schema.get("prefixItems")
        if not isinstance(value, list | tuple):
            return False
        if prefix is not None:
            return len(value) == len(prefix) and all(
                _fits(v, s) for v, s in zip(value, prefix, strict=True)
            )
        return all(_fits(v, items) for v in value)
    if kind in ("integer", "number"):
        if isinstance(value, bool) or not isinstance(value, int | float):
            return False
        if kind == "integer" and not float(value).is_integer():
            return False
        checks = (
            ("minimum", lambda v, b: v >= b),
            ("exclusiveMinimum", lambda v, b: v > b),
            ("maximum", lambda v, b: v <= b),
            ("exclusiveMaximum", lambda v, b: v < b),
        )
        return all(
            test(value, schema[key]) for key, test in checks if isinstance(schema.get(key), int | float)
        )
    return True


def check_assignments(
    assignments: Mapping[str, Any], node_names: Sequence[str], catalogue: Mapping[str, Any]
) -> list[str]:
    """One line per ``--set`` that the flow's nodes would refuse (empty: all fine).

    Keys are ``NODE.PARAM`` or a bare ``PARAM`` that exactly one of the flow's nodes has.
    """
    nodes = catalogue["nodes"]
    known = {n: nodes[n]["parameters"] for n in node_names if n in nodes}
    problems = []
    for key, value in assignments.items():
        node, _, parameter = key.rpartition(".")
        if node and node not in known:
            others = "a node of this flow" if node in nodes else "a node"
            problems.append(
                f"--set {key}: {node!r} is not {others}{did_you_mean(node, known)} "
                f"(this flow's nodes: {shortened(list(known))})"
            )
            continue
        owners = [n for n in ([node] if node else known) if parameter in known[n]]
        if not owners:
            if node:
                names = list(known[node])
                near = did_you_mean(parameter, names)
                where = f"node {node!r} has no parameter {parameter!r}{near}"
                choices = f" (its parameters: {shortened(names)})" if not near else ""
            else:
                full = [f"{n}.{p}" for n in known for p in known[n]]
                near = did_you_mean(parameter, [p for n in known for p in known[n]])
                where = f"no node of this flow has a parameter {parameter!r}{near}"
                choices = f" ({len(full)} parameters: `spectralize nodes`)"
            problems.append(f"--set {key}: {where}{choices}")
            continue
        if len(owners) > 1:
            problems.append(
                f"--set {key}: a parameter of nodes {', '.join(owners)}; write NODE.{parameter}"
            )
            continue
        schema = known[owners[0]][parameter]
        if not _fits(value, schema):
            expected = _kind_text(schema)
            near = ""
            allowed = [str(v) for v in _enum_schema(schema).get("enum", ())]
            if isinstance(value, str) and allowed:
                near = did_you_mean(value, allowed)
                expected = (
                    f"one of: {', '.join(allowed)}"
                    if len(allowed) <= 8 or not near
                    else f"one of {len(allowed)} values"
                )
            problems.append(f"--set {owners[0]}.{parameter}: expected {expected}, got {value!r}{near}")
    return problems


def _enum_schema(schema: Mapping[str, Any]) -> Mapping[str, Any]:
    """The option of ``schema`` that lists allowed values, or ``{}``."""
    if "enum" in schema:
        return schema
    for option in schema.get("anyOf", ()):
        if "enum" in option:
            return option
    return {}


def check_dask_address(address: str, timeout: float = DASK_TIMEOUT_S) -> None:
    """Refuse a scheduler address that does not accept a TCP connection within ``timeout``.

    Raises
    ------
    UsageError
        Naming the address and what failed (dask itself would wait out its connect timeout,
        and only when the first dask node starts).
    """
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address
    if scheme not in ("tcp", "tls"):
        return  # inproc://, ucx://...: dask checks these itself
    host, _, port = rest.rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    if not port.isdigit():
        raise UsageError(f"--dask-address {address!r}: expected tcp://HOST:PORT")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout):
            pass
    except OSError as error:
        reason = "no answer" if isinstance(error, TimeoutError) else error.strerror or str(error)
        raise UsageError(
            f"cannot reach the dask scheduler at {address} ({reason} within {timeout:g} s); "
            "check --dask-address and that `dask scheduler` runs"
        ) from None


def check_run(
    flow: str,
    store: str | Path | None,
    assignments: Mapping[str, Any],
    *,
    dask_address: str | None = None,
    catalogue: Mapping[str, Any] | None = None,
) -> None:
    """Everything ``spectralize run`` can check without loading the engine, all at once.

    ``store`` is ``None`` where the command makes the store itself (``spectralize demo``).

    Raises
    ------
    UsageError
        Listing every problem found (flow name, store, ``--set``, dask address).
    """
    if catalogue is None:
        from .node_listing import node_catalogue

        catalogue = node_catalogue()
    node_names, inputs = check_flow(flow, catalogue)
    problems: list[str] = []
    try:
        if store is not None:
            check_store(store, may_be_missing=not inputs)
    except UsageError as error:
        text = str(error)
        if inputs and not Path(store).exists():  # say what the store must hold, and how
            text += (
                f"; {flow!r} reads {shortened(sorted(inputs), 4)}: make the store with "
                "`spectralize ingest CAPTURE_DIR STORE` (or `spectralize run simulate STORE`)"
            )
        problems.append(text)
    problems += check_assignments(assignments, node_names, catalogue)
    if dask_address:
        try:
            check_dask_address(dask_address)
        except UsageError as error:
            problems.append(str(error))
    if len(problems) == 1:
        raise UsageError(problems[0])
    if problems:
        raise UsageError("\n".join([f"{len(problems)} problems:", *(f"  - {p}" for p in problems)]))
