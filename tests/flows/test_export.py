"""Exports read back with the libraries other software uses: Spectral Python and xarray."""

import numpy as np
import pytest
import spectral
import xarray as xr
from support.cubes import WAVELENGTH, cube_dataset

from spectralize.flows.cli import main
from spectralize.flows.export import ENVI_IGNORE, ExportError, export, label_ranges
from spectralize.schemas.run import SPECTRA_PRECISION
from spectralize.store import RunStore
from spectralize.store.precision import round_mantissa


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """A store whose spectra are ordered by image set (labels 2, 0, 1), as reconstructions are."""
    rng = np.random.default_rng(5)
    values = rng.uniform(0.0, 1.0, (3, WAVELENGTH.size, 6, 9))
    values[:, :, 0, 0] = np.nan  # a pixel without a spectrum
    cube = cube_dataset(values).assign_coords(image=[2, 0, 1])
    run = RunStore.create(tmp_path_factory.mktemp("export") / "run.zarr")
    run.write("spectra", cube, fingerprint="spectra-fp")
    # what the store keeps (the cube's precision); the exports carry those values unchanged
    kept = round_mantissa(cube["radiance"].values, SPECTRA_PRECISION.keepbits)
    return run, cube.assign(radiance=cube["radiance"].copy(data=kept))


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
        expected = np.where(np.isnan(expected), ENVI_IGNORE, expected)  # no value: the ignore value
        np.testing.assert_array_equal(np.asarray(image.load()), expected)  # by label, not position
        assert image.metadata["spectralize image"] == str(label)
        bound = float(image.metadata["spectralize precision bound relative"])
        assert bound == SPECTRA_PRECISION.relative_bound
        assert float(image.metadata["spectralize phi_o"]) == float(cube["phi_o"].sel(image=label))


def test_netcdf_opens_in_xarray_with_cf_attributes(store, tmp_path):
    run, cube = store
    (path,) = export(run, tmp_path / "cube.nc", format="netcdf")
    with xr.open_dataset(path) as ds:
        assert ds.attrs["Conventions"] == "CF-1.10"
        assert ds["wavelength"].attrs["units"] == "nm"
        assert ds["radiance"].attrs["units"] == "1" and ds["theta_o"].attrs["units"] == "degree"
        assert ds["radiance"].attrs["precision_keepbits"] == SPECTRA_PRECISION.keepbits
        assert ds["radiance"].attrs["precision_bound_relative"] == SPECTRA_PRECISION.relative_bound
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
    with pytest.raises(ExportError, match=r"image labels of the group: 0-2 \(3 images\), found \[7\]"):
        export(run, tmp_path / "out", format="envi", images=[7])
    with pytest.raises(ExportError, match="truth/spectra"):
        export(run, tmp_path / "out", format="envi", group="truth/spectra")
    with pytest.raises(ExportError, match="one of envi, netcdf"):
        export(run, tmp_path / "out", format="tiff")
    assert not (tmp_path / "out").exists()


def test_envi_ignore_value_is_a_number_and_nan_pixels_carry_it(tmp_path):
    values = np.random.default_rng(2).uniform(0.0, 1.0, (1, WAVELENGTH.size, 3, 4))
    values[0, :, 1, 2] = np.nan  # a pixel without a value
    run = RunStore.create(tmp_path / "run.zarr")
    run.write("spectra", cube_dataset(values), fingerprint="spectra-fp")
    (header, _) = export(run, tmp_path / "envi", format="envi")
    image = spectral.open_image(str(header))
    ignore = float(image.metadata["data ignore value"])
    assert ignore == ENVI_IGNORE
    loaded = np.asarray(image.load())
    assert (loaded[1, 2] == ignore).all() and np.isfinite(loaded).all()


def test_netcdf_into_a_folder_name_writes_a_nc_file_and_says_where(store, tmp_path, capsys):
    run, _ = store
    assert main(["export", str(run.path), str(tmp_path / "nc_dir"), "--format", "netcdf"]) == 0
    (path,) = (tmp_path / "nc_dir").iterdir()
    assert path.suffix == ".nc"
    assert f"wrote {path}" in capsys.readouterr().out
    with xr.open_dataset(path) as ds:  # pixel coordinates in px, as in the store
        assert ds["y"].attrs["units"] == ds["x"].attrs["units"] == "px"


def test_a_mistyped_group_gets_the_closest_cube_group_and_only_cube_groups(store, tmp_path):
    run, _ = store
    with pytest.raises(
        ExportError,
        match=r"spectral-cube group of run.zarr: spectra, found spectr; did you mean 'spectra'\?",
    ):
        export(run, tmp_path / "out", format="envi", group="spectr")
    assert label_ranges([0, 1, 2, 3, 7, 9, 10, 11]) == "0-3, 7, 9-11"
