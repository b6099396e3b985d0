"""A calibration node's check of its own result: warnings with the number and the cause."""

import numpy as np
import pytest
import xarray as xr

from spectralize.flows.result_checks import report_warnings
from spectralize.nodes.calibration.result_checks import oecf_rgb_warnings, spectral_warnings
from spectralize.schemas import CalibrationError

WAVELENGTH = np.arange(400.0, 701.0, 10.0)


def calibration(errors, peaks=(600.0, 540.0, 450.0), ripple=0.0):
    """A calibration/spectral group of two cameras with the given chart errors."""
    c = np.stack([np.exp(-0.5 * ((WAVELENGTH - p) / 30.0) ** 2) for p in peaks])
    q = 1.0 + 0.5 * np.sin(WAVELENGTH / 100.0) + ripple * (-1.0) ** np.arange(WAVELENGTH.size)
    return xr.Dataset(
        {
            "camera_mean_relative_error": ("camera", np.asarray(errors)),
            "camera_matrices": (("camera", "channel", "wavelength"), np.stack([c, c])),
            "quantum_efficiency": ("wavelength", q),
        },
        coords={
            "camera": [0, 1],
            "camera_name": ("camera", ["gh50-15", "gh50-45"]),
            "channel": ["R", "G", "B"],
            "wavelength": WAVELENGTH,
        },
    )


def chart(top):
    """A colour checker's RGB series per camera whose longest exposure piles up at ``top``."""
    counts = np.full((2, 3, 8, 8, 3), 500, dtype=np.uint16)
    counts[:, -1, :4] = top  # half the longest exposure at its largest code
    return xr.Dataset(
        {"rgb_counts": (("camera", "rgb_exposure", "y", "x", "channel"), counts)},
        coords={"camera": [0, 1], "rgb_exposure_time": (("camera", "rgb_exposure"), [[1, 2, 4]] * 2)},
        attrs={"rgb_bit_depth": 12},
    )


def test_a_sane_calibration_gives_no_warning():
    assert spectral_warnings(calibration([0.02, 0.025])) == []


def test_a_failed_chart_cross_check_names_the_camera_the_number_and_a_white_level():
    oecf = xr.Dataset({"white_level": ("camera", [4095, 4095])}, coords={"camera": [0, 1]})
    oecf.attrs["bit_depth"] = 12
    found = spectral_warnings(calibration([0.02, 0.54]), colour_checker=chart(3900), oecf_rgb=oecf)
    assert len(found) == 1
    assert found[0].startswith("camera gh50-45: chart cross-check 54 %, 50 % of its")
    assert "within 5 DN of 3900" in found[0] and "a white level below the top code?" in found[0]


def test_a_failed_cross_check_without_a_pile_up_points_at_the_response():
    found = spectral_warnings(calibration([0.3, 0.02]), colour_checker=chart(4095))
    assert "camera gh50-15: chart cross-check 30 %" in found[0] and "response" in found[0]


def test_c_out_of_rgb_order_and_rippling_q_warn():
    found = spectral_warnings(calibration([0.02, 0.02], peaks=(450.0, 540.0, 600.0), ripple=0.3))
    assert sum("not in the order of RGB sensitivities" in m for m in found) == 2
    assert any(m.startswith("Q ripples") for m in found)


def test_a_response_that_falls_warns():
    response = np.tile(np.linspace(0.0, 2.0, 1024), (1, 3, 1))
    response[0, 1, 700:720] = 0.5
    oecf = xr.Dataset(
        {"response": (("camera", "channel", "code"), response)},
        coords={"camera": [0], "channel": ["R", "G", "B"], "code": np.arange(1024)},
    )
    assert oecf_rgb_warnings(oecf, ["rgb45"]) == [
        "camera rgb45, channel G: the response falls between its black level and saturation"
    ]


def test_strict_turns_the_warnings_into_an_error_naming_them():
    printed = []
    report_warnings(
        ["calibrate_spectral: camera a: chart cross-check 54 %"], printed.append, strict=False
    )
    assert printed == ["calibrate_spectral: camera a: chart cross-check 54 %"]
    with pytest.raises(
        CalibrationError, match="--strict: 1 calibration warning.*chart cross-check 54 %"
    ):
        report_warnings(["calibrate_spectral: camera a: chart cross-check 54 %"], print, strict=True)
    report_warnings([], print, strict=True)  # nothing to stop on
