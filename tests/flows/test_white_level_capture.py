"""A capture whose RGB cameras clip at a white level below the top code.

The tiny sample capture folder with every RGB frame (scene, targets, registration) clipped at
``WHITE`` < 1023, the top code of its 10-bit cameras. Undeclared, the white level is found
from the data and the run's spectra are as good as the unclipped run's; declared in
capture.toml, it is used as given; declared as the top code (what the project did before it
knew of white levels), the chart cross-check fails, the flow warns with the cause, and
``run --strict`` exits 2 before the reconstruction.
"""

import glob
import re
import shutil

import numpy as np
import pytest
from support import capture_folders

from spectralize.datasets.capture.images import read_image
from spectralize.datasets.capture.write import write_png, write_tiff
from spectralize.flows import run_flow
from spectralize.flows.cli import main
from spectralize.flows.ingest import ingest
from spectralize.nodes.evaluation.accuracy import evaluate
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.store import RunStore

WHITE = 1000
UNCLIPPED_NRMSE = 0.0626  # the unclipped tiny sample's median nRMSE through btf (same code)
sample = capture_folders.sample  # the session's tiny capture folder (a fixture)
RGB_FILES = (
    "rgb/*.png",
    "white_reference/*_rgb_exp*",
    "colour_checker/*_rgb_exp*",
    "registration/rgb_rot*",
)


def clipped(sample, folder, declared=None):
    """A copy of the sample capture folder, RGB frames clipped at WHITE, ``declared`` as every
    camera's rgb.white_level_dn (None: not declared)."""
    shutil.copytree(sample, folder)
    for pattern in RGB_FILES:
        for path in glob.glob(str(folder / pattern)):
            image = read_image(path)
            writer = write_png if path.endswith(".png") else write_tiff
            writer(path, np.minimum(image, WHITE).astype(image.dtype))
    if declared is not None:
        toml = folder / "capture.toml"
        text = toml.read_text()
        names = re.findall(r'"([^"]+)"', re.search(r"cameras = \[(.*?)\]", text).group(1))
        table = ", ".join(f"{name} = {declared}" for name in names)
        toml.write_text(text.replace("[rgb]\n", f"[rgb]\nwhite_level_dn = {{{table}}}\n", 1))
    return folder


def test_an_undeclared_white_level_is_found_and_the_spectra_stay_as_good(prefect_api, sample, tmp_path):
    folder = clipped(sample, tmp_path / "capture")
    store_path = tmp_path / "run.zarr"
    ingest(folder, store_path)
    run_flow("btf", store_path)
    store = RunStore.open(store_path)
    oecf = store.read("calibration/oecf_rgb")
    assert oecf["white_level"].values.tolist() == [WHITE, WHITE]
    assert oecf.attrs["white_level_source"] == ["found", "found"]
    assert (oecf["saturation"].values < WHITE).all()
    calibration = store.read("calibration/spectral")
    assert (calibration["camera_mean_relative_error"].values < 0.03).all()
    truth = simulate_run(get_recipe("tiny", seed=0))["truth/spectra"]
    nrmse = evaluate(store.read("spectra"), truth, shots=store.read("raw/spectral"))["nrmse"]
    assert float(np.nanmedian(nrmse.values)) < 1.1 * UNCLIPPED_NRMSE
    report = (tmp_path / "run-report" / "index.html").read_text()
    assert f"rgb15 {WHITE} DN (found), rgb45 {WHITE} DN (found)" in report


def test_a_declared_white_level_is_used_as_given(prefect_api, sample, tmp_path):
    folder = clipped(sample, tmp_path / "capture", declared=WHITE + 2)
    store_path = tmp_path / "run.zarr"
    ingest(folder, store_path)
    assert RunStore.open(store_path).read("raw/rgb").attrs["white_level_dn"] == [WHITE + 2] * 2
    run_flow("recover_rgb_oecf", store_path)
    oecf = RunStore.open(store_path).read("calibration/oecf_rgb")
    assert oecf["white_level"].values.tolist() == [WHITE + 2] * 2
    assert oecf.attrs["white_level_source"] == ["declared", "declared"]


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_a_wrong_white_level_warns_and_strict_stops_before_reconstruction(
    prefect_api, sample, tmp_path, capsys
):
    folder = clipped(sample, tmp_path / "capture", declared=1023)  # the top code: wrong
    store_path = tmp_path / "run.zarr"
    ingest(folder, store_path)
    assert main(["run", "btf", str(store_path), "--strict"]) == 2
    err = capsys.readouterr().err
    assert "--strict" in err and "chart cross-check" in err
    assert "a white level below the top code?" in err and f"of {WHITE}" in err
    store = RunStore.open(store_path)
    assert store.has("calibration/spectral") and not store.has("spectra")
