"""capture.toml: an unknown key is refused with the closest known one, as node parameters are."""

import pytest
from support.capture_folders import GOOD_CONFIG as GOOD

from spectralize.datasets.capture import CaptureError, read_capture
from spectralize.datasets.capture.config import parse_config


def unknown(problems):
    return {p.where: p for p in problems if p.found.startswith("an unknown key")}


def test_a_misspelt_top_level_key_is_refused_with_the_key_it_meant():
    config, problems = parse_config("angle_tolerance_degree = 2.0\n" + GOOD, "x")
    assert config is None
    problem = unknown(problems)["capture.toml: angle_tolerance_degree"]
    assert problem.found == "an unknown key; did you mean 'angle_tolerance_deg'?"
    assert problem.expected.startswith("one of: ") and "angle_tolerance_deg" in problem.expected
    assert "rotation_step_deg" in problem.expected and "rgb" in problem.expected


def test_unknown_keys_of_every_section_and_unknown_sections_are_all_listed():
    text = (
        GOOD.replace("bit_depth = 10", "bit_depth = 10\nbitdepth = 10")
        .replace("omega = 0.8", "omega = 0.8\nomgea = 0.7")
        .replace('paired_camera = "arc45"', 'paired_camera = "arc45"\nblack_level = {arc15 = 60}')
        + "[colour_checker]\nshared_patch_indx = true\n[exposure]\nt1 = 1.0\n"
    )
    config, problems = parse_config(text, "x")
    assert config is None
    found = {where: p.found for where, p in unknown(problems).items()}
    assert found == {
        "capture.toml: spectral.bitdepth": "an unknown key; did you mean 'bit_depth'?",
        "capture.toml: exposure_plan.omgea": "an unknown key; did you mean 'omega'?",
        "capture.toml: rgb.black_level": "an unknown key; did you mean 'black_level_dn'?",
        "capture.toml: colour_checker.shared_patch_indx": (
            "an unknown key; did you mean 'shared_patch_index' or 'patch_index' or 'patch_indices'?"
        ),
        "capture.toml: exposure": "an unknown key; did you mean 'exposure_plan'?",
    }
    assert len(problems) == len(found)  # the known keys are all fine
    assert "one of: camera, bit_depth" == unknown(problems)["capture.toml: spectral.bitdepth"].expected


def test_the_documented_optional_keys_and_a_free_source_table_are_accepted():
    text = (
        'format = "spectralize-capture"\nversion = 1\nname = "wallpaper"\n'
        "angle_tolerance_deg = 0.5\nfollow_symlinks = false\n"
        + GOOD.replace(
            'paired_camera = "arc45"',
            'paired_camera = "arc45"\nchannels = ["R", "G", "B"]\n'
            'models = {arc15 = "D5100", arc45 = "D5100"}\nblack_level_dn = {arc15 = 60}',
        )
        + '[colour_checker]\nchart = "ColorChecker N Ohta"\n'
        'patch_index = "calibration/p.png"\nshared_patch_index = false\n'
        'patch_indices = {arc15 = "calibration/q.png"}\n'
        '[source]\nsoftware = "gantry control 4.2"\noperator = "anyone"\n'
    )
    config, problems = parse_config(text, "x")
    assert problems == [] and config is not None and config.name == "wallpaper"


def test_ingest_refuses_a_capture_folder_whose_capture_toml_has_a_typo(capture):
    config = capture / "capture.toml"
    config.write_text("angle_tolerance_degree = 2.0\n" + config.read_text())
    with pytest.raises(CaptureError) as info:
        read_capture(capture)
    assert "capture.toml: angle_tolerance_degree: expected one of: " in str(
        info.value
    ) and "found an unknown key; did you mean 'angle_tolerance_deg'?" in str(info.value), str(info.value)
