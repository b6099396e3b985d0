"""Tests of spectralize.nodes.calibration.hdr: Robertson HDR merge of RGB exposure series."""

from __future__ import annotations

import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration import hdr, oecf
from spectralize.nodes.simulation.camera_model import capture, response_model
from spectralize.schemas import CalibrationError, SchemaError

TIMES = np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0


def noise_for(bit_depth: int) -> tuple[float, float]:
    scale = 2.0 ** (bit_depth - 10)
    return 16.0 * scale, 3.0 * scale


def raw_rgb(
    radiance: np.ndarray,
    *,
    bit_depth: int = 10,
    model: str = "gamma",
    times: np.ndarray = TIMES,
    cameras: list[int] | None = None,
    seed: int = 0,
) -> xr.Dataset:
    """raw/rgb group simulated by eq. 5 from radiance (image, y, x, channel)."""
    rng = np.random.default_rng(seed)
    offset, sigma = noise_for(bit_depth)
    truth = response_model(model)
    counts = np.stack(
        [
            capture(
                image[None],
                times[:, None, None, None],
                response=truth,
                adc_offset=offset,
                noise_sigma=sigma,
                bit_depth=bit_depth,
                seed=rng,
            )
            for image in radiance
        ]
    )
    n = radiance.shape[0]
    return xr.Dataset(
        {
            "counts": (
                ("image", "exposure", "y", "x", "channel"),
                counts,
                {"units": "DN", "long_name": "raw RGB pixel value"},
            )
        },
        coords={
            "exposure_time": (("image", "exposure"), np.tile(times, (n, 1))),
            "channel": ["R", "G", "B"],
            "camera": ("image", cameras or [0] * n),
            "rotation": ("image", np.arange(n)),
            "led": ("image", np.arange(n)),
        },
        attrs={"bit_depth": bit_depth},
    )


def true_response(model: str, bit_depth: int) -> tuple[xr.DataArray, float]:
    """The true f at raw codes normalised to 1 at the mid code, and that normalisation."""
    offset, sigma = noise_for(bit_depth)
    full = 2**bit_depth - 1
    codes = np.arange(full + 1)
    f = response_model(model).response((codes + 0.5 - offset) / full)
    norm = float(np.interp(full / 2, codes, f))
    return xr.DataArray(
        f / norm,
        dims="code",
        coords={"code": codes},
        attrs={"black_level": int(offset + 3 * sigma), "saturation": full, "weighting": "gaussian"},
    ), norm


