import colour
import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.evaluation.colorimetry import (
    OBSERVER,
    render_srgb,
    spectra_to_xyz,
    white_point,
    xyz_weights,
)

SHAPE = colour.SpectralShape(410, 720, 10)
WAVELENGTH = SHAPE.wavelengths
CHECKER = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]


def checker_reflectance() -> np.ndarray:
    return np.array([CHECKER[name].copy().align(SHAPE).values for name in CHECKER])


def checker_cube(values: np.ndarray, block: int = 2) -> xr.DataArray:
    """(1, wavelength, 4 * block, 6 * block) cube of 24 patch spectra ``values`` (24, 32)."""
    grid = values.reshape(4, 6, -1).transpose(2, 0, 1)
    cube = np.repeat(np.repeat(grid, block, 1), block, 2)[None].astype(np.float32)
    return xr.DataArray(
        cube, dims=("image", "wavelength", "y", "x"), coords={"wavelength": WAVELENGTH}, name="radiance"
    )


def patch_pixels(rgb: xr.DataArray, block: int = 2) -> np.ndarray:
    """(24, 3) colour of each patch, read at its top-left pixel."""
    return rgb.values[0, ::block, ::block].reshape(24, 3)


def colour_science_srgb(xyz: np.ndarray, white=colour.CCS_ILLUMINANTS[OBSERVER]["D65"]) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        rgb = colour.XYZ_to_sRGB(xyz, illuminant=white)
    return np.round(255 * np.clip(rgb, 0, 1)).astype(np.uint8)


@pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")
def test_colourchecker_srgb_matches_colour_science():
    reflectance = checker_reflectance()
    rgb = render_srgb(checker_cube(reflectance), illuminant="D65", exposure=1.0)
    assert rgb.dims == ("image", "y", "x", "channel") and rgb.dtype == np.uint8
    assert rgb["channel"].values.tolist() == ["R", "G", "B"]
    cmfs = colour.MSDS_CMFS[OBSERVER]
    d65 = colour.SDS_ILLUMINANTS["D65"]

    # colour-science's own computation on the same 10 nm samples, the white (perfect
    # reflector) integrated with the same weights as in ASTM E308
    def to_xyz(values):
        return (
            colour.msds_to_XYZ(values, cmfs=cmfs, illuminant=d65, method="Integration", shape=SHAPE)
            / 100
        )

    white = colour.XYZ_to_xy(to_xyz(np.ones(32)))
    assert rgb.attrs["white_xy"] == pytest.approx(white.tolist())
    np.testing.assert_array_equal(patch_pixels(rgb), colour_science_srgb(to_xyz(reflectance), white))
    # and on colour-science's spectral distributions (interpolated to 1 nm): within 2 levels
    xyz_sd = (
        np.array(
            [
                colour.sd_to_XYZ(CHECKER[name], cmfs=cmfs, illuminant=d65, method="Integration")
                for name in CHECKER
            ]
        )
        / 100
    )
    difference = patch_pixels(rgb).astype(int) - colour_science_srgb(xyz_sd).astype(int)
    assert np.abs(difference).max() <= 2
    # sanity: white 9.5 is light grey, black 2 is dark, and red is red
    white, black, red = patch_pixels(rgb)[18], patch_pixels(rgb)[23], patch_pixels(rgb)[14]
    assert white.min() > 230 and black.max() < 70 and red[0] > 150 > red[1]


def test_perfect_reflector_is_srgb_white_and_exposure_scales_luminance():
    white = xr.DataArray(
        np.ones((1, 32, 2, 2)), dims=("image", "wavelength", "y", "x"), coords={"wavelength": WAVELENGTH}
    )
    assert (render_srgb(white, illuminant="D65", exposure=1.0).values == 255).all()
    # equal energy white is adapted to D65 white (CAT02)
    assert render_srgb(white, illuminant=None, exposure=1.0).values.min() >= 254
    half = render_srgb(white, illuminant="D65", exposure=0.5, dtype="float")
    assert half.dtype == np.float32
    expected = 1.055 * 0.5 ** (1 / 2.4) - 0.055  # the sRGB encoding of linear 0.5
    np.testing.assert_allclose(half.values, expected, atol=1e-4)
    assert half.attrs["exposure_scale"] == 0.5
    assert "0.5" in half.attrs["exposure_normalisation"]


def test_auto_exposure_maps_the_percentile_of_luminance_to_white():
    radiance = checker_cube(checker_reflectance()) * 0.25
    rgb = render_srgb(radiance, illuminant="D65", percentile=100.0)
    xyz = spectra_to_xyz(radiance, illuminant="D65")
    assert rgb.attrs["exposure_scale"] == pytest.approx(1 / float(xyz.sel(xyz="Y").max()))
    assert "100th percentile" in rgb.attrs["exposure_normalisation"]
    brightest = patch_pixels(rgb)[18]  # white 9.5 has the highest Y
    assert brightest.max() == 255
    same = render_srgb(radiance * 4, illuminant="D65", percentile=100.0)
    np.testing.assert_array_equal(same.values, rgb.values)  # auto exposure is scale-free


def test_xyz_weights_give_the_white_point_and_y_of_one():
    weights = xyz_weights(WAVELENGTH, illuminant="D65")
    assert weights.dims == ("wavelength", "xyz")
    xyz = np.ones(32) @ weights.values
    assert xyz[1] == pytest.approx(1.0)
    np.testing.assert_allclose(colour.XYZ_to_xy(xyz), white_point("D65"), atol=2e-3)
    np.testing.assert_allclose(white_point(None), [1 / 3, 1 / 3])


def test_rendering_is_lazy_and_equals_the_eager_result():
    cube = checker_cube(checker_reflectance(), block=4)
    eager = render_srgb(cube, illuminant="D65", exposure=1.3)
    lazy = render_srgb(cube.chunk({"y": 8, "x": 12}), illuminant="D65", exposure=1.3)
    assert lazy.chunks is not None
    np.testing.assert_array_equal(lazy.compute().values, eager.values)


def test_nan_renders_black_and_bad_inputs_are_rejected():
    values = np.ones((1, 32, 1, 2))
    values[0, 3, 0, 1] = np.nan
    cube = xr.DataArray(
        values, dims=("image", "wavelength", "y", "x"), coords={"wavelength": WAVELENGTH}
    )
    rgb = render_srgb(cube, illuminant="D65", exposure=1.0).values
    assert rgb[0, 0, 1].tolist() == [0, 0, 0] and rgb[0, 0, 0].tolist() == [255, 255, 255]
    uneven = cube.assign_coords(wavelength=np.r_[WAVELENGTH[:-1], 725.0])
    with pytest.raises(ValueError, match="evenly spaced"):
        render_srgb(uneven)
    with pytest.raises(ValueError, match="not a colour-science illuminant"):
        render_srgb(cube, illuminant="nonsense")
    with pytest.raises(ValueError, match="exposure"):
        render_srgb(cube, exposure=-1.0)
    with pytest.raises(ValueError, match="wavelength"):
        render_srgb(cube.rename(wavelength="band"))
