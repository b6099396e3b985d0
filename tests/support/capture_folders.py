"""The sample capture folder and a valid capture.toml, shared by the capture format and ingest tests."""

import csv

import pytest

from spectralize.datasets.capture.sample import write_capture_folder

GOOD_CONFIG = """
rotation_step_deg = 15
[rgb]
cameras = ["arc15", "arc45"]
bit_depth = 12
paired_camera = "arc45"
[spectral]
camera = "mono"
bit_depth = 10
[exposure_plan]
t0 = 0.02
s0 = 0.25
omega = 0.8
"""
"""A valid capture.toml (two RGB cameras, a spectral camera, the exposure plan) that the tests
of its parser and of the manifest rules start from."""


@pytest.fixture(scope="session")
def sample(tmp_path_factory):
    """The tiny recipe as a capture folder, written once (copy it to change it)."""
    return write_capture_folder(tmp_path_factory.mktemp("sample") / "capture", recipe="tiny")


def rows(folder):
    """The rows of a capture folder's manifest.csv, as dicts of text."""
    with open(folder / "manifest.csv", newline="") as handle:
        return list(csv.DictReader(handle))


def write_rows(folder, table):
    """Replace a capture folder's manifest.csv with ``table`` (dicts of text)."""
    with open(folder / "manifest.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(table[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(table)
