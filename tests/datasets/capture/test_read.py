"""A whole capture folder read and checked (the sample, and the sample altered)."""

import shutil

import pytest

from spectralize.datasets.capture import CaptureError, read_capture


def test_the_chart_can_be_named_instead_of_tabulated(sample, tmp_path):
    folder = shutil.copytree(sample, tmp_path / "capture")
    (folder / "calibration" / "colour_checker.csv").unlink()
    with pytest.raises(CaptureError, match="colour_checker.chart"):
        read_capture(folder)
    config = folder / "capture.toml"
    config.write_text(
        config.read_text().replace(
            "[colour_checker]\n", '[colour_checker]\nchart = "ColorChecker N Ohta"\n'
        )
    )
    capture = read_capture(folder)
    names, reflectance, chart = capture.patches
    assert chart == "ColorChecker N Ohta" and len(names) == 24 and reflectance.shape == (24, 32)
