"""``calibrate_spectral`` writes the measured illuminant ``L`` on the band wavelengths.

Band radiance is relative to the measured illuminant (``Q`` divides by reflectance times it),
so ``L`` in band radiance units is the measured spectrum at the band centres: what the set
model ``"shared-texel"`` reads from ``calibration/spectral``.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration.dark import average_dark_frames
from spectralize.nodes.calibration.oecf.low_snr import recover_spectral_oecf
from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf
from spectralize.nodes.calibration.spectral import calibrate_spectral
from spectralize.nodes.calibration.white_reference import measured_illuminant_on_bands
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.schemas import CalibrationError
from spectralize.schemas.run import GROUP_SCHEMAS
from spectralize.schemas.spec import validate_dataset

GROUP = "calibration/spectral"


@pytest.fixture(scope="module")
def tiny():
    run = {k: v.load() for k, v in simulate_run(get_recipe("tiny")).items() if k != "truth/spectra"}
    dark = average_dark_frames(run["raw/dark"]).load()
    spectral = calibrate_spectral(
        run["raw/white_reference"],
        run["raw/colour_checker"],
        dark,
        recover_rgb_oecf(run["raw/rgb"]),
        recover_spectral_oecf(run["raw/white_reference"], dark),
    )
    return run, spectral


def test_the_illuminant_is_the_measured_one_on_the_band_grid(tiny):
    run, spectral = tiny
    light = spectral["illuminant"]
    measured = run["raw/white_reference"]["illuminant"]
    assert light.dims == ("wavelength",)
    np.testing.assert_array_equal(
        light["wavelength"].values, spectral["quantum_efficiency"]["wavelength"]
    )
    np.testing.assert_allclose(
        light.values, measured.sel(wavelength=light["wavelength"]).values, rtol=1e-12
    )
    # the simulation's true LED spectrum, which band radiance is relative to
    np.testing.assert_allclose(
        light.values, run["truth/camera"]["illuminant"].sel(wavelength=light["wavelength"]).values
    )
    assert light.attrs["units"] == "1"
    assert light.attrs["source"] == "raw/white_reference:illuminant"
    assert "linear" in light.attrs["method"]


def test_the_group_with_its_illuminant_follows_its_schema(tiny):
    _, spectral = tiny
    assert "illuminant" in spectral
    assert validate_dataset(spectral, GROUP_SCHEMAS[GROUP], group=GROUP, values=True) == []
    # stores written before calibrate_spectral v5 have none, and still validate
    assert validate_dataset(spectral.drop_vars("illuminant"), GROUP_SCHEMAS[GROUP], group=GROUP) == []


def test_the_schema_refuses_an_illuminant_in_other_units_or_not_finite(tiny):
    _, spectral = tiny
    watts = spectral.assign(illuminant=spectral["illuminant"].assign_attrs(units="W m-2 sr-1 nm-1"))
    found = validate_dataset(watts, GROUP_SCHEMAS[GROUP], group=GROUP)
    assert found and "illuminant" in str(found[0])
    broken = spectral["illuminant"].copy(
        data=np.where(np.arange(spectral.sizes["wavelength"]) == 3, np.nan, 1.0)
    )
    found = validate_dataset(
        spectral.assign(illuminant=broken), GROUP_SCHEMAS[GROUP], group=GROUP, values=True
    )
    assert found and "illuminant" in str(found[0])


def test_an_illuminant_on_another_grid_is_interpolated_linearly_onto_the_bands():
    """A lab's measured spectrum on a 2 nm grid, the bands every 10 nm off its points."""
    grid = np.arange(400.0, 731.0, 2.0)
    values = 1.0 + 0.5 * np.sin(grid / 37.0) + 1e-3 * (grid - 400.0) ** 1.5
    measured = xr.DataArray(values, dims="wavelength", coords={"wavelength": grid})
    bands = np.arange(415.0, 721.0, 10.0)
    light = measured_illuminant_on_bands(measured[::-1], bands)  # order does not matter
    np.testing.assert_allclose(light.values, np.interp(bands, grid, values), rtol=1e-12)
    np.testing.assert_array_equal(light["wavelength"].values, bands)
    assert light.attrs["units"] == "1"


def test_an_illuminant_short_of_the_bands_or_not_positive_is_refused():
    grid = np.arange(450.0, 701.0, 5.0)
    measured = xr.DataArray(np.ones(grid.size), dims="wavelength", coords={"wavelength": grid})
    with pytest.raises(
        CalibrationError, match=r"raw/white_reference:illuminant: .*covers 450.0..700.0 nm .*\[420.0\]"
    ):
        measured_illuminant_on_bands(measured, np.array([420.0, 500.0]))
    dark = measured.where(measured["wavelength"] != 500.0, 0.0)
    with pytest.raises(CalibrationError, match=r"illuminant is not positive at \[500.0\] nm"):
        measured_illuminant_on_bands(dark, np.array([480.0, 500.0]))
