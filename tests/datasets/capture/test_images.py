"""Image files: read as stored, and probed against the camera that took them."""

import numpy as np
import pytest
import tifffile

from spectralize.datasets.capture import CaptureError
from spectralize.datasets.capture.images import probe, read_image
from spectralize.datasets.capture.write import write_png, write_tiff


def test_16_bit_png_and_tiff_are_read_as_written(tmp_path):
    rgb = np.arange(4 * 5 * 3, dtype=np.uint16).reshape(4, 5, 3) * 1000
    mono = np.arange(20, dtype=np.uint16).reshape(4, 5) * 3000
    for name, image, write in (
        ("a.png", rgb, write_png),
        ("b.tif", mono, write_tiff),
        ("c.png", mono, write_png),
    ):
        write(tmp_path / name, image)
        data = read_image(tmp_path / name)
        assert data.dtype == np.uint16
        np.testing.assert_array_equal(data, image)
    with pytest.raises(ValueError, match="unknown image format"):  # a CaptureError is one
        read_image(tmp_path / "d.jpg")
    with pytest.raises(CaptureError, match=r"d\.jpg: expected a \.tif, \.tiff or \.png file"):
        read_image(tmp_path / "d.jpg")


def test_a_probe_names_what_is_wrong_with_a_file(tmp_path):
    write_tiff(tmp_path / "ok.tif", np.full((4, 5), 1023, np.uint16))
    assert probe(tmp_path / "ok.tif", False, 10) == ((4, 5), None, None)
    _, expected, found = probe(tmp_path / "ok.tif", True, 10)
    assert expected == "an RGB image (y, x, 3)" and found == "shape (4, 5)"
    write_tiff(tmp_path / "high.tif", np.full((4, 5), 1024, np.uint16))
    assert probe(tmp_path / "high.tif", False, 10)[2] == "a value of 1024"
    tifffile.imwrite(tmp_path / "float.tif", np.zeros((4, 5), np.float32))
    assert probe(tmp_path / "float.tif", False, 10)[1:] == (
        "16-bit unsigned integer pixels (10-bit camera)",
        "float32",
    )
    tifffile.imwrite(tmp_path / "byte.tif", np.zeros((4, 5), np.uint8))
    assert probe(tmp_path / "byte.tif", False, 8) == ((4, 5), None, None)  # 8-bit for 8-bit cameras
    (tmp_path / "bad.tif").write_bytes(b"not a tiff")
    assert probe(tmp_path / "bad.tif", False, 10)[1] == "a readable TIFF or PNG file"
    assert probe(tmp_path / "none.tif", False, 10)[1:] == ("an image file", "no such file")


def test_the_header_is_checked_before_any_pixel_is_decoded(tmp_path):
    from spectralize.datasets.capture.images import read_header

    write_tiff(tmp_path / "a.tif", np.full((4, 5), 7, np.uint16))
    write_png(tmp_path / "b.png", np.full((4, 5, 3), 7, np.uint16))
    assert read_header(tmp_path / "a.tif").shape == (4, 5)
    assert read_header(tmp_path / "b.png").shape == (4, 5, 3)
    with pytest.raises(
        CaptureError,
        match=r"a\.tif: expected a frame of shape \(5, 4\), found the file declares shape \(4, 5\)",
    ):
        read_image(tmp_path / "a.tif", shape=(5, 4))
    with pytest.raises(CaptureError, match="at most 0 MiB, found .*: more than 0 MiB, not decoded"):
        read_image(tmp_path / "b.png", max_bytes=100)
    assert probe(tmp_path / "a.tif", False, 10, frame_shape=(8, 8)) == (
        None,
        "frames of 8 x 8 px like the others",
        "4 x 5 px (declared in its header, not decoded)",
    )
    assert probe(tmp_path / "a.tif", False, 10, max_bytes=16)[1] == "a frame of at most 0 MiB"
