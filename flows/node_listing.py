"""The text of ``spectralize nodes`` and the catalogue the command line checks ``--set``
against, cached on disk so that both answer without importing the science.

The catalogue (:func:`node_catalogue`) is the same knowledge as data: every node's input
groups and parameters' JSON schemas (types, bounds, allowed values), every flow's nodes
and the groups it reads from the store (:mod:`.command_checks` uses it). Both are rendered
from one load of the registry and cached together.

Listing the nodes needs every node's parameter model, which the engine derives from the
node function's signature: loading a node imports its stage (xarray, dask, zarr: the
slow part of the command). The listing changes only when the installed nodes or their
sources change, so it is cached under a key computed without importing any of them:

- the entry points of the group ``spectralize.nodes`` (name, target, distribution and its
  version), Python's version, and pydantic's (the parameter models);
- the size and modification time of every ``.py`` file in the package of each entry
  point's module and in spectralize's engine, schemas and flows (what decides the text).

An edited node, a new plugin or an upgraded distribution gives a new key. A listing whose
discovery warned (a plugin that failed to load) is not cached, so the warning shows every
time. The cache lives in ``$SPECTRALIZE_CACHE_DIR``, else ``$XDG_CACHE_HOME/spectralize``,
else ``~/.cache/spectralize``; a cache that cannot be written is skipped.
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import sys
import warnings
from collections.abc import Iterable, Iterator
from importlib.metadata import entry_points, version
from importlib.util import find_spec
from pathlib import Path
from typing import Any

from .assignments import format_value, type_text

__all__ = ["node_listing", "node_catalogue", "listing_key", "cache_dir"]

ENTRY_POINT_GROUP = "spectralize.nodes"  # engine.discovery's; not imported from there (heavy)
# Sources that decide the listing besides the nodes' own packages
LISTING_SOURCES = ("spectralize.engine", "spectralize.schemas", "spectralize.flows")


def cache_dir() -> Path:
    """Where the cached listing lives (see the module docstring)."""
    if own := os.environ.get("SPECTRALIZE_CACHE_DIR"):
        return Path(own)
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "spectralize"


def _package_files(module: str) -> Iterator[Path]:
    """The ``.py`` files of the outermost regular package on ``module``'s dotted path whose
    folder holds ``module`` (for ``spectralize.nodes.calibration.declarations``: all of
    ``spectralize.nodes``, since ``spectralize``'s own folder holds only its ``__init__``; for
    a plugin ``lab.nodes``: all of ``lab``), found without executing ``module`` or that package
    (only the parents above it are imported)."""
    parts = module.split(".")
    for end in range(1, len(parts) + 1):
        try:
            spec = find_spec(".".join(parts[:end]))
        except (ImportError, ValueError):
            return
        if spec is None:
            return
        if spec.origin in (None, "namespace"):
            continue
        roots = [Path(root) for root in spec.submodule_search_locations or ()]
        if not roots:  # a plain module
            yield Path(spec.origin)
            return
        rest = parts[end:]
        for root in roots:
            inside = root.joinpath(*rest)
            if not rest or inside.with_suffix(".py").is_file() or (inside / "__init__.py").is_file():
                yield from sorted(root.rglob("*.py"))
                return


def listing_key(modules: Iterable[str] | None = None) -> str:
    """A digest of everything the node listing depends on (see the module docstring)."""
    digest = hashlib.sha256(sys.version.encode())
    digest.update(version("pydantic").encode())
    eps = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda ep: (ep.name, ep.value))
    sources = set(LISTING_SOURCES if modules is None else modules)
    for ep in eps:
        dist = getattr(ep, "dist", None)
        origin = f"{dist.name} {dist.version}" if dist is not None else ""
        digest.update(f"{ep.name}={ep.value} ({origin})\n".encode())
        sources.add(ep.module)
    seen: set[Path] = set()
    for module in sorted(sources):
        for path in _package_files(module):
            if path in seen:
                continue
            seen.add(path)
            try:
                stat = path.stat()
            except OSError:
                continue
            digest.update(f"{path}:{stat.st_size}:{stat.st_mtime_ns}\n".encode())
    return digest.hexdigest()[:32]


def _registry() -> tuple[dict, bool]:
    """The installed nodes, and whether discovery went without warnings (then what is
    rendered from them may be cached); the warnings are shown again."""
    from spectralize.engine import registry

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        nodes = registry()
    for warning in caught:
        warnings.warn_explicit(warning.message, warning.category, warning.filename, warning.lineno)
    return nodes, not caught and bool(nodes)


def _render(nodes: dict) -> str:
    """The listing of ``nodes`` (the registry)."""
    lines = []
    for name, entry in sorted(nodes.items()):
        node = entry.node
        lines.append(f"{name}  (version {node.version})")
        if node.description:
            lines.append(f"    {node.description}")
        lines.append(f"    from:    {entry.source}")
        inputs = ", ".join(f"{arg} <- {group}" for arg, group in node.inputs.items()) or "none"
        lines.append(f"    inputs:  {inputs}")
        lines.append(f"    outputs: {', '.join(node.outputs)}")
        choices = node.parameter_choices()
        for pname, ptype, default, description in node.describe_parameters():
            field = node.parameters.model_fields.get(pname)
            required = field is not None and field.is_required()
            value = "VALUE" if required else format_value(default)
            setting = shlex.quote(f"{name}.{pname}={value}")
            note = " (required)" if required else ""
            lines.append(f"    --set {setting}  ({type_text(ptype)}{note}) {description}".rstrip())
            if pname in choices:
                lines.append(f"        one of: {', '.join(choices[pname]) or 'none'}")
    return "".join(f"{line}\n" for line in lines)


def _parameter_schemas(node) -> dict[str, Any]:
    """Parameter name -> its JSON schema (type, bounds, enum), ``{}`` where pydantic cannot
    write one (then only the name is checked early)."""
    try:
        properties = node.parameters.model_json_schema().get("properties", {})
    except Exception:  # a parameter type without a JSON schema: the engine checks it later
        properties = {}
    found = {}
    for name, field in node.parameters.model_fields.items():
        schema = dict(properties.get(name, {}))
        schema.pop("description", None)
        schema.pop("title", None)
        schema["required"] = field.is_required()
        found[name] = schema
    return found


def _render_catalogue(nodes: dict) -> dict[str, Any]:
    """What the command line checks before it loads the engine: every node's input groups
    and parameter schemas, every flow's nodes and the groups it reads from the store."""
    from spectralize.flows.pipelines import FLOWS, external_inputs

    catalogue: dict[str, Any] = {
        "nodes": {
            name: {
                "inputs": sorted(set(entry.node.inputs.values())),
                "parameters": _parameter_schemas(entry.node),
            }
            for name, entry in sorted(nodes.items())
        },
        "flows": {
            name: {
                "nodes": [step.node for step in flow.steps],
                "inputs": external_inputs(flow.steps),
            }
            for name, flow in sorted(FLOWS.items())
        },
    }
    return catalogue


