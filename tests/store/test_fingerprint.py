"""Fingerprints of node runs."""

from spectralize.store import (
    compute_fingerprint,
)


def test_fingerprint_depends_on_every_ingredient():
    base = compute_fingerprint("n", "1", {"a": 1}, {"raw/dark": "x"})
    assert base == compute_fingerprint("n", "1", {"a": 1}, {"raw/dark": "x"})
    assert base != compute_fingerprint("m", "1", {"a": 1}, {"raw/dark": "x"})
    assert base != compute_fingerprint("n", "2", {"a": 1}, {"raw/dark": "x"})
    assert base != compute_fingerprint("n", "1", {"a": 2}, {"raw/dark": "x"})
    assert base != compute_fingerprint("n", "1", {"a": 1}, {"raw/dark": "y"})
