import numpy as np
import pytest
import xarray as xr
from scipy import ndimage

from spectralize.nodes.calibration.registration import (
    ALIAS_DISTANCE_WARNING,
    PAIR_SPREAD_WARNING,
    PEAK_DISTANCE_WARNING,
    estimate_registration,
    estimate_shift,
    pair_rotations,
    register_frames,
    registration_warnings,
)
from spectralize.nodes.calibration.result_checks import result_warnings
from spectralize.schemas import SchemaError, validate_dataset
from spectralize.schemas.run import RAW_REGISTRATION


def texture(seed=0, shape=(64, 64)):
    """Patches of materials with sharp (slightly blurred) edges plus smooth shading."""
    rng = np.random.default_rng(seed)
    patches = rng.random((8, 8))[
        np.ix_(np.arange(shape[0]) * 8 // shape[0], np.arange(shape[1]) * 8 // shape[1])
    ]
    shading = ndimage.gaussian_filter(rng.random(shape), 6.0)
    return ndimage.gaussian_filter(patches, 0.7) * 800 + shading * 400 + 100


def shifted(image, shift):
    """image(p - shift), exactly, through the Fourier shift theorem."""
    return np.real(np.fft.ifftn(ndimage.fourier_shift(np.fft.fftn(image), shift)))


@pytest.mark.parametrize("shift", [(0.35, -0.6), (2.0, 1.25), (-3.4, 0.0)])
def test_sub_pixel_shift_is_recovered(shift):
    reference = texture()
    moving = shifted(reference, shift) * 0.3 + np.random.default_rng(1).normal(0, 0.5, reference.shape)
    found, _ = estimate_shift(reference, moving, upsample_factor=100)
    np.testing.assert_allclose(found, shift, atol=0.1)


def test_rotation_pairs_follow_the_15_degree_offset():
    assert pair_rotations(np.array([0.0, 15.0, 30.0])) == [(0, 1), (1, 2)]
    full = np.arange(24) * 15.0
    pairs = pair_rotations(full)
    assert len(pairs) == 24 and (23, 0) in pairs
    assert pair_rotations(np.array([0.0, 45.0])) == []


def registration_group(shift, rotations=4):
    rgb, spectral = [], []
    for r in range(rotations):
        base = texture(seed=r)
        rgb.append(np.stack([base * w for w in (0.5, 1.0, 0.7)], axis=-1))
    for r in range(rotations):
        # the spectral camera at rotation r sees what RGB saw at r - 1
        spectral.append(shifted(texture(seed=(r - 1) % rotations), shift) * 0.2 + 30)
    return xr.Dataset(
        {
            "rgb_counts": (("rotation", "y", "x", "channel"), np.asarray(rgb).astype(np.uint16)),
            "spectral_counts": (("rotation", "y", "x"), np.asarray(spectral).astype(np.uint16)),
        },
        coords={
            "rotation": np.arange(rotations),
            "rotation_angle": ("rotation", np.arange(rotations) * 15.0),
        },
    )


def test_run_registration_uses_the_one_rotation_offset():
    out = estimate_registration(registration_group((0.35, -0.6)))
    np.testing.assert_allclose(out["shift"].values, [0.35, -0.6], atol=0.1)
    assert out["spectral_rotation"].values.tolist() == [1, 2, 3]
    assert out["rgb_rotation"].values.tolist() == [0, 1, 2]
    assert float(out["residual"].max()) < 0.15
    assert out["shift"].attrs["units"] == "px"


def test_registration_errors_name_the_problem():
    group = registration_group((0.0, 0.0))
    # a missing variable is the schema's to report (the engine validates inputs before the
    # node runs); the node reports what a schema cannot say
    problems = validate_dataset(group.drop_vars("spectral_counts"), RAW_REGISTRATION)
    assert any(p.where == "raw/registration:spectral_counts" for p in problems)
    with pytest.raises(SchemaError, match="two rotations 15 degree apart"):
        estimate_registration(group.assign_coords(rotation_angle=("rotation", [0.0, 40, 80, 120])))


def test_register_frames_undoes_the_shift_lazily():
    shift = (0.35, -0.6)
    truth = ndimage.gaussian_filter(texture(seed=3, shape=(48, 48)), 1.5)
    frames = xr.DataArray(np.stack([shifted(truth, shift)] * 3), dims=("shot", "y", "x")).chunk(
        {"shot": 1}
    )
    out = register_frames(
        frames, xr.DataArray(list(shift), dims="axis", coords={"axis": ["y", "x"]}), order=3
    )
    assert out.chunks is not None
    inner = (slice(None), slice(4, -4), slice(4, -4))
    expected = np.stack([truth] * 3)[inner]
    after = np.abs(out.values[inner] - expected).mean()
    before = np.abs(frames.values[inner] - expected).mean()
    assert after < before / 10
    assert np.median(np.abs(out.values[inner] - expected) / expected) < 5e-3


def striped_scene(shift, shape=(48, 60), factor=4):
    """(y, x) material index of a periodic target, pixel-integrated: stripes of three
    materials 3 px wide over the top half, 4 px checks of two more below, content shifted by
    ``shift`` (dy, dx) [px]; returns (y, x, factor, factor) sub-pixel samples."""
    offsets = (np.arange(factor) + 0.5) / factor - 0.5
    yy = np.arange(shape[0])[:, None, None, None] + offsets[None, None, :, None] - shift[0]
    xx = np.arange(shape[1])[None, :, None, None] + offsets[None, None, None, :] - shift[1]
    yy, xx = np.broadcast_arrays(yy, xx)
    stripes = np.floor(xx / 3.0).astype(int) % 3
    checks = 3 + (np.floor(yy / 4.0) + np.floor(xx / 4.0)).astype(int) % 2
    return np.where(yy < shape[0] / 2, stripes, checks)


# RGB of the five materials, and two bands: one a mix of the RGB channels whose stripe
# contrast differs from the channels' sum, one no mix of the channels gives
STRIPED_RGB = np.array([[0.9, 0.6, 0.3], [0.25, 0.7, 0.9], [0.05, 0.1, 0.1], [0.7, 0.6, 0.2], [0.3] * 3])
BAND_OF_A_MIX = np.array([1.0, 0.05, 0.5, 0.8, 0.3])
BAND_OF_NO_MIX = np.array([1.0, 0.2, 0.05, 0.3, 0.8])


def striped_group(band_of, shift):
    rng = np.random.default_rng(0)
    rgb = STRIPED_RGB[striped_scene((0.0, 0.0))].mean(axis=(2, 3)) * 1000
    band = band_of[striped_scene(shift)].mean(axis=(2, 3)) * 500 + 40
    rgb = rgb + rng.normal(0, 2, rgb.shape)
    band = band + rng.normal(0, 2, band.shape)
    return xr.Dataset(
        {
            "rgb_counts": (("rotation", "y", "x", "channel"), np.stack([rgb, rgb]).astype(np.uint16)),
            "spectral_counts": (("rotation", "y", "x"), np.stack([band, band]).astype(np.uint16)),
        },
        coords={"rotation": [0, 1], "rotation_angle": ("rotation", [0.0, 15.0])},
    )


def test_a_periodic_target_is_registered_against_the_band_like_channel_mix():
    # the channels' sum has another stripe contrast than the band: its correlation peak lies
    # a stripe away; the mix of the channels that explains the band does not
    out = estimate_registration(striped_group(BAND_OF_A_MIX, (0.4, -0.7)))
    np.testing.assert_allclose(out["shift"].values, [0.4, -0.7], atol=0.25)
    assert float(out["unexplained"][0]) < 0.25
    assert registration_warnings(out) == []
    assert result_warnings("estimate_registration", {}, {"registration": out}) == []


def test_a_band_no_channel_mix_gives_on_a_periodic_target_warns():
    out = estimate_registration(striped_group(BAND_OF_NO_MIX, (0.4, -0.7)))
    assert float(out["alias_distance"][0]) > ALIAS_DISTANCE_WARNING
    messages = result_warnings("estimate_registration", {}, {"registration": out})
    assert messages == registration_warnings(out)
    assert len(messages) == 1 and "periodic target" in messages[0] and "0->1" in messages[0]


def test_registration_warns_when_pairs_disagree_or_find_another_peak():
    out = estimate_registration(registration_group((0.35, -0.6)))
    assert registration_warnings(out) == []
    far = out.assign(
        residual=out["residual"].copy(data=[0.1, PAIR_SPREAD_WARNING + 0.5, 0.1]),
        peak_distance=out["peak_distance"].copy(data=[0.2, 0.3, PEAK_DISTANCE_WARNING + 1.0]),
    )
    messages = registration_warnings(far)
    assert len(messages) == 2
    assert "2->3" in messages[0] and "another peak" not in messages[1]
    assert "1->2" in messages[1] and "disagree" in messages[1]
