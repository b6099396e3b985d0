"""Spectra relit under CIE A, FL11 and D65, and their CIEDE2000 against the truth relit alike."""

import colour
import numpy as np
import pytest
import xarray as xr
from support.checker import OBSERVER, SHAPE, WAVELENGTH, checker_reflectance, cube

from spectralize.nodes.evaluation import relight, relit_delta_e
from spectralize.nodes.evaluation.relit_colour import (
    LIGHTS,
    light_on_bands,
    reflectance_factor,
    relit_statistics,
)
from spectralize.schemas import ParameterError, SchemaError

pytestmark = pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")


def led() -> np.ndarray:
    """A white LED on the paper's bands (max 1): little light at the ends of the range."""
    light = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(SHAPE).values
    return light / light.max()


def checker_under(light: np.ndarray, n_image: int = 2) -> xr.Dataset:
    """The 24 ColorChecker patches as a 4 x 6 grid of 2 x 2 px squares under ``light``."""
    grid = (checker_reflectance() * light).reshape(4, 6, -1).transpose(2, 0, 1)
    patches = np.repeat(np.repeat(grid, 2, 1), 2, 2)
    return cube(np.stack([patches * (1.0 - 0.3 * i) for i in range(n_image)]))


def band_average(name: str) -> np.ndarray:
    """The light's mean over each 10 nm box by brute force (0.01 nm trapezoids, linear table)."""
    sd = colour.SDS_ILLUMINANTS[name]
    out = []
    for centre in WAVELENGTH:
        fine = np.linspace(centre - 5.0, centre + 5.0, 1001)
        out.append(np.trapezoid(np.interp(fine, sd.wavelengths, sd.values), fine) / 10.0)
    return np.array(out)


def test_identical_spectra_have_zero_difference_under_every_light():
    truth = checker_under(led())
    relit = relit_delta_e(truth, truth, led())
    assert relit["delta_e"].dims == ("light", "image", "y", "x")
    assert relit["light"].values.tolist() == list(LIGHTS)
    assert relit["delta_e"].attrs["units"] == "1" and "CIEDE2000" in relit["delta_e"].attrs["long_name"]
    assert "99th percentile" in relit.attrs["normalisation"]
    assert float(np.nanmax(np.abs(relit["delta_e"].values))) < 1e-4
    stats = relit_statistics(relit)
    assert set(stats) == set(LIGHTS)
    assert all(s["median"] < 1e-4 and s["p95"] < 1e-4 and s["excluded"] < 0.1 for s in stats.values())


def test_a_perturbed_estimate_matches_colour_science_computed_directly():
    light = led()
    truth = checker_under(light, n_image=1)
    tilt = 1.0 + 0.15 * np.sin((WAVELENGTH - 410.0) / 40.0)  # a change of spectral shape
    estimate = truth.copy(data={"radiance": truth["radiance"].values * tilt[None, :, None, None]})
    relit = relit_delta_e(estimate, truth, light, targets=("A", "FL11"), dark_floor=0.0)

    cmfs = colour.MSDS_CMFS[OBSERVER]
    ones = colour.sd_ones(SHAPE)
    floored = np.maximum(light, 0.01)
    for name in ("A", "FL11"):
        power = band_average(name)

        def xyz(radiance, power=power):  # (pixel, wavelength) radiance -> relit XYZ
            relit_spectra = radiance / floored * power
            return colour.msds_to_XYZ(
                relit_spectra, cmfs=cmfs, illuminant=ones, method="Integration", shape=SHAPE
            )

        white = xyz(floored[None])[0]  # the perfect reflector relit
        t = np.moveaxis(truth["radiance"].values[0].astype(np.float64), 0, -1).reshape(-1, 32)
        s = np.moveaxis(estimate["radiance"].values[0].astype(np.float64), 0, -1).reshape(-1, 32)
        xyz_t, xyz_s = xyz(t) / white[1], xyz(s) / white[1]
        scale = 1.0 / np.percentile(xyz_t[:, 1], 99)
        white_xy = colour.XYZ_to_xy(white)
        expected = colour.delta_E(
            colour.XYZ_to_Lab(xyz_s * scale, white_xy),
            colour.XYZ_to_Lab(xyz_t * scale, white_xy),
            method="CIE 2000",
        )
        found = relit["delta_e"].sel(light=name).values[0].reshape(-1)
        np.testing.assert_allclose(found, expected, rtol=1e-4, atol=1e-5)
        assert float(relit["exposure_scale"].sel(light=name)[0]) == pytest.approx(scale, rel=1e-9)
        np.testing.assert_allclose(relit["white_xy"].sel(light=name), white_xy, atol=1e-9)
        assert 0.5 < np.median(expected) < 20  # visible: a wrong relighting would show


