"""Each camera's own black level in the HDR merge, and recover_rgb_oecf's bounded sample.

Two RGB cameras of one run with different black levels (another lab's capture: capture.toml's
``rgb.black_level_dn`` per camera). The response of each camera is recovered above its own
black level, so the merge weights each image's codes with its own camera's level; one level
for all (the lowest camera's, hdr_merge version 1) weighted the higher camera's noise floor.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration import hdr
from spectralize.nodes.calibration.declarations import HDR_MERGE, merge_hdr_node
from spectralize.nodes.calibration.oecf import robertson
from spectralize.nodes.simulation.camera_model import capture, response_model
from spectralize.schemas import CalibrationError

TIMES = np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0
FULL = 1023  # 10 bit
OFFSETS = {0: 16, 1: 120}  # ADC offsets [DN] of the two cameras
SIGMA = 3.0  # read noise [DN]


def two_cameras(
    images_per_camera: int = 2, side: int = 24, seed: int = 1
) -> tuple[xr.Dataset, np.ndarray]:
    """raw/rgb of two cameras (offsets 16 and 120 DN, linear sensors) over one scene with a
    black patch (no light: every exposure at the camera's noise floor); and the radiance."""
    rng = np.random.default_rng(seed)
    n = 2 * images_per_camera
    radiance = np.exp(rng.uniform(np.log(3e-3), np.log(2.0), (n, side, side, 3)))
    radiance[:, :4, :4] = 0.0
    cameras = [i % 2 for i in range(n)]
    counts = np.stack(
        [
            capture(
                radiance[i][None],
                TIMES[:, None, None, None],
                response=response_model("linear"),
                adc_offset=OFFSETS[cameras[i]],
                noise_sigma=SIGMA,
                bit_depth=10,
                seed=100 + i,
            )
            for i in range(n)
        ]
    )
    raw = xr.Dataset(
        {"counts": (("image", "exposure", "y", "x", "channel"), counts, {"units": "DN"})},
        coords={
            "exposure_time": (("image", "exposure"), np.tile(TIMES, (n, 1))),
            "channel": ["R", "G", "B"],
            "camera": ("image", cameras),
        },
        attrs={"bit_depth": 10, "black_level_dn": [OFFSETS[0] + 6, OFFSETS[1] + 6]},
    )
    return raw, radiance


def true_oecf_rgb() -> xr.Dataset:
    """calibration/oecf_rgb with each camera's true (linear) response over its offset and its
    black level, offset + 3 sigma."""
    codes = np.arange(FULL + 1)
    tables = [np.clip((codes + 0.5 - OFFSETS[c]) / FULL, 0.0, None) for c in (0, 1)]
    tables = [t / np.interp(FULL / 2, codes, t) for t in tables]
    levels = [OFFSETS[c] + int(3 * SIGMA) for c in (0, 1)]
    return xr.Dataset(
        {
            "response": (("camera", "channel", "code"), np.stack([np.stack([t] * 3) for t in tables])),
            "black_level": ("camera", levels, {"units": "DN"}),
        },
        coords={"camera": [0, 1], "channel": ["R", "G", "B"], "code": codes},
        attrs={"bit_depth": 10, "black_level": min(levels), "saturation": FULL, "weighting": "gaussian"},
    )


def merged(raw: xr.Dataset, oecf: xr.Dataset, **levels: int) -> xr.Dataset:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the black patch: no weighted sample
        return hdr.merge_hdr(raw, oecf, **levels)


def test_each_image_is_merged_with_its_cameras_black_level() -> None:
    raw, _ = two_cameras()
    oecf = true_oecf_rgb()
    out = merged(raw, oecf)
    assert out.attrs["black_level"] == [25, 129] and out.attrs["level_cameras"] == [0, 1]
    # each camera's images as if merged alone with its own level (the method's definition)
    for camera, level in ((0, 25), (1, 129)):
        images = np.flatnonzero(raw["camera"].values == camera)
        alone = merged(raw.isel(image=images), oecf.sel(camera=[camera]), black_level=level)
        np.testing.assert_array_equal(out["radiance"].values[images], alone["radiance"].values)
    # one level for all (the lowest camera's, the former merge) changes the higher camera's
    # radiance and only its: its noise floor (121..129 DN) got weight
    old = merged(raw, oecf, black_level=25)
    high = raw["camera"].values == 1
    np.testing.assert_array_equal(old["radiance"].values[~high], out["radiance"].values[~high])
    assert np.mean(old["radiance"].values[high] != out["radiance"].values[high]) > 0.3


def test_the_higher_cameras_floor_is_counted_and_bounded() -> None:
    """A black patch (no light): the higher-black-level camera's codes sit at its noise floor
    (120 +- 3 DN) in every exposure. With its own level (129 DN) every such pixel-channel is
    counted as under-exposed and gets the documented upper bound f(black)/t_max; with the
    lowest camera's level (25 DN) its floor noise was merged as a measurement and not
    counted (n_underexposed missed most of them)."""
    raw, _ = two_cameras()
    oecf = true_oecf_rgb()
    high = np.flatnonzero(raw["camera"].values == 1)
    new = merged(raw, oecf)
    old = merged(raw, oecf, black_level=25)
    patch = new["radiance"].values[high][:, :4, :4]
    bound = float(oecf["response"].sel(camera=1).isel(channel=0, code=129)) / TIMES[-1]
    np.testing.assert_allclose(patch, bound, rtol=1e-6)
    assert np.all(old["radiance"].values[high][:, :4, :4] <= bound)  # below the bound: noise
    assert np.unique(old["radiance"].values[high][:, :4, :4]).size > 10  # noise, no bound
    # the higher camera's patch: 2 images x 4 x 4 px x 3 channels more under-exposed at least
    assert new.attrs["n_underexposed"] - old.attrs["n_underexposed"] >= 2 * 4 * 4 * 3


def test_radiance_error_of_the_higher_camera_old_and_new() -> None:
    """The higher camera's relative radiance error over the lit, resolvable range (radiance
    at least 10x the darkest): with its own black level (new) and with the lowest camera's
    (old) both within the read noise. On these sensors (the true response, valid below the
    black level too) the floor samples the old level weighted were unbiased: the change is
    the contract (each camera's under-exposed codes get weight 0, as its response was
    recovered with), not a bias in lit pixels."""
    raw, radiance = two_cameras(images_per_camera=2, side=32, seed=3)
    oecf = true_oecf_rgb()
    high = raw["camera"].values == 1
    x = radiance[high]
    new = merged(raw, oecf)["radiance"].values[high]
    old = merged(raw, oecf, black_level=25)["radiance"].values[high]
    bright = x > 0.1
    scale = np.median(new[bright] / x[bright])
    lit = x > 0.03
    for estimate in (new, old):
        error = np.abs(estimate[lit] / (scale * x[lit]) - 1)
        assert np.median(error) < 0.02
    np.testing.assert_allclose(old[bright], new[bright], rtol=0.02)


def test_a_frame_dark_at_its_cameras_level_is_refused() -> None:
    """A frame of the higher camera entirely at its floor (light off) carries no information:
    refused by the merge and by the node's value check with that camera's level; one level
    for all (the lowest) let it through."""
    raw, _ = two_cameras()
    counts = raw["counts"].values.copy()
    rng = np.random.default_rng(0)
    high = int(np.flatnonzero(raw["camera"].values == 1)[0])
    counts[high, 0] = 120 + rng.integers(-3, 4, counts[high, 0].shape)  # 117..123 DN, > 25
    dark = raw.copy(data={"counts": counts})
    oecf = true_oecf_rgb()
    with pytest.raises(CalibrationError, match=r"entirely dark \(<= black_level = 129\)"):
        merged(dark, oecf)
    refusals = HDR_MERGE.refusals({"raw_rgb": dark, "oecf_rgb": oecf})
    assert len(refusals) == 1 and "black_level = 129" in str(refusals[0])
    assert f"image={high}, exposure=0" in str(refusals[0])
    assert HDR_MERGE.refusals({"raw_rgb": dark, "oecf_rgb": oecf}, {"black_level": 25}) == []
    assert HDR_MERGE.refusals({"raw_rgb": raw, "oecf_rgb": oecf}) == []


def test_nodes_carry_the_levels_per_camera() -> None:
    """recover_rgb_oecf writes each camera's black level as a variable over camera [DN];
    hdr_merge's function reads it, and its black_level parameter overrides every camera."""
    raw, _ = two_cameras(images_per_camera=2, side=32)
    oecf = robertson.recover_rgb_oecf(raw, calibration_targets=False)
    levels = oecf["black_level"]
    assert levels.dims == ("camera",) and levels.attrs["units"] == "DN"
    assert levels.values.tolist() == [OFFSETS[0] + 6 + 3, OFFSETS[1] + 6 + 3]  # black_level_dn + 3
    assert oecf.attrs["black_levels"] == levels.values.tolist()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        out = merge_hdr_node(raw, oecf)
        forced = merge_hdr_node(raw, oecf, black_level=40)
    assert out.attrs["black_level"] == levels.values.tolist()
    assert forced.attrs["black_level"] == 40
    direct = merged(raw, oecf, black_level={0: 25, 1: 129})
    np.testing.assert_array_equal(out["radiance"].values, direct["radiance"].values)


# -- recover_rgb_oecf's bounded, deterministic sample of raw/rgb ---------------------------------
def test_rgb_oecf_sample_is_an_even_deterministic_spread() -> None:
    cameras = np.tile(np.arange(3), 40)  # 120 images, 40 per camera, cameras interleaved
    raw = xr.Dataset(coords={"camera": ("image", cameras)})
    every = robertson.rgb_oecf_sample(raw)
    np.testing.assert_array_equal(every, np.arange(120))  # fewer than MAX_IMAGES: all
    picked = robertson.rgb_oecf_sample(raw, max_images=5)
    np.testing.assert_array_equal(picked, robertson.rgb_oecf_sample(raw, max_images=5))
    for camera in range(3):
        own = picked[cameras[picked] == camera]
        assert own.tolist() == [camera + 3 * k for k in (0, 10, 20, 29, 39)]  # first to last


def test_recovery_reads_the_sample_and_is_unchanged_below_the_cap(monkeypatch) -> None:
    """Below MAX_IMAGES per camera the response is the one from every image (the tests' and
    demo runs, lazy or not); above it, from the sample: the HDR radiance of the lit pixels it
    gives is within 0.5 % (median; 2 % at the 99th percentile) of the one from every image's
    response, here with half the images (3 of 6 per camera; measured 0.15 % and 0.75 %)."""
    raw, radiance = two_cameras(images_per_camera=6, side=24, seed=4)
    every = robertson.recover_rgb_oecf(raw, calibration_targets=False)
    again = robertson.recover_rgb_oecf(raw.chunk({"image": 1}), calibration_targets=False)
    np.testing.assert_array_equal(every["response"].values, again["response"].values)
    assert every.attrs["sampled_images"] == 12
    monkeypatch.setattr(robertson, "MAX_IMAGES", 3)
    monkeypatch.setattr(robertson.rgb_oecf_sample, "__defaults__", (3,))
    sampled = robertson.recover_rgb_oecf(raw, calibration_targets=False)
    assert sampled.attrs["sampled_images"] == 6
    # what the response is for: the HDR radiance it merges, lit pixels (bounds left out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        a = hdr.merge_hdr(raw, every)["radiance"].values
        b = hdr.merge_hdr(raw, sampled)["radiance"].values
    lit = radiance > 0.03  # 10x the darkest: resolved in some exposure of either camera
    difference = np.abs(b[lit] / a[lit] - 1)
    assert np.median(difference) < 0.005 and np.quantile(difference, 0.99) < 0.02


def test_refusals_on_the_sample_name_raw_rgb_positions(monkeypatch) -> None:
    """The check reads the sample only; its errors name the frame's position in raw/rgb."""
    raw, _ = two_cameras(images_per_camera=6, side=16, seed=5)
    counts = raw["counts"].values.copy()
    counts[10, 0] = FULL  # camera 0's last image (always in the sample): saturated
    counts[2, 0] = FULL  # camera 0's second image: not in its sample of 3 of 6 (images 0, 4, 10)
    saturated = raw.copy(data={"counts": counts})
    monkeypatch.setattr(robertson.rgb_oecf_sample, "__defaults__", (3,))
    found = robertson.rgb_oecf_refusals(saturated)
    assert len(found) == 1
    assert "frame image=10, exposure=0, channel=0" in str(found[0])
    assert "3 such frame(s)" in str(found[0])  # three channels of one frame; image 2 not read
    with pytest.raises(CalibrationError, match=r"frame image=10, exposure=0, channel=0"):
        robertson.recover_rgb_oecf(saturated, calibration_targets=False)