def random_radiance(shape: tuple[int, ...], seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.exp(rng.uniform(np.log(5e-3), np.log(1.5), shape))


@pytest.mark.parametrize("bit_depth", [8, 10, 12, 16])
def test_merge_reproduces_the_radiance(bit_depth: int) -> None:
    radiance = random_radiance((1, 40, 40, 3))
    ds = raw_rgb(radiance, bit_depth=bit_depth)
    response, norm = true_response("gamma", bit_depth)
    out = hdr.merge_hdr(ds, response)
    estimate = out["radiance"].values * norm
    ratio = estimate / radiance
    assert out["radiance"].dtype == np.float32
    assert np.all(np.isfinite(estimate))
    assert abs(np.median(ratio) - 1) < 0.005  # unbiased
    assert np.median(np.abs(ratio - 1)) < 0.02  # within the read noise
    assert np.quantile(np.abs(ratio - 1), 0.99) < 0.15  # darkest pixels: ~9% noise


def test_merge_with_a_recovered_response() -> None:
    radiance = random_radiance((2, 96, 96, 3))
    ds = raw_rgb(radiance)
    recovered = oecf.recover_oecf(ds, black_level=25)
    assert recovered["response"].dims == ("camera", "channel", "code")
    merged = hdr.merge_hdr(ds, recovered)["radiance"].values
    truth, norm = true_response("gamma", 10)
    reference = hdr.merge_hdr(ds, truth)["radiance"].values
    # one global scale separates them (the response is known up to scale)
    scale = np.median(merged / reference)
    assert np.median(np.abs(merged / (scale * reference) - 1)) < 0.005
    assert np.median(np.abs(merged * norm / scale / radiance - 1)) < 0.02


def test_output_contract_and_coords() -> None:
    ds = raw_rgb(random_radiance((2, 16, 24, 3)))
    response, _ = true_response("gamma", 10)
    out = hdr.merge_hdr(ds, response)
    radiance = out["radiance"]
    assert radiance.dims == ("image", "y", "x", "channel")
    assert radiance.shape == (2, 16, 24, 3)
    assert radiance.attrs["units"] == "1"
    assert radiance.attrs["long_name"] == "relative RGB radiance"
    assert out["channel"].values.tolist() == ["R", "G", "B"]
    assert out["rotation"].values.tolist() == [0, 1]
    assert "exposure_time" not in out.coords
    assert out.attrs["black_level"] == 25 and out.attrs["saturation"] == 1023
    assert out.attrs["weighting"] == "gaussian"
    assert out.attrs["n_saturated"] == out.attrs["n_underexposed"] == 0
    assert isinstance(radiance.data, np.ndarray)


def test_lazy_input_stays_lazy_and_chunks_agree() -> None:
    ds = raw_rgb(random_radiance((2, 40, 40, 3)))
    response, _ = true_response("log", 10)
    eager = hdr.merge_hdr(ds, response, chunks={"image": 2, "y": 40, "x": 40})
    lazy_input = ds.chunk({"image": 1, "y": 16, "x": 16})
    lazy = hdr.merge_hdr(lazy_input, response)
    assert isinstance(lazy["radiance"].data, da.Array)
    assert lazy["radiance"].data.numblocks == (2, 3, 3, 1)
    np.testing.assert_array_equal(lazy["radiance"].values, eager["radiance"].values)


def test_a_chunk_of_many_images_is_merged_in_blocks_with_the_same_result(monkeypatch) -> None:
    ds = raw_rgb(random_radiance((7, 8, 8, 3)))
    response, _ = true_response("log", 10)
    per_image = hdr.merge_hdr(ds.chunk({"image": 1}), response)["radiance"]
    image = ds["counts"].nbytes // ds.sizes["image"]
    monkeypatch.setattr(hdr, "BLOCK_BYTES", 2 * image)  # a shard of 7 images: 4 blocks
    blocks = hdr._image_block(ds["counts"].chunk({"image": -1}))
    assert blocks == (2, 2, 2, 1)
    in_blocks = hdr.merge_hdr(ds.chunk({"image": -1}), response)["radiance"]
    assert in_blocks.chunks[0] == (7,)  # given back the chunks read
    np.testing.assert_array_equal(in_blocks.values, per_image.values)


def test_each_image_uses_its_cameras_response() -> None:
    radiance = random_radiance((2, 40, 40, 3))
    gamma = raw_rgb(radiance[:1], model="gamma", seed=1)
    log = raw_rgb(radiance[1:], model="log", seed=2)
    ds = xr.concat([gamma, log], dim="image").assign_coords(camera=("image", [5, 9]))
    f_gamma, n_gamma = true_response("gamma", 10)
    f_log, n_log = true_response("log", 10)
    per_camera = xr.concat(
        [f_gamma.expand_dims(channel=["R", "G", "B"]), f_log.expand_dims(channel=["R", "G", "B"])],
        dim=xr.DataArray([5, 9], dims="camera", name="camera"),
    )
    per_camera.attrs = f_gamma.attrs
    out = hdr.merge_hdr(ds, per_camera)["radiance"].values
    for image, norm in ((0, n_gamma), (1, n_log)):
        ratio = out[image] * norm / radiance[image]
        assert np.median(np.abs(ratio - 1)) < 0.02
    wrong = hdr.merge_hdr(ds, f_gamma)["radiance"].values
    assert np.median(np.abs(wrong[1] * n_gamma / radiance[1] - 1)) > 0.1


def test_saturated_and_dark_pixels_get_bounds_counted_and_warned() -> None:
    radiance = random_radiance((1, 20, 20, 3))
    radiance[0, 0, 0, :] = 500.0  # saturated in every exposure
    radiance[0, 0, 1, :] = 0.0  # dark in every exposure
    ds = raw_rgb(radiance)
    response, norm = true_response("gamma", 10)
    with pytest.warns(RuntimeWarning, match=r"3 saturated in every exposure.*3 dark in every"):
        out = hdr.merge_hdr(ds, response)
    assert out.attrs["n_saturated"] == 3
    assert out.attrs["n_underexposed"] == 3
    assert out.attrs["n_unresolved"] == 0
    x = out["radiance"].values[0] * norm
    lower = response.values[1023] * norm / TIMES[0]
    np.testing.assert_allclose(x[0, 0], lower, rtol=1e-5)  # f(saturation) / t_min
    assert np.all(x[0, 0] < 500.0)  # a lower bound
    upper = response.values[25] * norm / TIMES[-1]
    np.testing.assert_allclose(x[0, 1], upper, rtol=1e-5)  # f(black_level) / t_max
    assert np.all(x[0, 1] >= 0.0)
    assert np.all(np.isfinite(x))


def test_merge_robertson_core_by_hand() -> None:
    counts = np.array([[10, 40, 250], [5, 20, 255]])  # two pixels, three exposures
    times = np.array([1.0, 4.0, 25.0])
    f = np.arange(256, dtype=float)[None, :]
    weights = oecf.weighting_function(np.arange(256), black_level=0, saturation=255, kind="uniform")
    x = hdr.merge_robertson(counts, times, f, weights, black_level=0, saturation=255)
    expected0 = (1 * 10 + 4 * 40 + 25 * 250) / (1 + 16 + 625)
    expected1 = (1 * 5 + 4 * 20) / (1 + 16)  # the saturated sample is excluded
    np.testing.assert_allclose(x, [expected0, expected1], rtol=1e-6)


# -- bad input ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def small() -> xr.Dataset:
    return raw_rgb(random_radiance((2, 8, 8, 3)))


@pytest.mark.parametrize(
    ("times", "word"),
    [([1.0, 3.0, 2.0, 25.0, 60.0], "unsorted"), ([1.0, 3.0, 3.0, 25.0, 60.0], "duplicate")],
)
def test_unsorted_or_duplicate_times(small: xr.Dataset, times: list[float], word: str) -> None:
    bad = small.assign_coords(
        exposure_time=(("image", "exposure"), np.array([TIMES, np.array(times) / 60]))
    )
    response, _ = true_response("gamma", 10)
    with pytest.raises(CalibrationError, match=rf"exposure_time \(image 1\).*{word}"):
        hdr.merge_hdr(bad, response)


def test_all_saturated_or_dark_frames(small: xr.Dataset) -> None:
    response, _ = true_response("gamma", 10)
    counts = small["counts"].values.copy()
    counts[1, 4, :, :, 2] = 1023
    with pytest.raises(CalibrationError, match=r"image=1, exposure=4, channel=2 .*entirely saturated"):
        hdr.merge_hdr(small.copy(data={"counts": counts}), response)
    counts = small["counts"].values.copy()
    counts[0, 0] = 20
    with pytest.raises(CalibrationError, match=r"image=0, exposure=0, .*entirely dark"):
        hdr.merge_hdr(small.copy(data={"counts": counts}), response)


def test_contract_violations(small: xr.Dataset) -> None:
    response, _ = true_response("gamma", 10)
    with pytest.raises(SchemaError, match="expected dims"):
        hdr.merge_hdr(small.isel(channel=0), response)
    with pytest.raises(SchemaError, match="integer DN"):
        hdr.merge_hdr(small.astype(float), response)
    with pytest.raises(SchemaError, match="bit_depth"):
        hdr.merge_hdr(small.drop_attrs(), response)
    with pytest.raises(SchemaError, match="exposure_time"):
        hdr.merge_hdr(small.drop_vars("exposure_time"), response)
    counts = small["counts"].values.copy()
    counts[0, 2, 0, 0, 0] = 5000
    with pytest.raises(CalibrationError, match=r"must lie in \[0, 1023\].*5000"):
        hdr.merge_hdr(small.copy(data={"counts": counts}), response)


def test_response_mismatches(small: xr.Dataset) -> None:
    response, _ = true_response("gamma", 10)
    rg = response.expand_dims(channel=["R", "G"])
    with pytest.raises(CalibrationError, match=r"no channel\(s\) \['B'\]"):
        hdr.merge_hdr(small, rg)
    per_camera = response.expand_dims(camera=[3])
    with pytest.raises(CalibrationError, match=r"no response for camera\(s\) \[0\]"):
        hdr.merge_hdr(small, per_camera)
    low = response.assign_attrs(dark_subtracted=True)
    with pytest.raises(CalibrationError, match="dark-subtracted"):
        hdr.merge_hdr(small, low)
    with pytest.raises(CalibrationError, match="NaN"):
        hdr.merge_hdr(small, response.where(response.code != 7))
    with pytest.raises(CalibrationError, match="black_level < saturation"):
        hdr.merge_hdr(small, response, black_level=900, saturation=800)
