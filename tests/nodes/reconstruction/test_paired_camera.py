"""Each image read through its own camera's C: its RGB mapped into the paired camera's."""

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction.inputs import in_paired_camera
from spectralize.schemas.errors import ReconstructionError


def _hdr():
    rng = np.random.default_rng(0)
    radiance = xr.DataArray(
        rng.random((3, 4, 5, 3)).astype(np.float32),
        dims=("image", "y", "x", "channel"),
        coords={"image": [10, 11, 12], "channel": ["R", "G", "B"], "camera": ("image", [0, 1, 1])},
    )
    return xr.Dataset({"radiance": radiance})


def _calibration(cameras, maps):
    return xr.Dataset(
        {"rgb_transform": (("camera", "channel", "channel_in"), np.stack(maps))},
        coords={"camera": cameras, "camera_name": ("camera", [f"c{k}" for k in cameras])},
    )


def test_each_image_is_mapped_by_its_camera_s_map():
    hdr = _hdr()
    side = np.array([[2.0, 0.1, 0.0], [0.0, 3.0, 0.0], [0.0, -0.2, 4.0]])
    out = in_paired_camera(hdr, _calibration([0, 1], [np.eye(3), side]))
    values, mapped = hdr["radiance"].values, out["radiance"].values
    np.testing.assert_allclose(mapped[0], values[0], rtol=1e-6)
    np.testing.assert_allclose(mapped[1:], np.einsum("ck,iyxk->iyxc", side, values[1:]), rtol=1e-5)
    assert out["radiance"].dims == hdr["radiance"].dims and out["radiance"].dtype == np.float32
    assert out["image"].values.tolist() == [10, 11, 12] and "camera_name" not in out["radiance"].coords


def test_without_maps_or_identity_maps_the_rgb_is_unchanged_and_a_missing_camera_is_an_error():
    hdr = _hdr()
    assert in_paired_camera(hdr, xr.Dataset()) is hdr
    assert in_paired_camera(hdr, _calibration([0, 1], [np.eye(3), np.eye(3)])) is hdr
    with pytest.raises(ReconstructionError, match=r"no map for RGB camera\(s\) \[1\]"):
        in_paired_camera(hdr, _calibration([0], [2 * np.eye(3)]))
