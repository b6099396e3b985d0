"""The sample capture folder: deterministic, and in the documented format."""

import csv
import hashlib
import tomllib

import numpy as np
import png
import tifffile

from spectralize.datasets.capture import MANIFEST_COLUMNS
from spectralize.datasets.capture.sample import main


def digest(folder):
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_the_sample_is_written_deterministically_in_the_documented_format(tmp_path):
    assert main([str(tmp_path / "a"), "--recipe", "tiny", "--chart-by-name"]) == 0
    assert main([str(tmp_path / "b"), "--recipe", "tiny", "--chart-by-name"]) == 0
    first = digest(tmp_path / "a")
    assert first == digest(tmp_path / "b")  # byte for byte
    folder = tmp_path / "a"
    with open(folder / "manifest.csv", newline="") as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == MANIFEST_COLUMNS
        rows = list(reader)
    assert len(rows) + 6 == len(first)  # every file listed, + manifest, toml, 4 calibration files
    config = tomllib.loads((folder / "capture.toml").read_text())
    assert config["colour_checker"]["chart"] == "ColorChecker N Ohta"
    assert not (folder / "calibration" / "colour_checker.csv").exists()
    kinds = {r["kind"] for r in rows}
    assert kinds == {"rgb", "spectral", "dark", "white_reference", "colour_checker", "registration"}
    rgb = next(r for r in rows if r["kind"] == "rgb")
    width, height, _, info = png.Reader(filename=str(folder / rgb["file"])).read()
    assert (info["bitdepth"], info["planes"], width, height) == (16, 3, 32, 32)
    band = next(r for r in rows if r["kind"] == "spectral")
    frame = tifffile.imread(folder / band["file"])
    assert frame.dtype == np.uint16 and frame.shape == (32, 32) and frame.max() < 2**10
    assert band["wavelength_nm"] and not rgb["wavelength_nm"]
