"""Compressed TIFFs (LZW, Deflate, PackBits), as camera software writes them, read like plain ones."""

import numpy as np
import pytest
import tifffile
from support.capture_folders import rows

from spectralize.datasets.capture import read_capture
from spectralize.datasets.capture.images import probe, read_image
from spectralize.flows.ingest import ingest
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.store import RunStore

COMPRESSIONS = [
    ("lzw", None),
    ("lzw", "horizontal"),  # LZW with the differencing predictor: the most common camera TIFF
    ("zlib", None),  # Deflate
    ("adobe_deflate", "horizontal"),
    ("packbits", None),
]


@pytest.mark.parametrize("compression, predictor", COMPRESSIONS)
def test_compressed_tiffs_are_read_as_written(tmp_path, compression, predictor):
    rgb = (np.arange(6 * 7 * 3, dtype=np.uint16).reshape(6, 7, 3) * 19) % 1024
    mono = (np.arange(6 * 7, dtype=np.uint16).reshape(6, 7) * 23) % 1024
    for name, image, photometric in (("rgb.tif", rgb, "rgb"), ("mono.tif", mono, "minisblack")):
        path = tmp_path / name
        tifffile.imwrite(
            path, image, photometric=photometric, compression=compression, predictor=predictor
        )
        np.testing.assert_array_equal(read_image(path), image)
        assert probe(path, image.ndim == 3, 10) == ((6, 7), None, None)


def test_a_capture_folder_of_lzw_tiffs_ingests_the_same_pixels(capture, tmp_path):
    tiffs = [r["file"] for r in rows(capture) if r["file"].lower().endswith((".tif", ".tiff"))]
    assert len(tiffs) > 100  # every kind of frame of the sample has TIFFs
    for name in tiffs:
        path = capture / name
        image = tifffile.imread(path)
        photometric = "rgb" if image.ndim == 3 else "minisblack"
        tifffile.imwrite(path, image, photometric=photometric, compression="lzw", predictor=True)
        assert tifffile.TiffFile(path).pages[0].compression == tifffile.COMPRESSION.LZW
    read_capture(capture)  # every file probed and decoded: nothing refused
    ingest(capture, tmp_path / "run.zarr")
    store = RunStore.open(tmp_path / "run.zarr")
    assert store.validate() == []
    simulated = simulate_run(get_recipe("tiny"))
    for group in ("raw/rgb", "raw/spectral", "raw/dark", "raw/white_reference", "raw/registration"):
        for name, var in store.read(group).data_vars.items():  # bit for bit, as written
            if var.dtype == np.uint16:
                np.testing.assert_array_equal(var.values, simulated[group][name].values, err_msg=name)
