"""Tests of the camera model (paper eq. 5), the response models and the two cameras."""

from __future__ import annotations

import colour
import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

from spectralize.nodes.simulation.camera_model import (
    RESPONSE_MODELS,
    GammaResponse,
    LinearResponse,
    LogResponse,
    RGBCamera,
    SCurveResponse,
    ShapeMismatchError,
    SimulationParameterError,
    SpectralCamera,
    camera_sensitivities,
    capture,
    check_wavelength,
    gaussian_bandpass,
    noiseless_signal,
    oecf_table,
    response_model,
    spectral_quantum_efficiency,
)
from spectralize.nodes.simulation.ground_truth import (
    WAVELENGTHS,
    colourchecker_reflectances,
    illuminant_spd,
)
from spectralize.schemas import SpectralizeError

MODELS = [LinearResponse(), GammaResponse(2.2), LogResponse(10.0), SCurveResponse(4.0, 0.35)]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_response_models_are_monotone_inverse_pairs(model):
    e = np.linspace(0, 1, 1001)
    v = model.oecf(e)
    assert v[0] == pytest.approx(0, abs=1e-12) and v[-1] == pytest.approx(1)
    assert np.all(np.diff(v) > 0)
    np.testing.assert_allclose(model.response(v), e, atol=1e-9)
    assert model.oecf(2.0) == pytest.approx(1.0)  # saturation
    table = oecf_table(model, bit_depth=8)
    assert table.shape == (256,) and np.all(np.diff(table) > 0)
    assert table[-1] == pytest.approx(1.0)


def test_response_model_dispatch():
    assert set(RESPONSE_MODELS) == {"linear", "gamma", "log", "s_curve"}
    assert response_model("gamma", gamma=1.8).gamma == 1.8
    with pytest.raises(SimulationParameterError, match="known models"):
        response_model("cubic")
    with pytest.raises(SimulationParameterError, match="does not take"):
        response_model("linear", gamma=2.0)
    with pytest.raises(SimulationParameterError, match="midpoint"):
        SCurveResponse(midpoint=1.5)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_mean_of_many_frames_converges_to_the_noiseless_value(model):
    x = np.linspace(0.02, 0.6, 12)  # away from the clamps (noiseless codes 20..~990)
    frames = capture(
        np.broadcast_to(x, (20000, x.size)),
        1.0,
        response=model,
        adc_offset=20.0,
        noise_sigma=3.0,
        bit_depth=10,
        seed=7,
    )
    expected = noiseless_signal(x, 1.0, response=model, adc_offset=20.0, bit_depth=10)
    # the floor of eq. 5 lowers the mean by 1/2 DN; the standard error is 3 / sqrt(20000)
    np.testing.assert_allclose(frames.mean(axis=0) + 0.5, expected, atol=5 * 3 / np.sqrt(2e4))


@pytest.mark.parametrize("bit_depth", [8, 10, 12, 16])
def test_clamping_at_the_bit_depth(bit_depth):
    high = capture(np.full(1000, 5.0), 1.0, adc_offset=10, noise_sigma=2.0, bit_depth=bit_depth, seed=1)
    assert high.dtype == np.uint16
    assert np.all(high == 2**bit_depth - 1)
    low = capture(np.zeros(1000), 1.0, adc_offset=0.0, noise_sigma=5.0, bit_depth=bit_depth, seed=1)
    assert low.min() == 0 and low.max() < 30  # clamped at 0, never wrapped around


@settings(max_examples=25, deadline=None)
@given(
    t1=st.floats(1e-3, 1.0),
    factor=st.floats(1.0, 50.0),
    seed=st.integers(0, 2**31),
    model=st.sampled_from(MODELS),
)
def test_counts_are_monotone_in_exposure_time(t1, factor, seed, model):
    x = np.linspace(0.0, 1.0, 200)
    a = capture(x, t1, response=model, adc_offset=8, noise_sigma=2.0, seed=seed)
    b = capture(x, t1 * factor, response=model, adc_offset=8, noise_sigma=2.0, seed=seed)
    assert np.all(b >= a)


@settings(max_examples=15, deadline=None)
@given(sigma=st.floats(1.0, 8.0), seed=st.integers(0, 2**31))
def test_gaussian_noise_variance_as_specified(sigma, seed):
    n = 40000
    frames = capture(np.full(n, 0.3), 1.0, adc_offset=64, noise_sigma=sigma, seed=seed)
    # Gaussian N_sigma plus the floor's uniform quantisation error (variance 1/12)
    expected = sigma**2 + 1 / 12
    assert frames.astype(float).var() == pytest.approx(expected, rel=6 * np.sqrt(2 / n))


