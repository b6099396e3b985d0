"""Exports read back with the libraries other software uses: Spectral Python and xarray."""

import numpy as np
import pytest
import spectral
import xarray as xr
from support.cubes import WAVELENGTH, cube_dataset

from spectralize.flows.cli import main
from spectralize.flows.export import ExportError, export
from spectralize.store import RunStore


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A store whose spectra are ordered by image set (labels 2, 0, 1), as reconstructions are."""
    rng = np.random.default_rng(5)
    values = rng.uniform(0.0, 1.0, (3, WAVELENGTH.size, 6, 9))
    values[:, :, 0, 0] = np.nan  # a pixel without a spectrum
    cube = cube_dataset(values).assign_coords(image=[2, 0, 1])
    run = RunStore.create(tmp_path_factory.mktemp("export") / "run.zarr")
    run.write("spectra", cube, fingerprint="spectra-fp")
    return run, cube


@pytest.mark.filterwarnings("ignore::spectral.io.spyfile.NaNValueWarning")
def test_envi_opens_in_spectral_python_per_image_with_wavelengths(store, tmp_path):
    run, cube = store
    files = export(run, tmp_path / "envi", format="envi", images=[0, 2])
    headers = [f for f in files if f.suffix == ".hdr"]
    assert [h.name for h in headers] == ["run_spectra_image0.hdr", "run_spectra_image2.hdr"]
    for header, label in zip(headers, (0, 2), strict=True):
        image = spectral.open_image(str(header))
        assert image.shape == (6, 9, WAVELENGTH.size)  # lines, samples, bands
        np.testing.assert_allclose(image.bands.centers, WAVELENGTH)
        assert image.bands.band_unit == "Nanometers"
        expected = cube["radiance"].sel(image=label).transpose("y", "x", "wavelength").values
        np.testing.assert_array_equal(np.asarray(image.load()), expected)  # by label, not position
        assert image.metadata["spectralize image"] == str(label)
        assert float(image.metadata["spectralize phi_o"]) == float(cube["phi_o"].sel(image=label))


def test_netcdf_opens_in_xarray_with_cf_attributes(store, tmp_path):
    run, cube = store
    (path,) = export(run, tmp_path / "cube.nc", format="netcdf")
    with xr.open_dataset(path) as ds:
        assert ds.attrs["Conventions"] == "CF-1.10"
        assert ds["wavelength"].attrs["units"] == "nm"
        assert ds["radiance"].attrs["units"] == "1" and ds["theta_o"].attrs["units"] == "degree"
        assert sorted(ds["image"].values.tolist()) == [0, 1, 2]
        for label in (0, 1, 2):  # each image's cube under its own label
            np.testing.assert_array_equal(
                ds["radiance"].sel(image=label).values, cube["radiance"].sel(image=label).values
            )
            assert float(ds["phi_o"].sel(image=label)) == float(cube["phi_o"].sel(image=label))
        np.testing.assert_array_equal(ds["x"].values, np.arange(9))


def test_netcdf_per_image_and_a_selection_from_the_command_line(store, tmp_path, capsys):
    run, cube = store
    code = main(
        [
            "export",
            str(run.path),
            str(tmp_path / "nc"),
            "--format",
            "netcdf",
            "--per-image",
            "--image",
            "1",
        ]
    )
    assert code == 0, capsys.readouterr().err
    (path,) = sorted((tmp_path / "nc").glob("*.nc"))
    with xr.open_dataset(path) as ds:
        assert ds["image"].values.tolist() == [1]
        np.testing.assert_array_equal(ds["radiance"].values[0], cube["radiance"].sel(image=1).values)


def test_unknown_labels_groups_and_formats_are_errors_and_write_nothing(store, tmp_path):
    run, _ = store
    with pytest.raises(ExportError, match=r"image labels of the group: \[\d, \d, \d\], found \[7\]"):
        export(run, tmp_path / "out", format="envi", images=[7])
    with pytest.raises(ExportError, match="truth/spectra"):
        export(run, tmp_path / "out", format="envi", group="truth/spectra")
    with pytest.raises(ExportError, match="one of envi, netcdf"):
        export(run, tmp_path / "out", format="tiff")
    assert not (tmp_path / "out").exists()