def test_a_metamer_under_the_capture_light_differs_under_fl11():
    """Two spectra equal in colour under the capture's light (here D65) but not under FL11."""
    d65 = light_on_bands("D65", WAVELENGTH).values
    truth = checker_under(d65, n_image=1)
    cmfs = colour.MSDS_CMFS[OBSERVER].copy().align(SHAPE).values  # (32, 3)
    null = np.linalg.svd(cmfs.T)[2][3:]  # spectra with XYZ = 0 under equal energy
    bump = null[0] / np.abs(null[0]).max() * 0.05
    values = truth["radiance"].values + bump[None, :, None, None]
    relit = relit_delta_e(truth.copy(data={"radiance": values}), truth, d65, dark_floor=0.0)
    stats = relit_statistics(relit)
    assert stats["D65"]["p95"] < 1e-3  # a metamer under the light it was captured under
    assert stats["FL11"]["median"] > 0.3 and stats["A"]["median"] > 0.03


def test_relighting_under_the_capture_light_is_the_identity_up_to_normalisation():
    d65 = light_on_bands("D65", WAVELENGTH)
    truth = checker_under(d65.values, n_image=1)["radiance"]
    relit = relight(truth, d65, "D65")
    ratio = relit.values / truth.values.astype(np.float64)
    np.testing.assert_allclose(ratio, ratio.flat[0], rtol=1e-6)
    assert relit.attrs["light"] == "D65" and relit.attrs["units"] == "1"
    # the normalisation: a perfect reflector relit has Y = 1 and the light's white
    flat = xr.DataArray(d65.values, dims="wavelength", coords={"wavelength": WAVELENGTH})
    weights = colour.msds_to_XYZ(
        relight(flat, d65, "A").values,
        cmfs=colour.MSDS_CMFS[OBSERVER],
        illuminant=colour.sd_ones(SHAPE),
        method="Integration",
        shape=SHAPE,
    )
    assert weights[1] == pytest.approx(100.0, rel=1e-9)
    np.testing.assert_allclose(colour.XYZ_to_xy(weights), [0.4476, 0.4074], atol=2e-3)  # A's white


def test_band_averages_keep_the_lines_of_fl11_that_point_sampling_misses():
    power = light_on_bands("FL11", WAVELENGTH).values
    expected = band_average("FL11")
    np.testing.assert_allclose(power / power.max(), expected / expected.max(), rtol=1e-4)
    point = colour.SDS_ILLUMINANTS["FL11"][WAVELENGTH]
    at = {w: i for i, w in enumerate(WAVELENGTH)}
    # the 435 nm line lies between the 430 and 440 nm bands: point samples miss it
    share = (power[at[430.0]] + power[at[440.0]]) / power.sum()
    assert share > 1.3 * (point[at[430.0]] + point[at[440.0]]) / point.sum()


def test_the_light_floor_caps_the_gain_where_the_light_is_dark():
    light = led().copy()
    light[:2] = 0.0  # no light at 410 and 420 nm
    truth = checker_under(led(), n_image=1)["radiance"]
    factor = reflectance_factor(truth, light, light_floor=0.05)
    np.testing.assert_allclose(
        factor.isel(wavelength=0).values, truth.isel(wavelength=0).values / 0.05, rtol=1e-6
    )
    assert factor.attrs["light_floor"] == 0.05
    relit = relit_delta_e(truth, truth, light)
    assert np.isfinite(relit["delta_e"].values).mean() > 0.9