@settings(max_examples=10, deadline=None)
@given(e=st.floats(0.05, 0.8), full_well=st.floats(500.0, 20000.0), seed=st.integers(0, 999))
def test_shot_noise_variance_as_specified(e, full_well, seed):
    n = 40000
    frames = capture(
        np.full(n, e), 1.0, adc_offset=32, noise_sigma=2.0, noise="shot", full_well=full_well, seed=seed
    )
    scale = 2**10 - 1
    expected = scale**2 * e / full_well + 2.0**2 + 1 / 12
    assert frames.mean() + 0.5 == pytest.approx(scale * e + 32, abs=0.02 * scale * e + 0.3)
    assert frames.astype(float).var() == pytest.approx(expected, rel=6 * np.sqrt(2 / n))


def test_seeded_and_deterministic():
    x = np.random.default_rng(0).random((16, 16))
    a = capture(x, 0.5, noise_sigma=3.0, seed=11)
    b = capture(x, 0.5, noise_sigma=3.0, seed=11)
    c = capture(x, 0.5, noise_sigma=3.0, seed=12)
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)
    g = np.random.default_rng(5)
    d = capture(x, 0.5, noise_sigma=3.0, seed=g)
    np.testing.assert_array_equal(d, capture(x, 0.5, noise_sigma=3.0, seed=np.random.default_rng(5)))


def test_capture_keeps_xarray_dims_and_coords():
    x = xr.DataArray(np.full((2, 3, 4), 0.2), dims=("shot", "y", "x"), coords={"shot": [10, 11]})
    out = capture(x, 0.5, quantum_efficiency=2.0, adc_offset=4, bit_depth=12)
    assert isinstance(out, xr.DataArray) and out.dims == ("shot", "y", "x")
    assert out.attrs["units"] == "DN" and out.attrs["bit_depth"] == 12
    assert list(out.shot.values) == [10, 11]
    assert int(out[0, 0, 0]) == int(np.floor(0.2 * 0.5 * 2.0 * 4095 + 4))


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"exposure_time": 0.0}, "exposure_time"),
        ({"exposure_time": -1.0}, "exposure_time"),
        ({"quantum_efficiency": 0.0}, "quantum_efficiency"),
        ({"quantum_efficiency": [1.0, -0.5]}, "quantum_efficiency"),
        ({"bit_depth": 7}, "bit_depth"),
        ({"bit_depth": 17}, "bit_depth"),
        ({"bit_depth": 10.0}, "bit_depth"),
        ({"bit_depth": True}, "bit_depth"),
        ({"noise_sigma": -1.0}, "noise_sigma"),
        ({"adc_offset": -2.0}, "adc_offset"),
        ({"irradiance": [0.1, np.nan]}, "irradiance"),
        ({"irradiance": [0.1, -0.2]}, "irradiance"),
        ({"noise": "poisson"}, "noise"),
        ({"seed": -3}, "seed"),
    ],
)
def test_bad_input_names_the_parameter(kwargs, name):
    args = {"irradiance": [0.1, 0.2], "exposure_time": 1.0} | kwargs
    irradiance = args.pop("irradiance")
    with pytest.raises(SimulationParameterError, match=name) as info:
        capture(irradiance, **args)
    assert isinstance(info.value, ValueError) and isinstance(info.value, SpectralizeError)


def test_shapes_that_do_not_broadcast():
    with pytest.raises(ShapeMismatchError, match="broadcast"):
        capture(np.zeros((4, 5)), np.ones(3))
    with pytest.raises(ShapeMismatchError, match="DataArray"):
        capture(xr.DataArray(np.zeros(3), dims="x"), np.ones((2, 3)))


def test_wavelengths_must_increase():
    with pytest.raises(SimulationParameterError, match="strictly increasing"):
        check_wavelength([500, 490, 510])
    with pytest.raises(SimulationParameterError, match="strictly increasing"):
        camera_sensitivities([500, 500, 510])
    with pytest.raises(ShapeMismatchError, match="1-D"):
        check_wavelength(np.ones((2, 2)))
    with pytest.raises(SimulationParameterError, match="380"):
        camera_sensitivities([300, 400])


