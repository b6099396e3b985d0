"""capture.toml text into a Config: every bad key is a problem naming it."""

from support.capture_folders import GOOD_CONFIG as GOOD

from spectralize.datasets.capture.config import parse_config


def test_a_good_config_and_its_defaults():
    config, problems = parse_config(GOOD, "wallpaper")
    assert problems == []
    assert config.name == "wallpaper"  # the folder's name when none is given
    assert config.rgb_cameras == ("arc15", "arc45") and config.paired_camera == "arc45"
    assert (config.rgb_bit_depth, config.spectral_bit_depth) == (12, 10)
    assert config.rotation_step == 15.0 and isinstance(config.rotation_step, float)
    assert config.angle_tolerance == 0.5 and config.channels == ("R", "G", "B")
    assert config.chart is None and config.patch_index == "calibration/colour_checker_patches.png"
    assert (config.t0, config.s0, config.omega) == (0.02, 0.25, 0.8)


def test_every_bad_key_is_listed_and_no_config_is_returned():
    text = (
        GOOD.replace("bit_depth = 12", "bit_depth = 20")
        .replace('paired_camera = "arc45"', 'paired_camera = "arc75"')
        .replace('camera = "mono"', 'camera = "arc15"')
        .replace("omega = 0.8", "omega = 0")
        .replace("s0 = 0.25", "")
        .replace("rotation_step_deg = 15", 'format = "other"\nrotation_step_deg = 15')
    )
    config, problems = parse_config(text, "x")
    assert config is None
    where = sorted(p.where for p in problems)
    assert where == sorted(
        [
            "capture.toml: format",
            "capture.toml: rgb.bit_depth",
            "capture.toml: rgb.paired_camera",
            "capture.toml: spectral.camera",
            "capture.toml: omega",
            "capture.toml: exposure_plan.s0",
        ]
    )


def test_a_toml_syntax_error_is_one_problem():
    config, problems = parse_config("[rgb\n", "x")
    assert config is None and len(problems) == 1
    assert "a readable TOML file" in str(problems[0]) and "TOMLDecodeError" in str(problems[0])
