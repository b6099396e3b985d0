"""The sample capture folder (tests/support/capture_folders.py), written once per session here."""

import shutil

import pytest
from support.capture_folders import sample  # noqa: F401  (a fixture)


@pytest.fixture
def capture(sample, tmp_path):  # noqa: F811
    """A copy of the sample capture folder, to change."""
    return shutil.copytree(sample, tmp_path / "capture", copy_function=shutil.copy2)