def _rgb_camera(**kwargs) -> RGBCamera:
    c = camera_sensitivities(WAVELENGTHS)
    return RGBCamera(camera_matrix=c, responses={ch: LinearResponse() for ch in "RGB"}, **kwargs)


def test_colour_checker_rgb_through_C_agrees_with_colour_science():
    """C S of the 24 ColorChecker patches under LED-B3 vs colour.sd_to_XYZ with the camera."""
    cam = _rgb_camera()
    refl = colourchecker_reflectances(WAVELENGTHS)
    ell = illuminant_spd(WAVELENGTHS, name="LED-B3")
    radiance = (refl * ell).rename(patch="y").expand_dims(x=1).transpose("wavelength", "y", "x")
    ours = cam.channel_irradiance(radiance).isel(x=0).values  # (patch, channel)

    shape = colour.SpectralShape(410, 720, 10)
    cmfs = colour.MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"].copy().align(shape)
    ill = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(shape)
    chart = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    theirs = np.array(
        [
            colour.sd_to_XYZ(
                chart[name].copy().align(shape), cmfs=cmfs, illuminant=ill, k=1, method="Integration"
            )
            for name in refl.patch_name.values
        ]
    )
    # colour-science normalises (k, range scale, peak of our C and L): one common constant
    ratio = theirs / ours
    np.testing.assert_allclose(ratio, ratio.flat[0], rtol=1e-9)


def test_rgb_camera_exposure_series():
    cam = _rgb_camera(adc_offset=16, noise_sigma=0.0)
    radiance = xr.DataArray(
        np.full((WAVELENGTHS.size, 4, 5), 0.01),
        dims=("wavelength", "y", "x"),
        coords={"wavelength": WAVELENGTHS},
    )
    counts = cam.capture(radiance, [0.1, 0.4, 1.6], seed=0)
    assert counts.dims == ("exposure", "y", "x", "channel")
    assert counts.sizes == {"exposure": 3, "y": 4, "x": 5, "channel": 3}
    assert list(counts.exposure_time.values) == [0.1, 0.4, 1.6]
    g = counts.sel(channel="G").mean(("y", "x")).values
    assert np.all(np.diff(g) > 0)
    with pytest.raises(ShapeMismatchError, match="wavelength"):
        cam.channel_irradiance(radiance.isel(wavelength=slice(0, 10)))
    with pytest.raises(SimulationParameterError, match="responses"):
        RGBCamera(camera_matrix=camera_sensitivities(WAVELENGTHS), responses={"R": LinearResponse()})
    with pytest.raises(SimulationParameterError, match="bit_depth"):
        _rgb_camera(bit_depth=20)


def test_spectral_camera_bandpass_and_band_shot():
    bp = gaussian_bandpass(WAVELENGTHS, fwhm=10.0)
    np.testing.assert_allclose(bp.sum("wavelength"), 1.0)
    assert bp.values[5, 5] > 0.8 and bp.values[5, 6] < 0.1
    np.testing.assert_array_equal(
        gaussian_bandpass(WAVELENGTHS, fwhm=0).values, np.eye(WAVELENGTHS.size)
    )
    q = spectral_quantum_efficiency(WAVELENGTHS)
    assert q.values.max() == pytest.approx(1.0)
    assert q.values[0] < 0.3 * q.values.max()  # weak blue, as in the paper's Figure 3
    cam = SpectralCamera(quantum_efficiency=q, bandpass_fwhm=0.0, adc_offset=10, noise_sigma=0.0)
    spectrum = np.linspace(0.1, 0.5, WAVELENGTHS.size)
    radiance = xr.DataArray(
        np.broadcast_to(spectrum[:, None, None], (32, 3, 3)),
        dims=("wavelength", "y", "x"),
        coords={"wavelength": WAVELENGTHS},
    )
    shot = cam.capture(radiance, wavelength=550.0, exposure_time=0.5, seed=0)
    j = int(np.flatnonzero(WAVELENGTHS == 550)[0])
    assert int(shot[0, 0]) == int(np.floor(spectrum[j] * 0.5 * q.values[j] * 1023 + 10))
    assert float(shot.wavelength) == 550.0 and float(shot.exposure_time) == 0.5
    with pytest.raises(SimulationParameterError, match="not a band"):
        cam.capture(radiance, wavelength=555.0, exposure_time=0.5)
    with pytest.raises(SimulationParameterError, match="quantum_efficiency"):
        SpectralCamera(quantum_efficiency=q * 0)
