"""Shared fixtures: small real data, real zarr stores on tmp disk, a real Prefect API."""

from __future__ import annotations

import pytest

import spectralize.flows  # noqa: F401  (sets Prefect's environment defaults before import)


@pytest.fixture(scope="session")
def prefect_api():
    """A real, temporary Prefect API (SQLite) for the whole session; started on first use."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield
