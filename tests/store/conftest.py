"""Run stores for the store tests: an empty one, and one holding a small ``raw/dark``."""

import pytest

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.store import RunStore


@pytest.fixture
def store(tmp_path):
    return RunStore.create(tmp_path / "run.zarr")


@pytest.fixture
def dark_store(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    store.write(
        "raw/dark",
        make_raw_dark(frames=8, shape=(6, 7), exposure_times=(0.1, 0.2), frames_per_chunk=4),
        fingerprint="raw",
    )
    return store
