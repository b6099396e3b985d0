"""Per-pixel nRMSE, spectral angle and CIEDE2000 against known answers and colour-science."""

import colour
import numpy as np
import pytest
from support.checker import (
    OBSERVER,
    SHAPE,
    checker_reflectance,
    checker_truth,
    cube,
)

from spectralize.nodes.evaluation.pixel_metrics import colour_difference, normalised_rmse, spectral_angle


def test_nrmse_of_a_constant_offset_is_offset_over_the_image_mean():
    truth = checker_truth()
    spectra = truth.copy(deep=True)
    spectra["radiance"] = truth.radiance + np.float32(0.01)
    nrmse = normalised_rmse(spectra, truth)
    assert nrmse.dims == ("image", "y", "x") and nrmse.dtype == np.float32
    assert nrmse.attrs["units"] == "1"
    means = truth.radiance.astype(np.float64).mean(("wavelength", "y", "x")).values
    for image in range(3):
        np.testing.assert_allclose(nrmse[image].values, 0.01 / means[image], rtol=1e-4)
    # the normaliser is per image: image 2 is twice as bright as image 0
    assert nrmse[2].values.mean() == pytest.approx(nrmse[0].values.mean() / 2, rel=1e-4)


def test_nrmse_is_rms_over_wavelength_of_a_relative_error():
    truth = cube(np.ones((1, 32, 2, 2)))
    error = np.zeros((1, 32, 2, 2))
    error[0, :16, 0, 0] = 0.2  # half the bands off by 0.2 -> rmse sqrt(0.02) = 0.1414
    error[0, ::2, 1, 1] = -0.4  # every second band off by -0.4 -> rmse sqrt(0.08)
    spectra = cube(1.0 + error)
    nrmse = normalised_rmse(spectra, truth).values[0]
    np.testing.assert_allclose(nrmse, [[np.sqrt(0.02), 0.0], [0.0, np.sqrt(0.08)]], rtol=1e-5)


def test_nrmse_is_nan_for_nan_pixels_and_for_a_black_truth_image():
    values = np.ones((2, 32, 2, 2))
    values[1] = 0.0
    truth = cube(values)
    spectra_values = values.copy()
    spectra_values[0, 5, 1, 0] = np.nan
    nrmse = normalised_rmse(cube(spectra_values), truth).values
    assert np.isnan(nrmse[0, 1, 0]) and np.isfinite(nrmse[0, 0, 0])
    assert np.isnan(nrmse[1]).all()


def test_spectral_angle_known_answers():
    truth = np.zeros((1, 32, 1, 4))
    spectra = np.zeros((1, 32, 1, 4))
    truth[0, 0, 0, :] = 1.0
    spectra[0, 0, 0, 0] = 3.0  # same direction: 0 degree
    spectra[0, :2, 0, 1] = 1.0  # (1, 1) vs (1, 0): 45 degree
    spectra[0, 1, 0, 2] = 2.0  # orthogonal: 90 degree
    # pixel 3: zero spectrum -> undefined
    angle = spectral_angle(cube(spectra), cube(truth))
    assert angle.attrs["units"] == "degree"
    values = angle.values[0, 0]
    np.testing.assert_allclose(values[:3], [0.0, 45.0, 90.0], atol=1e-4)
    assert np.isnan(values[3])


def test_spectral_angle_is_accurate_for_tiny_angles_and_scale_invariant():
    truth = checker_truth(n_image=1)
    angle = spectral_angle(truth.radiance * 7.0, truth)
    assert float(np.nanmax(angle.values)) < 1e-3
    t = np.zeros((1, 32, 1, 1))
    s = np.zeros((1, 32, 1, 1))
    t[0, 0] = 1.0
    s[0, 0], s[0, 1] = 1.0, 1e-3  # atan(1e-3) = 0.0573 degree
    small = spectral_angle(cube(s), cube(t)).values.item()
    assert small == pytest.approx(np.degrees(np.arctan(1e-3)), rel=1e-3)


@pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")
def test_colour_difference_matches_colour_science_for_two_patches():
    reflectance = checker_reflectance()
    dark_skin, light_skin = reflectance[0], reflectance[1]
    truth = cube(np.broadcast_to(dark_skin[None, :, None, None], (1, 32, 2, 2)))
    spectra = cube(np.broadcast_to(light_skin[None, :, None, None], (1, 32, 2, 2)))
    delta = colour_difference(spectra, truth, illuminant="D65")
    assert delta.dims == ("image", "y", "x") and delta.attrs["illuminant"] == "D65"

    cmfs = colour.MSDS_CMFS[OBSERVER]
    d65 = colour.SDS_ILLUMINANTS["D65"]

    def xyz(values):
        return (
            colour.msds_to_XYZ(values, cmfs=cmfs, illuminant=d65, method="Integration", shape=SHAPE)
            / 100
        )

    white = colour.XYZ_to_xy(xyz(np.ones(32)))  # the perfect reflector on the same bands

    def lab(values):
        return colour.XYZ_to_Lab(xyz(values), white)

    expected = colour.delta_E(lab(light_skin), lab(dark_skin), method="CIE 2000")
    np.testing.assert_allclose(delta.values, expected, rtol=1e-5)
    assert 10 < expected < 40  # a big, visible difference
    # and close to colour-science's spectral-distribution path (1 nm interpolation)
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    lab_sd = [
        colour.XYZ_to_Lab(
            colour.sd_to_XYZ(sds[n], cmfs=cmfs, illuminant=d65, method="Integration") / 100,
            colour.CCS_ILLUMINANTS[OBSERVER]["D65"],
        )
        for n in ("light skin", "dark skin")
    ]
    assert float(delta.values[0, 0, 0]) == pytest.approx(
        float(colour.delta_E(*lab_sd, method="CIE 2000")), abs=0.5
    )


def test_colour_difference_is_zero_for_identical_spectra_and_depends_on_illuminant():
    truth = checker_truth(n_image=1)
    assert float(np.abs(colour_difference(truth, truth).values).max()) < 1e-6
    brighter = truth.radiance * 1.1
    under_d65 = colour_difference(brighter, truth, illuminant="D65").values
    under_a = colour_difference(brighter, truth, illuminant="A").values
    assert under_d65.min() > 0
    assert not np.allclose(under_d65, under_a)
    with pytest.raises(ValueError, match="not a colour-science illuminant"):
        colour_difference(truth, truth, illuminant="D-nonsense")
