"""Every RGB camera calibrated on its own, and each LED's power (issue 25, items 1 and 3).

Bad calibration input is refused before anything is written, naming the file and the line:
a camera without chart frames (unless ``rgb.models`` says it is of a calibrated camera's
model), a chart label image of the wrong size, an LED power table missing an LED.
"""

import json
import re

import numpy as np
import pytest
from support.capture_folders import rows, write_rows

from spectralize.datasets.capture import CaptureError, read_capture
from spectralize.datasets.capture.write import write_png
from spectralize.flows import run_flow
from spectralize.flows.ingest import ingest
from spectralize.nodes.evaluation.figures_calibration import camera_calibration_rows
from spectralize.store import RunStore

TARGETS = ("white_reference", "colour_checker")


def _without_chart_frames(folder, camera):
    write_rows(folder, [r for r in rows(folder) if not (r["kind"] in TARGETS and r["camera"] == camera)])


def _config(folder, old, new):
    path = folder / "capture.toml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


def _refused(folder, tmp_path, pattern):
    """read_capture and ingest refuse the folder with ``pattern``; no store is created."""
    with pytest.raises(CaptureError, match=pattern):
        read_capture(folder)
    store = tmp_path / "run.zarr"
    with pytest.raises(CaptureError, match=pattern):
        ingest(folder, store)
    assert not store.exists()


def test_each_camera_photographs_the_targets_and_the_store_keeps_them_per_camera(capture, tmp_path):
    found = read_capture(capture)
    own = {r.camera for r in found.rows if r.kind in TARGETS}
    assert own == {"rgb15", "rgb45", "mono"} and set(found.rgb_patch_index) == {"rgb15", "rgb45"}
    ingest(capture, tmp_path / "run.zarr")
    checker = RunStore.open(tmp_path / "run.zarr").read("raw/colour_checker")
    assert checker["rgb_counts"].dims == ("camera", "rgb_exposure", "y", "x", "channel")
    assert checker["camera"].values.tolist() == [0, 1]
    assert checker["camera_name"].values.tolist() == ["rgb15", "rgb45"]
    assert checker["rgb_patch_index"].shape == (2, *checker["patch_index"].shape)
    assert checker.attrs["camera_models"] == ["Nikon 5100 (NPL)"] * 2
    assert json.loads(checker.attrs["calibration_borrowed"]) == {}


def test_a_camera_without_chart_frames_is_refused_unless_its_model_has_them(capture, tmp_path):
    _without_chart_frames(capture, "rgb15")
    # rgb.models says rgb15 is of rgb45's model: it borrows rgb45's calibration, and says so
    found = read_capture(capture)
    assert {r.camera for r in found.rows if r.kind in TARGETS} == {"rgb45", "mono"}
    ingest(capture, tmp_path / "borrowed.zarr")
    checker = RunStore.open(tmp_path / "borrowed.zarr").read("raw/colour_checker")
    assert checker["camera"].values.tolist() == [1]
    assert json.loads(checker.attrs["calibration_borrowed"]) == {"rgb15": "rgb45"}
    # without rgb.models: an error naming the manifest and the camera, nothing written
    _config(capture, 'models = {"rgb15" = "Nikon 5100 (NPL)", "rgb45" = "Nikon 5100 (NPL)"}\n', "")
    _refused(capture, tmp_path, r"manifest\.csv: white_reference, colour_checker \(camera rgb15\)")
    # a model no camera with chart frames has: refused, saying so
    _config(capture, "[rgb]\n", '[rgb]\nmodels = {"rgb15" = "Sigma", "rgb45" = "Nikon"}\n')
    with pytest.raises(CaptureError, match="rgb.models says 'Sigma'"):
        read_capture(capture)


def test_a_chart_label_image_of_the_wrong_size_is_refused_naming_it(capture, tmp_path):
    _config(capture, "shared_patch_index = true", "shared_patch_index = false")
    _refused(capture, tmp_path, r"calibration/colour_checker_patches_rgb15\.png.*no such file")
    labels = tmp_path / "labels.png"
    write_png(labels, np.ones((7, 9), np.uint16))
    (capture / "calibration" / "colour_checker_patches_rgb15.png").write_bytes(labels.read_bytes())
    _refused(capture, tmp_path, r"calibration/colour_checker_patches_rgb15\.png.*shape \(7, 9\)")


def test_an_led_power_table_missing_an_led_is_refused_naming_the_line_that_uses_it(capture, tmp_path):
    leds = sorted({int(r["led"]) for r in rows(capture) if r["kind"] in ("rgb", "spectral")})
    table = capture / "calibration" / "led_power.csv"
    table.write_text("led,relative_power\n" + "".join(f"{led},{1 + 0.01 * led}\n" for led in leds[1:]))
    first = next(
        i + 2
        for i, r in enumerate(rows(capture))
        if r["kind"] in ("rgb", "spectral") and int(r["led"]) == leds[0]
    )
    _refused(
        capture,
        tmp_path,
        rf"calibration/led_power\.csv.*a row for LED {leds[0]}, which lights manifest\.csv line {first}\b",
    )
    table.write_text(table.read_text() + f"{leds[0]},0\n")
    _refused(
        capture, tmp_path, re.escape(f"calibration/led_power.csv line {len(leds) + 1}: relative_power")
    )


def test_led_powers_reach_the_band_shots_and_the_rgb_images(capture, tmp_path):
    leds = sorted({int(r["led"]) for r in rows(capture) if r["kind"] in ("rgb", "spectral")})
    power = {led: 1.0 + 0.02 * k for k, led in enumerate(leds)}
    (capture / "calibration" / "led_power.csv").write_text(
        "led,relative_power\n" + "".join(f"{led},{p}\n" for led, p in power.items())
    )
    assert read_capture(capture).led_power == power
    ingest(capture, tmp_path / "run.zarr")
    store = RunStore.open(tmp_path / "run.zarr")
    rgb, spectral = store.read("raw/rgb"), store.read("raw/spectral")
    np.testing.assert_allclose(rgb["led_power"].values, [power[int(v)] for v in rgb["led"].values])
    np.testing.assert_allclose(
        spectral["led_power"].values, [power[int(v)] for v in spectral["led"].values]
    )
    paired_leds = rgb["led"].sel(image=spectral["image"].values).values
    np.testing.assert_allclose(spectral["image_led_power"].values, [power[int(v)] for v in paired_leds])


@pytest.mark.slow
def test_a_borrowing_camera_gets_its_lender_s_c_and_the_calibration_says_so(
    prefect_api, capture, tmp_path
):
    _without_chart_frames(capture, "rgb15")
    ingest(capture, tmp_path / "run.zarr")
    run_flow("calibrate", tmp_path / "run.zarr")
    calibration = RunStore.open(tmp_path / "run.zarr").read("calibration/spectral").load()
    assert calibration["camera"].values.tolist() == [0, 1]
    assert str(calibration["c_source"].sel(camera=0).values) == (
        "borrowed from rgb45 (same model in capture.toml rgb.models)"
    )
    np.testing.assert_array_equal(
        calibration["camera_matrices"].sel(camera=0), calibration["camera_matrices"].sel(camera=1)
    )
    np.testing.assert_allclose(calibration["rgb_transform"].sel(camera=0), np.eye(3), atol=1e-9)
    rows = {r["camera"]: r for r in camera_calibration_rows(calibration)}
    assert rows["rgb15"]["c_source"].startswith("borrowed") and rows["rgb15"]["model_difference"] is None