def test_dark_pixels_of_the_truth_are_left_out_or_kept():
    values = checker_under(led(), n_image=1)["radiance"].values.copy()
    values[0, :, :2, :2] *= 1e-4  # a near-black patch
    truth = cube(values)
    estimate = truth.copy(data={"radiance": values * 1.1})
    relit = relit_delta_e(estimate, truth, led())
    assert np.isnan(relit["delta_e"].values[:, 0, :2, :2]).all()
    assert relit_statistics(relit)["A"]["excluded"] == pytest.approx(4 / values[0, 0].size)
    kept = relit_delta_e(estimate, truth, led(), dark_floor=0.0)
    assert np.isfinite(kept["delta_e"].values).all()


def test_a_lazy_cube_in_another_image_order_gives_the_same_maps():
    truth = checker_under(led(), n_image=2).assign_coords(image=[0, 1])
    estimate = truth.copy(data={"radiance": truth["radiance"].values * 1.05})
    eager = relit_delta_e(estimate, truth, led())
    lazy = relit_delta_e(
        estimate.isel(image=[1, 0]).chunk({"image": 1}), truth.chunk({"image": 1}), led()
    )
    assert lazy["delta_e"].chunks is not None
    np.testing.assert_allclose(
        lazy["delta_e"].sel(image=[0, 1]).values, eager["delta_e"].values, rtol=1e-6
    )


def test_bad_inputs_raise_naming_the_array_or_parameter():
    truth = checker_under(led(), n_image=1)
    light = xr.DataArray(led(), dims="wavelength", coords={"wavelength": WAVELENGTH + 5.0})
    with pytest.raises(SchemaError, match="illuminant_L:wavelength"):
        relit_delta_e(truth, truth, light)
    with pytest.raises(SchemaError, match="illuminant_L: expected 32 values"):
        relit_delta_e(truth, truth, led()[:-1])
    negative = led().copy()
    negative[3] = -0.1
    with pytest.raises(SchemaError, match="illuminant_L: expected finite, non-negative"):
        relight(truth["radiance"], negative, "A")
    with pytest.raises(SchemaError, match="spectra:radiance"):
        relit_delta_e(truth.isel(x=slice(0, 4)), truth, led())
    with pytest.raises(SchemaError, match="radiance:wavelength"):
        relight(truth["radiance"].drop_vars("wavelength"), led(), "A")
    with pytest.raises(ParameterError, match="not a colour-science illuminant"):
        relight(truth["radiance"], led(), "D-nonsense")
    with pytest.raises(ParameterError, match="light_floor"):
        relight(truth["radiance"], led(), "A", light_floor=0.0)
    with pytest.raises(ParameterError, match="white_percentile") as raised:
        relit_delta_e(truth, truth, led(), white_percentile=0.0, dark_floor=-1.0)
    assert "dark_floor" in str(raised.value)  # every problem at once
    with pytest.raises(ParameterError, match="targets"):
        relit_delta_e(truth, truth, led(), targets=("A", "A"))


def test_without_exposure_the_white_diffuser_is_white():
    light = led()
    truth = checker_under(light, n_image=2)  # radiance = reflectance x L: R is the reflectance
    estimate = truth.copy(data={"radiance": truth["radiance"].values * 1.05})
    absolute = relit_delta_e(estimate, truth, light, white_percentile=None, dark_floor=0.0)
    np.testing.assert_array_equal(absolute["exposure_scale"].values, 1.0)
    assert "white diffuser" in absolute.attrs["normalisation"]
    assert absolute.attrs["white_percentile"] == "none"
    exposed = relit_delta_e(estimate, truth, light, dark_floor=0.0)
    assert (exposed["exposure_scale"].values > 1).all()  # the chart's brightest patch is below 1
    assert not np.allclose(absolute["delta_e"].values, exposed["delta_e"].values)