#: The cached renderings: name -> (file suffix, encode, decode).
_CACHED = {
    "nodes": (".txt", str, str),
    "catalogue": (".json", json.dumps, json.loads),
}


def _cached(name: str, *, use_cache: bool) -> Any:
    """The rendering ``name`` of :data:`_CACHED`, from its cache file ``<name>-<key><suffix>``
    when it is there; else both renderings are made from one load of the registry and both
    cached (so the first ``spectralize nodes`` or ``run`` makes the other answer at once)."""
    key = listing_key() if use_cache else ""
    paths = {n: cache_dir() / f"{n}-{key}{suffix}" for n, (suffix, _, _) in _CACHED.items()}
    if use_cache:
        try:
            return _CACHED[name][2](paths[name].read_text(encoding="utf-8"))
        except (OSError, ValueError):
            pass
    nodes, cacheable = _registry()
    values = {"nodes": _render(nodes), "catalogue": _render_catalogue(nodes)}
    if use_cache and cacheable:
        for other, (suffix, encode, _) in _CACHED.items():
            path = paths[other]
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                for old in path.parent.glob(f"{other}-*{suffix}"):  # of older sources
                    old.unlink(missing_ok=True)
                partial = path.with_name(f"{path.name}.{os.getpid()}.tmp")
                partial.write_text(encode(values[other]), encoding="utf-8")
                os.replace(partial, path)
            except OSError:
                pass
    return values[name]


def node_listing(*, use_cache: bool = True) -> str:
    """The text ``spectralize nodes`` prints (empty when no node is installed): from the
    cache when its key matches, else rendered from the registry and cached."""
    return _cached("nodes", use_cache=use_cache)


def node_catalogue(*, use_cache: bool = True) -> dict[str, Any]:
    """Nodes (input groups, parameter JSON schemas) and flows (nodes, groups read from the
    store) as plain data, cached like the listing: what ``spectralize run`` checks in
    milliseconds before Prefect and the engine load (:mod:`.command_checks`)."""
    return _cached("catalogue", use_cache=use_cache)
