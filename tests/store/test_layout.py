"""How data sits on disk and reads back: sorted, loaded and pixel coordinates, netCDF-friendly attrs, text in a specified zarr type."""

import json
import warnings

import dask.array as da
import numpy as np
import xarray as xr


def image_cube(order):
    n = len(order)
    return xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                da.from_array(
                    np.arange(n, dtype=np.float32)[:, None, None, None]
                    * np.ones((1, 3, 2, 2), np.float32)
                ),
                {"units": "1"},
            )
        },
        coords={
            "image": np.asarray(order),
            "wavelength": ("wavelength", [450.0, 550.0, 650.0], {"units": "nm"}),
            "camera": ("image", da.from_array(np.asarray(order) % 2)),
        },
    )


def test_reads_are_sorted_have_loaded_coords_pixel_coords_and_netcdf_friendly_attrs(
    dark_store, tmp_path
):
    dark_store.write(
        "cube", image_cube([3, 0, 2, 1]), fingerprint="c", provenance={"node": "n", "p": {"a": 1}}
    )
    ds = dark_store.read("cube")
    assert ds.image.values.tolist() == [0, 1, 2, 3]
    assert ds.radiance.sel(image=0, wavelength=555, method="nearest").values.tolist() == [[1, 1], [1, 1]]
    assert ds.sel(image=slice(0, 1)).sizes["image"] == 2
    assert ds.camera.chunks is None  # loaded
    assert ds.where(ds.camera == 1, drop=True).image.values.tolist() == [1, 3]
    assert ds.x.values.tolist() == [0, 1] and ds.y.attrs["units"] == "px"
    assert json.loads(ds.attrs["spectralize_provenance"])["p"] == {"a": 1}  # JSON text
    assert dark_store.provenance("cube")["p"] == {"a": 1}
    ds.to_netcdf(tmp_path / "read.nc")  # a read() result writes as it is
    assert dark_store.read("cube", friendly=False).image.values.tolist() == [0, 1, 2, 3]  # on disk
    plain = xr.open_zarr(str(dark_store.path), group="cube", consolidated=True)
    assert json.loads(plain.attrs["spectralize_provenance"])["node"] == "n"
    plain.to_netcdf(tmp_path / "cube.nc")  # bookkeeping attrs are JSON strings
    assert xr.open_dataset(tmp_path / "cube.nc").radiance.shape == (4, 3, 2, 2)


def test_text_is_stored_with_a_specified_zarr_type_and_read_back_equal(store):
    lazy_labels = da.from_array(np.array(["red", "green", "blue"]), chunks=2)
    ds = xr.Dataset(
        {"label": (("image",), lazy_labels)},
        coords={"camera": ("image", np.array(["cam00", "cam01", "cam02"]))},
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. zarr's UnstableSpecificationWarning for <U
        store.write("text", ds, fingerprint="t")
    for name in ("label", "camera"):
        meta = json.loads((store.path / "text" / name / "zarr.json").read_text())
        assert meta["data_type"] == "string", (name, meta["data_type"])
    back = store.read("text")
    assert back.label.values.tolist() == ["red", "green", "blue"]
    assert back.camera.values.tolist() == ["cam00", "cam01", "cam02"]
