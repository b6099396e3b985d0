"""Tests of the assembled gantry run: groups, layout, pairing, determinism, laziness."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from spectralize.nodes.simulation.assembly import GROUPS, Gantry, simulate_run
from spectralize.nodes.simulation.camera_model import SimulationParameterError, response_model
from spectralize.nodes.simulation.recipes import GantryRecipe, get_recipe
from spectralize.schemas import GROUP_SCHEMAS, validate_dataset
from spectralize.store import RunStore

# fixed-width string coords (channel, sensor, patch_name) make zarr 3 warn that their dtype
# has no v3 spec yet; the contract asks for kind U strings (see datasets/README.md)
pytestmark = pytest.mark.filterwarnings("ignore::zarr.errors.UnstableSpecificationWarning")


@pytest.fixture(scope="module")
def tiny():
    gantry = Gantry(get_recipe("tiny"))
    return gantry, {k: ds.load() for k, ds in gantry.groups().items()}


@pytest.mark.slow
def test_groups_follow_the_contract(tiny, tmp_path):
    _, groups = tiny
    assert set(groups) == set(GROUPS)
    assert set(GROUPS) <= set(GROUP_SCHEMAS)  # every group is part of the contract (schemas.run)
    for name, ds in groups.items():
        assert validate_dataset(ds, GROUP_SCHEMAS[name]) == []
        for var in ds.variables.values():
            if var.dims and var.dtype.kind in "fiu":
                assert "units" in var.attrs and "long_name" in var.attrs, (name, var)
    store = RunStore.create(tmp_path / "run.zarr")
    for name, ds in simulate_run(get_recipe("tiny")).items():
        store.write(name, ds, schema=GROUP_SCHEMAS[name])
    assert store.validate() == []
    for name in GROUPS:  # read back from zarr
        assert validate_dataset(store.read(name), GROUP_SCHEMAS[name]) == []
    back = store.read("raw/rgb")
    np.testing.assert_array_equal(back.counts.values, groups["raw/rgb"].counts.values)


def test_layout_and_dtypes(tiny):
    gantry, g = tiny
    r = gantry.recipe
    rgb = g["raw/rgb"]
    n_img = len(r.rgb_camera_thetas) * len(r.leds) * r.n_rotations
    assert rgb.counts.shape == (n_img, 4, 32, 32, 3) and rgb.counts.dtype == np.uint16
    assert rgb.attrs["bit_depth"] == 10 and int(rgb.counts.max()) <= 1023
    assert rgb.exposure_time.dims == ("image", "exposure")
    assert set(np.unique(rgb.theta_o)) == {15.0, 45.0}
    # longer exposures give more counts
    means = rgb.counts.astype(float).mean(("image", "y", "x", "channel")).values
    assert np.all(np.diff(means) > 0)
    sp = g["raw/spectral"]
    assert sp.counts.dims == ("shot", "y", "x") and sp.counts.dtype == np.uint16
    truth = g["truth/spectra"]
    assert truth.radiance.shape == (n_img, 32, 32, 32) and truth.radiance.dtype == np.float32
    assert np.all(truth.radiance >= 0)
    cam = g["truth/camera"]
    assert cam.camera_matrix.dims == ("channel", "wavelength")
    assert cam.oecf.dims == ("sensor", "code") and cam.sizes["code"] == 1024
    assert cam.misregistration.values.tolist() == list(r.misregistration)


def test_sparse_mode_spreads_32_bands_over_the_led_set(tiny):
    gantry, g = tiny
    sp = g["raw/spectral"]
    for _, shots in sp.groupby(["rotation", "led_set"]):
        assert sorted(shots.wavelength.values) == sorted(gantry.renderer.wavelength)  # each band once
        assert len(np.unique(shots.led)) == gantry.recipe.spectral_set_size
    # exposure times follow the plan (eq. 2), quantised to the shutter step
    plan = g["raw/exposure_plan"]
    t = plan.exposure_time_quantised.sel(wavelength=sp.wavelength).values
    np.testing.assert_allclose(sp.exposure_time.values, t)
    np.testing.assert_allclose(
        sp.filter_size.values, plan.filter_size.sel(wavelength=sp.wavelength).values
    )
    # the plan's cost is what the shots took (up to the 0.1 ms shutter step)
    assert float(plan.spectral_capture_time) == pytest.approx(
        float(sp.exposure_time.sum()), abs=sp.sizes["shot"] * 0.5e-4
    )
    assert float(plan.rgb_capture_time) == pytest.approx(float(g["raw/rgb"].exposure_time.sum()))
    # every exposure time the spectral camera uses has a dark stack
    dark_times = set(g["raw/dark"].exposure_time.values.tolist())
    used = set(sp.exposure_time.values.tolist())
    used |= set(g["raw/white_reference"].spectral_exposure_time.values.tolist())
    used.add(float(g["raw/registration"].spectral_exposure_time))
    assert used <= dark_times


def test_spectral_shot_at_rotation_r_plus_1_sees_rgb_image_of_rotation_r(tiny):
    """Same sample-frame angles, and the same radiance up to the known shift."""
    gantry, g = tiny
    sp, rgb = g["raw/spectral"], g["raw/rgb"]
    img = rgb.isel(image=sp.image.values)
    assert np.all(img.rotation.values == sp.rotation.values - 1)
    assert np.all(img.theta_o.values == 45.0)
    for angle in ("theta_i", "phi_i", "theta_o", "phi_o"):
        np.testing.assert_allclose(sp[angle].values, img[angle].values, atol=1e-9)
    # the LED of the shot is one rotation step further round the ring
    th, ph = gantry.schedule.led_theta, gantry.schedule.led_phi
    np.testing.assert_allclose(th[sp.led.values], th[img.led.values])
    np.testing.assert_allclose((ph[sp.led.values] - ph[img.led.values]) % 360, 15.0)

    # noise-free spectral camera and an integer shift: counts are eq. 5 of the shifted truth
    dy, dx = 2, -1
    recipe = get_recipe("tiny", misregistration=(float(dy), float(dx)), spectral_noise_sigma=0.0)
    run = simulate_run(recipe)
    shots = run["raw/spectral"].isel(shot=slice(0, 6)).load()
    cam = run["truth/camera"].load()
    truth = run["truth/spectra"].radiance.isel(image=shots.image.values).load()
    spec = json.loads(cam.attrs["responses"])["mono"]
    response = response_model(spec.pop("model"), **spec)
    q = cam.quantum_efficiency.sel(wavelength=shots.wavelength).values
    for k in range(shots.sizes["shot"]):
        j = int(np.flatnonzero(cam.wavelength.values == float(shots.wavelength[k]))[0])
        band = np.tensordot(cam.bandpass.values[j], truth.values[k], axes=1)  # (y, x)
        t = float(shots.exposure_time[k])
        signal = response.oecf(band * t * q[k]) * 1023  # in the RGB image's frame
        dark = cam.spectral_adc_offset.values + cam.spectral_dark_current.values * t
        measured = shots.counts.values[k].astype(float)
        # spectral(p) = rgb(p - shift): compare where both are inside the image
        got = measured[dy:, : 32 + dx]
        want = np.floor(signal[: 32 - dy, -dx:] + dark[dy:, : 32 + dx])
        assert np.abs(got - want).max() <= 1.0  # float32 offsets may flip a floor


def test_registration_shots_reveal_the_misregistration():
    dy, dx = 3, -2
    run = simulate_run(get_recipe("tiny", misregistration=(float(dy), float(dx))))
    reg = run["raw/registration"].load()
    a = reg.rgb_counts.isel(rotation=0, channel=1).values.astype(float)
    b = reg.spectral_counts.isel(rotation=1).values.astype(float)
    fa, fb = np.fft.fft2(a - a.mean()), np.fft.fft2(b - b.mean())
    corr = np.fft.ifft2(fb * np.conj(fa) / (np.abs(fb * np.conj(fa)) + 1e-9)).real
    peak = np.unravel_index(np.argmax(corr), corr.shape)
    found = [(p + 16) % 32 - 16 for p in peak]
    assert found == [dy, dx]


def test_deterministic_and_independent_of_chunking():
    base = {"noise_tile": 16}
    a = simulate_run(get_recipe("tiny", chunk_size=16, frames_per_chunk=3, **base))
    b = simulate_run(get_recipe("tiny", chunk_size=32, frames_per_chunk=7, **base))
    for group, var in (
        ("raw/rgb", "counts"),
        ("raw/spectral", "counts"),
        ("raw/dark", "frames"),
        ("raw/white_reference", "spectral_counts"),
        ("truth/camera", "spectral_adc_offset"),
        ("truth/spectra", "radiance"),
    ):
        assert a[group][var].data.chunks != b[group][var].data.chunks
        np.testing.assert_array_equal(a[group][var].values, b[group][var].values)
    c = simulate_run(get_recipe("tiny", seed=1, **base))
    assert np.any(c["raw/spectral"].counts.values != a["raw/spectral"].counts.values)


def test_paper_scale_is_lazy():
    run = simulate_run(get_recipe("paper"))
    rgb = run["raw/rgb"]
    assert rgb.counts.shape == (52272, 4, 2048, 2048, 3)
    total = sum(ds.nbytes for ds in run.values())
    assert total > 1e13  # tens of TB if computed
    assert rgb.counts.data.chunksize == (1, 4, 512, 512, 3)
    chunk = rgb.counts.isel(image=777, x=slice(512, 1024), y=slice(0, 512)).values
    assert chunk.shape == (4, 512, 512, 3) and chunk.dtype == np.uint16
    assert run["raw/spectral"].sizes["shot"] == 24 * 20 * 32  # 20 sets of <= 10 LEDs


def test_recipe_validation():
    with pytest.raises(ValidationError, match="extra"):
        GantryRecipe(sizes=3)
    with pytest.raises(ValidationError, match="noise_tile"):
        GantryRecipe(size=1024, chunk_size=300)
    with pytest.raises(ValidationError, match="spectral camera"):
        GantryRecipe(rgb_camera_thetas=(0.0, 30.0))
    with pytest.raises(ValidationError, match="rotation_step"):
        GantryRecipe(spectral_camera_phi=30.0)
    with pytest.raises(ValidationError, match="leds"):
        GantryRecipe(leds=(0, 0))
    with pytest.raises(ValidationError):
        GantryRecipe(rgb_bit_depth=17)
    with pytest.raises(SimulationParameterError, match="nothing to shoot"):
        Gantry(get_recipe("tiny", n_rotations=1))
    with pytest.raises(SimulationParameterError, match="GantryRecipe"):
        simulate_run({"size": 32})
    r = GantryRecipe(name="x")
    with pytest.raises(ValidationError):
        r.size = 3  # frozen
