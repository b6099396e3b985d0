"""Fingerprints of node runs: what makes a finished group up to date.

A group carries the fingerprint of the node run that made it, the sha256 of the node's name
and version, its parameters and the fingerprints of its inputs: a step whose output already
carries the fingerprint it would write is up to date (this is what resumes flows).

The precision an array is stored at (:class:`~spectralize.schemas.Precision`, see
:mod:`.precision`) is not part of a fingerprint: it is the store's contract, checked by
``validate``, not the node's computation. A group stored losslessly before its schema
declared a precision meets every bound and stays up to date; a resumed write rounds every
region when it packs them, so one array never mixes precisions.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from typing import Any

__all__ = ["canonical_json", "compute_fingerprint", "STORE_LAYOUT"]

STORE_LAYOUT = 2
"""The on-disk layout a fingerprint promises (2: label order, shards, manifests beside the
metadata). Part of every fingerprint, so that groups of an older layout are recomputed (or
ingested again) instead of being read as if they were laid out like this one."""


def canonical_json(value: Any) -> str:
    """``value`` as JSON with sorted keys and no spaces: equal values give equal text."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=str)


def compute_fingerprint(
    node: str, version: str, parameters: Mapping[str, Any], inputs: Mapping[str, str]
) -> str:
    """Fingerprint of one node run: sha256 of its name, version, parameters, inputs and the
    store layout (:data:`STORE_LAYOUT`).

    Parameters
    ----------
    node, version
        The node's declared name and version.
    parameters
        JSON-serialisable parameter values.
    inputs
        Input group name -> that group's fingerprint.
    """
    payload = {
        "node": node,
        "version": version,
        "parameters": dict(parameters),
        "inputs": dict(inputs),
        "layout": STORE_LAYOUT,
    }
    return hashlib.sha256(canonical_json(payload).encode()).hexdigest()
