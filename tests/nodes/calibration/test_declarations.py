"""The calibration node declarations: entry points, parameters derived from the signatures."""

from __future__ import annotations

import pytest

from spectralize.nodes.calibration import declarations
from spectralize.nodes.calibration.oecf.weighting import WEIGHTING_FUNCTIONS
from spectralize.schemas import ParameterError

# every parameter of every calibration node and its default (the former explicit models)
DEFAULTS = {
    "DARK_AVERAGE": {"frames_per_chunk": 16, "ddof": 1, "model": "linear"},
    "RECOVER_RGB_OECF": {
        "calibration_targets": True,
        "per_camera": True,
        "black_level": None,
        "weighting": "gaussian",
        "tolerance": 1e-6,
        "max_pixels": 200_000,
        "smooth": 16,
        "low_end": True,
        "log_spline": True,
    },
    "RECOVER_SPECTRAL_OECF": {
        "band": None,
        "low_signal_fraction": 0.15,
        "filter_size": 25.0,
        "full_exposures": 4,
        "tolerance": 1e-6,
    },
    "CALIBRATE_SPECTRAL": {
        "camera_matrix_method": "lobes",
        "ridge": None,
        "weak_light": 0.15,
        "smoothness": None,
        "nonnegative": True,
        "white_patch": True,
        "matched_levels": True,
        "patch_margin": 2,
        "min_snr": 1.0,
    },
    "HDR_MERGE": {"black_level": None, "saturation": None},
    "ESTIMATE_REGISTRATION": {"azimuth_offset": 15.0, "upsample_factor": 50, "max_shift": 8.0},
    "CALIBRATE_BANDS": {"filter_size": None, "order": 1, "led_power": True},
}


@pytest.mark.parametrize("name", sorted(DEFAULTS))
def test_parameters_come_from_the_signature(name: str) -> None:
    node = getattr(declarations, name)
    assert node.parse_parameters({}).model_dump() == DEFAULTS[name]
    assert all(description for *_, description in node.describe_parameters())


def test_weighting_is_validated_from_its_table() -> None:
    node = declarations.RECOVER_RGB_OECF
    for kind in WEIGHTING_FUNCTIONS:
        assert node.parse_parameters({"weighting": kind}).weighting == kind
    with pytest.raises(
        ParameterError,
        match=r"recover_rgb_oecf.weighting.*'gaussian', 'hat', "
        r"'uniform'.*'box'",
    ):
        node.parse_parameters({"weighting": "box"})


@pytest.mark.parametrize(
    ("name", "values"),
    [
        ("RECOVER_RGB_OECF", {"tolerance": 0.5}),
        ("RECOVER_RGB_OECF", {"max_pixels": 10}),
        ("RECOVER_SPECTRAL_OECF", {"low_signal_fraction": 0}),
        ("RECOVER_SPECTRAL_OECF", {"full_exposures": 1}),
        ("CALIBRATE_SPECTRAL", {"min_snr": 0}),
        ("CALIBRATE_SPECTRAL", {"camera_matrix_method": "splines"}),
        ("CALIBRATE_SPECTRAL", {"ridge": -1.0}),
        ("DARK_AVERAGE", {"ddof": 2}),
        ("DARK_AVERAGE", {"model": "spline"}),
        ("ESTIMATE_REGISTRATION", {"upsample_factor": 0}),
        ("CALIBRATE_BANDS", {"order": 6}),
        ("HDR_MERGE", {"saturation": 0}),
        ("CALIBRATE_BANDS", {"unknown": 1}),
    ],
)
def test_limits_and_unknown_keys_are_errors(name: str, values: dict) -> None:
    with pytest.raises(ParameterError):
        getattr(declarations, name).parse_parameters(values)
