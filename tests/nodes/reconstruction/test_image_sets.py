import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction.image_sets import select_image_sets, set_members
from spectralize.schemas import SchemaError


def gantry_images(rotations=2, leds_per_ring=24, thetas=(15.0, 45.0, 75.0)):
    """Images of 3 cameras x 24 LEDs x rotations; the 45 degree camera's LEDs 0..19 have bands."""
    rows = []
    for rotation in range(rotations):
        for camera, theta_o in enumerate(thetas):
            for led in range(leds_per_ring):
                rows.append((camera, rotation, led, 50.0, (led * 15.0 + rotation * 15.0) % 360, theta_o))
    rows = np.array(rows)
    images = xr.Dataset(
        coords={
            "image": ("image", np.arange(len(rows))),
            "camera": ("image", rows[:, 0].astype(int)),
            "rotation": ("image", rows[:, 1].astype(int)),
            "led": ("image", rows[:, 2].astype(int)),
            "theta_i": ("image", rows[:, 3]),
            "phi_i": ("image", rows[:, 4]),
            "theta_o": ("image", rows[:, 5]),
        }
    )
    anchors = np.flatnonzero((images.camera.values == 1) & (images.led.values < 20))
    # each sweep of the filter spreads the 32 bands round-robin over 10 anchor images
    shot_image = [anchors[g * 10 + b % 10] for g in range(len(anchors) // 10) for b in range(32)]
    wavelength = np.tile(np.arange(410.0, 730.0, 10.0), len(anchors) // 10)
    shots = xr.Dataset(coords={"image": ("shot", shot_image), "wavelength": ("shot", wavelength)})
    return images, shots, anchors


def test_every_image_is_owned_by_exactly_one_set():
    images, shots, anchors = gantry_images()
    sets = select_image_sets(images, shots)
    owners = sets["image_set"].values
    assert (owners >= 0).all()
    owned_members = sets["member"].values[sets["owned"].values]
    assert sorted(owned_members.tolist()) == images["image"].values.tolist()
    assert sets["has_bands"].values.sum() == len(np.unique(shots.image))


def test_sets_are_ten_anchors_plus_ten_similar_others():
    images, shots, anchors = gantry_images()
    sets = select_image_sets(images, shots)
    for s in range(sets.sizes["set"]):
        member, owned = set_members(sets, s)
        has_bands = sets["has_bands"].sel(image=member).values
        assert has_bands.sum() == 10 and has_bands[:10].all()  # anchors first
        assert (~has_bands).sum() <= 10
    # others are assigned to the anchor group with the nearest light direction
    distance = sets["light_distance"].where(~sets["has_bands"]).values
    assert np.nanmax(distance) < 90


def test_set_sizes_are_configurable_and_seed_is_a_set():
    images, shots, _ = gantry_images()
    sets = select_image_sets(images, shots, anchors_per_set=5, others_per_set=3)
    widths = (sets["member"].values >= 0).sum(axis=1)
    assert widths.max() == 8
    assert 0 <= sets.attrs["seed_set"] < sets.sizes["set"]


def test_no_band_shots_is_an_error():
    images, _, _ = gantry_images(rotations=1)
    shots = xr.Dataset(coords={"image": ("shot", [9999])})
    with pytest.raises(SchemaError, match="no shot pairs with an image"):
        select_image_sets(images, shots)
    with pytest.raises(SchemaError, match="images:theta_i"):
        select_image_sets(images.drop_vars("theta_i"), shots)


def test_default_sets_follow_the_sweeps_of_all_bands():
    images, shots, _ = gantry_images()
    sets = select_image_sets(images, shots)
    for s in range(sets.sizes["set"]):
        member, _ = set_members(sets, s)
        waves = shots.wavelength.values[np.isin(shots.image.values, member)]
        assert len(np.unique(waves)) == 32  # every set has every band
