"""The run's endmember library: learnt once from the pooled band shots of a run's sets, near
the true endmembers of a hard scene, and mixed by every set of the set nodes."""

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.evaluation.pixel_metrics import normalised_rmse
from spectralize.nodes.reconstruction.endmember_library import (
    endmember_library,
    library_sets,
    spectral_angles,
)
from spectralize.nodes.reconstruction.set_reconstruction import (
    library_endmembers,
    reconstruct_image_sets,
    reconstruct_seed_set,
)
from spectralize.nodes.simulation.scenes import get_scene
from spectralize.nodes.simulation.scenes.materials import sharp_led
from spectralize.schemas import ReconstructionError, validate_dataset
from spectralize.schemas.run import ENDMEMBER_LIBRARY, SPECTRA, SPECTRA_SEED

SCENE = "dark-still-life"
SIZE = 32
IMAGES = 20
ANGLES = ("theta_i", "phi_i", "theta_o", "phi_o")


def hard_run(n_sets: int) -> dict:
    """A run of ``n_sets`` sets of one hard scene: the same materials and layout in every set,
    each set's capture noise its own (seed = set); as the set nodes read it: hdr, bands, a
    calibration with C and the light, image_sets (each set owns its 20 images), and the
    truth and true endmembers (reflectance x light)."""
    rgbs, shots, truths = [], [], []
    for k in range(n_sets):
        capture = get_scene(SCENE, size=SIZE, seed=k, n_images=IMAGES)
        labels = np.arange(k * IMAGES, (k + 1) * IMAGES)
        rgbs.append(capture.rgb.assign_coords(image=labels))
        band = capture.bands
        shots.append(band.assign_coords(image=("shot", band["image"].values + k * IMAGES)))
        truths.append(capture.truth.assign_coords(image=labels))
    wavelength = capture.camera_matrix["wavelength"].values
    light = sharp_led(wavelength)
    band = xr.concat(shots, "shot")
    rgb = xr.concat(rgbs, "image").transpose("image", "y", "x", "channel")
    n_image = rgb.sizes["image"]
    hdr = xr.Dataset({"radiance": rgb}).assign_coords(
        camera=("image", np.zeros(n_image, int)),
        rotation=("image", np.zeros(n_image, int)),
        led=("image", np.arange(n_image) % IMAGES),
        **{a: ("image", rgb[a].values, {"units": "degree"}) for a in ANGLES},
    )
    bands = xr.Dataset(
        {"radiance": band.drop_vars(["wavelength", "image", "filter_size", "exposure_time"])},
        coords={c: ("shot", band[c].values) for c in ("wavelength", "image", "filter_size")},
    ).assign_coords(exposure_time=("shot", band["exposure_time"].values))
    calibration = xr.Dataset(
        {
            "camera_matrix": capture.camera_matrix,
            "illuminant": ("wavelength", light),
        }
    )
    members = np.arange(n_sets * IMAGES).reshape(n_sets, IMAGES)
    with_bands = np.isin(np.arange(n_sets * IMAGES), band["image"].values)
    image_sets = xr.Dataset(
        {
            "image_set": ("image", np.repeat(np.arange(n_sets), IMAGES)),
            "has_bands": ("image", with_bands),
            "member": (("set", "slot"), members),
            "owned": (("set", "slot"), np.ones_like(members, dtype=bool)),
        },
        coords={"image": np.arange(n_sets * IMAGES)},
        attrs={"seed_set": 0},
    )
    return {
        "hdr": hdr,
        "bands": bands,
        "calibration": calibration,
        "image_sets": image_sets,
        "truth": xr.concat(truths, "image"),
        "endmembers": capture.layout.reflectance * light[None],
        "layout": capture.layout,
    }


@pytest.fixture(scope="module")
def run():
    return hard_run(3)


