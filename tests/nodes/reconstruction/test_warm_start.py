import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction.warm_start import transport_spectra, warm_start
from spectralize.schemas import ReconstructionError


def test_spectra_follow_appearance_and_intensity():
    rng = np.random.default_rng(0)
    materials_rgb = np.array([[1.0, 0.2, 0.1], [0.1, 0.8, 0.3], [0.2, 0.2, 0.9]])
    materials_spectra = rng.random((3, 32))
    labels = rng.integers(0, 3, 300)
    shade = rng.uniform(0.5, 1.5, 300)
    source_rgb = materials_rgb[labels] * shade[:, None]
    source_spectra = materials_spectra[labels] * shade[:, None]
    target_labels = rng.integers(0, 3, 50)
    target_shade = rng.uniform(0.6, 1.4, 50)
    moved = transport_spectra(
        source_rgb, source_spectra, materials_rgb[target_labels] * target_shade[:, None]
    )
    np.testing.assert_allclose(
        moved, materials_spectra[target_labels] * target_shade[:, None], rtol=0.05
    )


def test_xarray_interface_keeps_target_coords():
    rgb = xr.DataArray(
        np.random.default_rng(1).random((2, 4, 5, 3)),
        dims=("image", "y", "x", "channel"),
        coords={"image": [0, 1], "led": ("image", [3, 4])},
    )
    spectra = xr.DataArray(
        np.random.default_rng(2).random((2, 32, 4, 5)),
        dims=("image", "wavelength", "y", "x"),
        coords={"wavelength": np.arange(410, 730, 10.0)},
    )
    target = rgb.assign_coords(image=[7, 8], led=("image", [9, 10]))
    source_rgb = rgb.values.reshape(-1, 3)  # solved pixels, as the flow samples them
    source_spectra = spectra.transpose("image", "y", "x", "wavelength").values.reshape(-1, 32)
    out = warm_start(source_rgb, source_spectra, target, spectra["wavelength"].values, k=1)
    assert out.dims == ("image", "wavelength", "y", "x")
    assert out["image"].values.tolist() == [7, 8] and out["led"].values.tolist() == [9, 10]
    assert out["wavelength"].values.tolist() == spectra["wavelength"].values.tolist()
    # identical RGB, one neighbour -> the source's own spectra
    np.testing.assert_allclose(out.values, spectra.values, rtol=1e-5)


def test_mismatched_inputs_are_named():
    with pytest.raises(ReconstructionError, match="source_spectra"):
        transport_spectra(np.ones((3, 3)), np.ones((2, 32)), np.ones((1, 3)))
    with pytest.raises(ReconstructionError, match="target_rgb"):
        warm_start(np.ones((3, 3)), np.ones((3, 32)), xr.DataArray(np.ones((4, 3))), np.arange(32))
