"""A capture whose white reference is not even: the flat field's check warns, --strict stops.

The tiny sample capture folder with a shadow on its white reference (every RGB and band
frame of the target darkened by a quarter in a small blob off the centre, its brightest codes
left alone: a saturated pixel stays saturated): the calibration
measures the dip the smooth falloff cannot explain, warns with it, and ``run --strict``
exits 2 before anything after the calibration runs.
"""

import glob
import shutil

import numpy as np
import pytest
from support import capture_folders

from spectralize.datasets.capture.images import read_image
from spectralize.datasets.capture.write import write_png, write_tiff
from spectralize.flows.cli import main
from spectralize.flows.ingest import ingest
from spectralize.store import RunStore

sample = capture_folders.sample  # the session's tiny capture folder (a fixture)


def shadowed(sample, folder, depth=0.25):
    """A copy of the sample capture folder with a shadow on every white-reference frame."""
    shutil.copytree(sample, folder)
    for path in glob.glob(str(folder / "white_reference" / "*")):
        if not path.endswith((".png", ".tif", ".tiff")):
            continue
        image = read_image(path)
        yy, xx = np.mgrid[0 : image.shape[0], 0 : image.shape[1]]
        shade = 1 - depth * np.exp(-((yy - 9) ** 2 + (xx - 22) ** 2) / (2 * 3.0**2))
        shade = shade[..., None] if image.ndim == 3 else shade
        writer = write_png if path.endswith(".png") else write_tiff
        top = np.iinfo(image.dtype).max if image.max() > 1023 else 1023
        keep = image >= min(int(image.max()), top)  # saturated stays saturated
        writer(path, np.where(keep, image, np.round(image * shade)).astype(image.dtype))
    return folder


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_shadow_on_the_white_reference_warns_and_strict_stops(prefect_api, sample, tmp_path, capsys):
    store_path = tmp_path / "run.zarr"
    ingest(shadowed(sample, tmp_path / "capture"), store_path)
    assert main(["run", "btf", str(store_path), "--strict"]) == 2
    err = capsys.readouterr().err
    assert "--strict" in err and "the white reference is not even: a local dip of" in err
    assert "camera rgb45" in err and "the spectral camera" in err
    store = RunStore.open(store_path)
    assert store.has("calibration/spectral") and not store.has("spectra")
