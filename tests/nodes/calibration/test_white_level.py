"""The white level found from the data: a pile-up of codes below the top code."""

import numpy as np
import pytest

from spectralize.nodes.calibration.white_level import saturation_code, white_level, white_margin
from spectralize.schemas import CalibrationError


def frames(clip: int, bit_depth: int = 12, seed: int = 0) -> np.ndarray:
    """Long exposures of a textured scene, some of it far past the top, clipped at ``clip``."""
    rng = np.random.default_rng(seed)
    exposure = rng.lognormal(np.log(2500.0), 0.5, size=(4, 64, 64))
    codes = exposure + rng.normal(0.0, 4.0, exposure.shape)
    return np.clip(np.round(codes), 0, clip).astype(np.uint16)


def test_a_12_bit_sensor_clipping_at_3900_is_found():
    level, evidence = white_level(frames(3900), 12)
    assert level == 3900
    assert evidence.max_code == 3900 and evidence.share > 0.05
    assert evidence.at_max > 100 * evidence.baseline


def test_clipping_at_the_top_code_is_no_white_level():
    level, evidence = white_level(frames(4095), 12)
    assert level is None and evidence.max_code == 4095


def test_unclipped_frames_have_no_white_level():
    rng = np.random.default_rng(1)
    codes = np.round(rng.normal(2000.0, 150.0, size=(4, 64, 64))).astype(np.uint16)
    level, evidence = white_level(codes, 12)
    assert level is None and evidence.max_code < 4095


def test_a_flat_target_far_below_the_top_is_no_white_level():
    """A uniform frame of little noise piles its values up too, but in the lower half."""
    codes = np.full((2, 32, 32), 900, dtype=np.uint16)
    assert white_level(codes, 12)[0] is None


def test_a_few_clipped_pixels_are_no_evidence():
    codes = frames(4095)
    codes = np.minimum(codes, 3000)  # most of the scene under 3000 ...
    codes[codes == 3000] = 2999
    codes.flat[:5] = 3900  # ... and five hot pixels at 3900
    assert white_level(codes, 12)[0] is None


def test_codes_beyond_the_bit_depth_are_refused():
    with pytest.raises(CalibrationError, match="bit depth 10"):
        white_level(np.array([0, 1100]), 10)


def test_the_saturated_codes_start_at_the_white_level_less_its_noise():
    assert saturation_code(None, 12) == 4095 and saturation_code(4095, 12) == 4095
    assert saturation_code(3900, 12) == 3900 - white_margin(12)
    assert white_margin(10) == 3 and white_margin(12) == 8


@pytest.fixture(scope="module")
def tiny():
    from spectralize.nodes.simulation.assembly import simulate_run
    from spectralize.nodes.simulation.recipes import get_recipe

    return {k: v.load() for k, v in simulate_run(get_recipe("tiny", seed=0)).items()}


def _response_error(oecf, truth, below):
    """Median and largest |f / f_true - 1| (one scale per channel) over codes 50 .. below: above
    the low end (the codes under its anchor, about 43 here, come from the reverse regression of
    the samples, test_low_end.py), where the fitted response and the white level decide."""
    codes = oecf["code"].values
    errors = []
    for ch in "RGB":
        offset = float(truth["adc_offset"].sel(sensor=ch))
        f = oecf["response"].sel(channel=ch).isel(camera=0).values
        true = np.interp(codes - offset, truth["code"].values, truth["oecf"].sel(sensor=ch).values)
        keep = (codes >= 50) & (codes <= below)
        scale = (f[keep] @ true[keep]) / (f[keep] @ f[keep])
        errors.append(np.abs(scale * f[keep] / true[keep] - 1))
    errors = np.concatenate(errors)
    return float(np.median(errors)), float(errors.max())


def test_recover_rgb_oecf_finds_the_white_level_of_clipped_frames(tiny):
    from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf

    white = 1000

    def clip(ds, name):
        return ds.assign({name: ds[name].clip(max=white).astype(ds[name].dtype)})

    rgb = clip(tiny["raw/rgb"], "counts")
    checker = clip(tiny["raw/colour_checker"], "rgb_counts")
    reference = clip(tiny["raw/white_reference"], "rgb_counts")
    found = recover_rgb_oecf(rgb, checker, reference)
    assert found["white_level"].values.tolist() == [white, white]
    assert found.attrs["white_level_source"] == ["found", "found"]
    assert found["saturation"].values.tolist() == [white - white_margin(10)] * 2
    median, worst = _response_error(found, tiny["truth/camera"], white - 4)
    assert median < 0.003 and worst < 0.02
    # the white level taken for the top code: only 1023 saturated, the clamped codes fitted
    blind = recover_rgb_oecf(rgb.assign_attrs(white_level_dn=[1023, 1023]), checker, reference)
    assert blind.attrs["white_level_source"] == ["declared", "declared"]
    assert _response_error(blind, tiny["truth/camera"], white - 4)[0] > 0.05


def test_unclipped_frames_keep_the_top_code(tiny):
    from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf

    out = recover_rgb_oecf(tiny["raw/rgb"], tiny["raw/colour_checker"], tiny["raw/white_reference"])
    assert out["white_level"].values.tolist() == [1023, 1023]
    assert out["saturation"].values.tolist() == [1023, 1023] and out.attrs["saturation"] == 1023
    assert out.attrs["white_level_source"] == ["top code", "top code"]


def test_targets_that_clip_below_codes_the_scene_reaches_show_their_white_level(tiny):
    """Each source's longest exposures apart: the scene's codes up to the top code do not hide
    the targets' pile-up a few codes below it."""
    from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf

    white = 1020

    def clip(ds):
        return ds.assign(rgb_counts=ds["rgb_counts"].clip(max=white).astype(ds["rgb_counts"].dtype))

    rgb = tiny["raw/rgb"]
    assert int(rgb["counts"].max()) > white  # the scene reaches above the targets' white level
    found = recover_rgb_oecf(rgb, clip(tiny["raw/colour_checker"]), clip(tiny["raw/white_reference"]))
    assert found["white_level"].values.tolist() == [white, white]
    assert found.attrs["white_level_source"] == ["found", "found"]
    median, worst = _response_error(found, tiny["truth/camera"], white - 4)
    assert median < 0.003 and worst < 0.02
