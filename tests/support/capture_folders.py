"""The sample capture folder shared by the tests of the capture format and of ingest."""

import csv

import pytest

from spectralize.datasets.capture.sample import write_capture_folder


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