def dominant_angle(library: xr.Dataset, run: dict) -> float:
    """Median spectral angle [degree] from the true endmembers of the materials that cover
    at least 1 % of the scene to their nearest learnt endmember (the highlight left out)."""
    layout = run["layout"]
    share = np.bincount(layout.label.ravel(), minlength=len(layout.reflectance)) / layout.label.size
    atoms = library["atoms"].values[~library["highlight"].values]
    return float(np.median(spectral_angles(run["endmembers"][share >= 0.01], atoms)))


def test_library_sets_are_spread_over_the_run():
    assert library_sets(10, 4).tolist() == [0, 3, 6, 9]
    assert library_sets(3, 8).tolist() == [0, 1, 2]
    assert library_sets(5, 1).tolist() == [0]
    with pytest.raises(ReconstructionError, match="image_sets"):
        library_sets(0, 8)


def test_pooled_library_follows_its_schema_and_nears_the_true_endmembers(run):
    inputs = {k: run[k] for k in ("hdr", "bands", "calibration", "image_sets")}
    one = endmember_library(**inputs, sets=1)
    pooled = endmember_library(**inputs, sets=3)
    assert validate_dataset(pooled, ENDMEMBER_LIBRARY) == []
    assert pooled.attrs["image_sets"] == [0, 1, 2] and one.attrs["image_sets"] == [0]
    assert pooled.attrs["images"] == 3 * IMAGES and pooled.attrs["stride"] == 1
    assert pooled["highlight"].values[-1] and pooled["highlight"].sum() == 1
    assert np.isfinite(pooled["split_angle"].values).all()
    # the sets' pooled band shots bring the materials' spectra nearer the truth than one set's
    assert dominant_angle(pooled, run) < 7.0
    assert dominant_angle(pooled, run) < dominant_angle(one, run)
    # the solves read it back as it was learnt
    endmembers = library_endmembers(pooled, pooled["wavelength"].values)
    np.testing.assert_array_equal(endmembers.atoms, pooled["atoms"].values)
    assert endmembers.centres.shape == (endmembers.atoms.shape[0] - 1, 2)
    with pytest.raises(ReconstructionError, match="wavelength"):
        library_endmembers(pooled, pooled["wavelength"].values + 3.0)


def test_set_nodes_mix_the_run_library_in_every_set(run, monkeypatch):
    inputs = {k: run[k] for k in ("hdr", "bands", "calibration", "image_sets")}
    library = endmember_library(**inputs, sets=3)
    seed = reconstruct_seed_set(**inputs, endmember_library=library, tile=None)
    assert seed.attrs["endmembers"] == "run" and validate_dataset(seed, SPECTRA_SEED) == []
    cube = reconstruct_image_sets(**inputs, spectra_seed=seed, endmember_library=library, tile=None)
    assert cube.attrs["endmembers"] == "run" and validate_dataset(cube, SPECTRA) == []
    cube = cube.compute()
    error = normalised_rmse(cube.radiance, run["truth"].sel(image=cube.image))
    assert float(error.median()) < 0.05
    # without the library, or told not to mix it, each set learns its own, as before
    own = reconstruct_seed_set(**inputs, tile=None)
    unused = reconstruct_seed_set(**inputs, endmember_library=library, run_library=False, tile=None)
    assert own.attrs["endmembers"] == "set" == unused.attrs["endmembers"]
    np.testing.assert_array_equal(own["radiance"].values, unused["radiance"].values)
    assert not np.array_equal(own["radiance"].values, seed["radiance"].values)
    # batched sets (a run of many sets of tiny frames) and tiles take the same library
    import spectralize.nodes.reconstruction.set_reconstruction as set_reconstruction

    monkeypatch.setattr(set_reconstruction, "BATCH_SETS_ABOVE", 1)
    batched = reconstruct_image_sets(
        **inputs, spectra_seed=seed, endmember_library=library, tile=None
    ).compute()
    np.testing.assert_array_equal(batched["radiance"].values, cube["radiance"].values)
    tiled = reconstruct_seed_set(**inputs, endmember_library=library, tile=16)
    assert tiled.attrs["tiles"] > 1 and tiled.attrs["endmembers"] == "run"
    assert np.isfinite(tiled["radiance"].values).all()
