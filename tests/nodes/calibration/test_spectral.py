"""Tests of the spectral calibration's steps: QE, camera matrix C, cross-validation.

(``band_shots``, ``white_reference``, ``camera_smooth``, ``chart_patches`` and
``cross_validation`` in ``spectralize.nodes.calibration``; the node ``calibrate_spectral`` is
tested in ``test_calibration.py``.)
"""

from __future__ import annotations

import io

import colour
import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration import hdr
from spectralize.nodes.calibration.band_shots import band_signal
from spectralize.nodes.calibration.camera_smooth import (
    SMOOTHNESS_CANDIDATES,
    camera_matrix,
    cross_validated_smoothness,
)
from spectralize.nodes.calibration.chart_patches import patch_means
from spectralize.nodes.calibration.cross_validation import cross_validate, predict_rgb
from spectralize.nodes.calibration.white_reference import quantum_efficiency
from spectralize.nodes.evaluation.figures_calibration import plot_cross_validation
from spectralize.nodes.simulation.camera_model import (
    camera_sensitivities,
    capture,
    response_model,
    spectral_quantum_efficiency,
)
from spectralize.schemas import CalibrationError, SchemaError

WAVELENGTHS = np.arange(410.0, 721.0, 10.0)  # 32 bands, as in the paper
SHAPE = colour.SpectralShape(410, 720, 10)
OFFSET, SIGMA, BITS, FULL = 16.0, 3.0, 10, 1023
RGB_TIMES = np.array([1.0, 3.0, 8.0, 25.0, 60.0]) / 60.0


def illuminant() -> xr.DataArray:
    values = colour.SDS_ILLUMINANTS["D65"].copy().align(SHAPE).values
    return xr.DataArray(values / values.max(), dims="wavelength", coords={"wavelength": WAVELENGTHS})


def checker_reflectance() -> xr.DataArray:
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    values = np.stack([sd.copy().align(SHAPE).values for sd in sds.values()])
    return xr.DataArray(
        values, dims=("patch", "wavelength"), coords={"patch": list(sds), "wavelength": WAVELENGTHS}
    )


def checker_labels(patch: int = 8) -> np.ndarray:
    """(y, x) patch index of a 4 x 6 colour checker, 1 px background between patches."""
    labels = -np.ones((4 * patch, 6 * patch), dtype=int)
    for k in range(24):
        r, c = divmod(k, 6)
        labels[r * patch + 1 : (r + 1) * patch - 1, c * patch + 1 : (c + 1) * patch - 1] = k
    return labels


def paint(values: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """Image (y, x, ...) with patch ``k`` set to ``values[k]``, background 0.02 x mean."""
    out = np.broadcast_to(0.02 * values.mean(axis=0), labels.shape + values.shape[1:]).copy()
    out[labels >= 0] = values[labels[labels >= 0]]
    return out


def spectral_camera_response() -> xr.DataArray:
    """True f of the spectral camera over dark-subtracted values (eq. 5, s-curve)."""
    code = np.linspace(-20.0, FULL, 2048)
    f = response_model("s_curve").response(np.clip(code, 0, None) / FULL)
    return xr.DataArray(f, dims="code", coords={"code": code}, attrs={"dark_subtracted": True})


def spectral_shots(
    radiance: np.ndarray, times: np.ndarray, *, seed: int, quantum_efficiency: np.ndarray
) -> xr.Dataset:
    """raw/spectral-like shots (shot, y, x), one per band, of radiance (band, y, x)."""
    counts = capture(
        radiance,
        times[:, None, None],
        response=response_model("s_curve"),
        quantum_efficiency=quantum_efficiency[:, None, None],
        adc_offset=OFFSET,
        noise_sigma=SIGMA,
        bit_depth=BITS,
        seed=seed,
    )
    return xr.Dataset(
        {"counts": (("shot", "y", "x"), counts)},
        coords={"wavelength": ("shot", WAVELENGTHS), "exposure_time": ("shot", times)},
        attrs={"bit_depth": BITS},
    )


def dark_group(times: np.ndarray, shape: tuple[int, int], seed: int) -> xr.Dataset:
    frames = capture(
        np.zeros((times.size, 16) + shape),
        1.0,
        adc_offset=OFFSET,
        noise_sigma=SIGMA,
        bit_depth=BITS,
        seed=seed,
    ).astype(float)
    return xr.Dataset(
        {
            "mean": (("exposure_time", "y", "x"), frames.mean(axis=1).astype(np.float32)),
            "std": (("exposure_time", "y", "x"), frames.std(axis=1, ddof=1).astype(np.float32)),
        },
        coords={"exposure_time": times},
    )


@pytest.fixture(scope="module")
def white_setup():
    q_true = spectral_quantum_efficiency(WAVELENGTHS).values
    light = illuminant()
    rho = 0.95
    times = 0.5 / (rho * light.values * q_true)  # ~ half of full scale in every band
    radiance = np.broadcast_to((rho * light.values)[:, None, None], (32, 24, 24))
    shots = spectral_shots(radiance, times, seed=11, quantum_efficiency=q_true)
    dark = dark_group(times, (24, 24), seed=12)
    return shots, dark, light, rho, q_true


def test_quantum_efficiency_from_white_reference(white_setup) -> None:
    shots, dark, light, rho, q_true = white_setup
    result = quantum_efficiency(shots, dark, light, reflectance=rho, response=spectral_camera_response())
    q = result["quantum_efficiency"]
    assert q.dims == ("wavelength",)
    np.testing.assert_allclose(q["wavelength"].values, WAVELENGTHS)
    assert q.attrs["units"] == "1"
    np.testing.assert_allclose(q.values, q_true, rtol=0.01)
    assert np.all(result["snr"].values > 50)


def test_quantum_efficiency_with_a_raw_code_response_and_roi(white_setup) -> None:
    shots, dark, light, rho, q_true = white_setup
    code = np.arange(FULL + 1)
    f_raw = response_model("s_curve").response((code + 0.5 - OFFSET) / FULL)
    raw_response = xr.DataArray(f_raw, dims="code", coords={"code": code})
    reflectance = xr.DataArray(np.full(32, rho), dims="wavelength", coords={"wavelength": WAVELENGTHS})
    q = quantum_efficiency(
        shots,
        dark,
        light,
        reflectance=reflectance,
        response=raw_response,
        roi={"y": slice(4, 20), "x": slice(2, 22)},
    )["quantum_efficiency"]
    np.testing.assert_allclose(q.values, q_true, rtol=0.02)
    linear = quantum_efficiency(shots, dark, light, reflectance=rho)["quantum_efficiency"]
    assert np.corrcoef(linear.values, q_true)[0, 1] > 0.99  # a linear guess only scales


def test_band_signal_keeps_negative_values(white_setup) -> None:
    shots, dark, _, _, _ = white_setup
    black = shots.copy(
        data={
            "counts": np.clip(
                capture(
                    np.zeros((32, 24, 24)),
                    1.0,
                    adc_offset=OFFSET,
                    noise_sigma=SIGMA,
                    bit_depth=BITS,
                    seed=5,
                ),
                0,
                None,
            )
        }
    )
    signal = band_signal(black, dark)
    assert signal.dims == ("shot", "y", "x")
    assert (signal < 0).mean() > 0.3  # noise below the dark level survives
    per_band = signal.mean(("y", "x")) * shots["exposure_time"]
    assert np.abs(per_band).max() < 0.6  # unbiased: no clipping at zero


@pytest.fixture(scope="module")
def checker_setup():
    """Colour checker: HDR RGB shots (gamma camera, Nikon sensitivities) and spectral shots."""
    reflectance = checker_reflectance()
    light = illuminant()
    spectra = reflectance * light  # (patch, wavelength)
    c_true = camera_sensitivities(WAVELENGTHS)  # (channel, wavelength)
    rgb_true = (spectra @ c_true.T).values  # (patch, channel)
    labels = checker_labels()
    scene = paint(rgb_true / rgb_true.max(), labels)  # (y, x, channel)
    counts = capture(
        scene[None],
        RGB_TIMES[:, None, None, None],
        response=response_model("gamma"),
        adc_offset=OFFSET,
        noise_sigma=SIGMA,
        bit_depth=BITS,
        seed=21,
    )
    raw = xr.Dataset(
        {"counts": (("image", "exposure", "y", "x", "channel"), counts[None])},
        coords={"exposure_time": (("image", "exposure"), RGB_TIMES[None]), "channel": ["R", "G", "B"]},
        attrs={"bit_depth": BITS},
    )
    code = np.arange(FULL + 1)
    f = response_model("gamma").response((code + 0.5 - OFFSET) / FULL)
    response = xr.DataArray(f / f[511], dims="code", coords={"code": code}, attrs={"black_level": 25})
    radiance = hdr.merge_hdr(raw, response)["radiance"].isel(image=0)
    measured = patch_means(radiance, labels, names=list(reflectance["patch"].values))
    return spectra, measured, c_true, labels, light


def test_camera_matrix_from_colour_checker_shots(checker_setup) -> None:
    spectra, measured, c_true, _, _ = checker_setup
    result = camera_matrix(measured, spectra)
    c = result["camera_matrix"]
    assert c.dims == ("channel", "wavelength") and c.shape == (3, 32)
    assert c["channel"].values.tolist() == ["R", "G", "B"]
    assert np.all(c.values >= 0)
    scale = float((c * c_true).sum() / (c_true * c_true).sum())
    error = np.linalg.norm(c.values / scale - c_true.values) / np.linalg.norm(c_true.values)
    assert error < 0.15, error
    per_channel = np.linalg.norm(c.values / scale - c_true.values, axis=1) / np.linalg.norm(
        c_true.values, axis=1
    )
    assert per_channel.max() < 0.25, per_channel
    assert result.attrs["relative_rms_residual"] < 0.01
    assert result["residual"].dims == ("patch", "channel")


def test_smoothness_regularises_and_nonnegativity_holds(checker_setup) -> None:
    spectra, measured, c_true, _, _ = checker_setup
    rough = camera_matrix(measured, spectra, smoothness=0.0, nonnegative=False)
    smooth = camera_matrix(measured, spectra, smoothness=1e-2)
    curvature = [
        float(np.abs(np.diff(r["camera_matrix"].values, 2, axis=1)).sum()) for r in (rough, smooth)
    ]
    assert curvature[1] < 0.2 * curvature[0]
    assert np.any(rough["camera_matrix"].values < 0)
    assert np.all(smooth["camera_matrix"].values >= 0)


def _shape_error(c: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per channel: distance between the unit-norm rows of ``c`` and of ``truth``."""
    unit = c / np.linalg.norm(c, axis=1, keepdims=True)
    return np.linalg.norm(unit - truth / np.linalg.norm(truth, axis=1, keepdims=True), axis=1)


def test_cross_validated_smoothness_recovers_c_under_a_peaked_led():
    """A foreign lab's chart (18 smooth patches) under an LED with a narrow blue peak: many C
    reproduce the chart, a fixed weak smoothness picks a wrong one, leaving patches out
    does not."""
    from support import foreign_gantry as lab

    wl = lab.WAVELENGTHS
    spectra = xr.DataArray(
        lab.chart_reflectances(wl) * lab.illuminant(wl),
        dims=("patch", "wavelength"),
        coords={"patch": np.arange(18), "wavelength": wl},
    )
    truth = lab.rgb_sensitivity(wl)
    rng = np.random.default_rng(3)
    rgb = spectra.values @ truth.T
    rgb = rgb * (1 + 0.01 * rng.standard_normal(rgb.shape))  # 1 % patch-mean noise
    measured = xr.DataArray(rgb, dims=("patch", "channel"), coords={"patch": np.arange(18)})
    chosen, scores = cross_validated_smoothness(measured, spectra)
    assert scores.dims == ("smoothness",) and scores.size == len(SMOOTHNESS_CANDIDATES)
    assert chosen == float(scores["smoothness"][int(np.argmin(scores.values))])
    fixed = camera_matrix(measured, spectra, smoothness=1e-3)["camera_matrix"].values
    picked = camera_matrix(measured, spectra, smoothness=chosen)["camera_matrix"].values
    assert _shape_error(picked, truth).max() < 0.5 * _shape_error(fixed, truth).max()
    with pytest.raises(CalibrationError, match="at least 3 patches"):
        cross_validated_smoothness(measured.isel(patch=[0, 1]), spectra.isel(patch=[0, 1]))


def test_cross_validation_table_and_figure(checker_setup, white_setup) -> None:
    spectra, measured, c_true, labels, light = checker_setup
    c = camera_matrix(measured, spectra)
    # QE from the white reference, then a spectral capture of the checker
    shots_w, dark_w, _, rho, q_true = white_setup
    response = spectral_camera_response()
    q = quantum_efficiency(shots_w, dark_w, light, reflectance=rho, response=response)
    cube = np.moveaxis(paint(spectra.values, labels), -1, 0)  # (band, y, x)
    times = 0.3 / (cube.max(axis=(1, 2)) * q_true)
    shots = spectral_shots(cube, times, seed=31, quantum_efficiency=q_true)
    dark = dark_group(times, labels.shape, seed=32)
    signal = band_signal(shots, dark, response=response)
    band_radiance = (
        (signal / q["quantum_efficiency"].values[:, None, None])
        .assign_coords(wavelength=("shot", WAVELENGTHS))
        .swap_dims(shot="wavelength")
    )
    captured = patch_means(band_radiance, labels, names=list(spectra["patch"].values))
    table = cross_validate(measured, captured, c)
    assert set(table.data_vars) == {"measured", "predicted", "difference", "relative_error"}
    assert table["relative_error"].dims == ("patch",)
    assert table["relative_error"].sizes["patch"] == 24
    assert table.attrs["mean_relative_error"] < 0.02, table.attrs
    assert table.attrs["max_relative_error"] < 0.06
    assert table.attrs["worst_patch"] in spectra["patch"].values
    np.testing.assert_allclose(table["difference"], table["predicted"] - table["measured"])
    # a wrong C is caught by the cross-check
    wrong = c.copy(deep=True)
    wrong["camera_matrix"] = wrong["camera_matrix"].roll(wavelength=3)
    assert cross_validate(measured, captured, wrong).attrs["mean_relative_error"] > 0.05

    figure = plot_cross_validation(table)
    assert len(figure.axes) == 4
    assert figure.axes[3].get_ylabel() == "relative error [%]"
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    assert buffer.getvalue()[:4] == b"\x89PNG"


def test_patch_means_and_predict_rgb() -> None:
    labels = np.array([[0, 0, -1], [1, 1, 1]])
    data = xr.DataArray(np.arange(12.0).reshape(2, 3, 2), dims=("y", "x", "channel"))
    means = patch_means(data, labels, names=["a", "b"])
    assert means.dims == ("patch", "channel")
    np.testing.assert_allclose(means.sel(patch="a"), [1.0, 2.0])
    np.testing.assert_allclose(means.sel(patch="b"), [8.0, 9.0])
    c = xr.DataArray(
        np.eye(3)[:2],
        dims=("channel", "wavelength"),
        coords={"channel": ["R", "G"], "wavelength": [500.0, 600.0, 700.0]},
    )
    spectra = xr.DataArray(
        [[1.0, 2.0, 3.0]], dims=("patch", "wavelength"), coords={"wavelength": [500.0, 600.0, 700.0]}
    )
    np.testing.assert_allclose(predict_rgb(spectra, c).values, [[1.0, 2.0]])


# -- bad input ----------------------------------------------------------------------------------
def test_white_reference_darker_than_the_noise(white_setup) -> None:
    shots, dark, light, rho, _ = white_setup
    dim = shots.copy(deep=True)
    dim["counts"].values[7] = capture(
        np.zeros((24, 24)), 1.0, adc_offset=OFFSET + 1, noise_sigma=SIGMA, bit_depth=BITS, seed=3
    )
    with pytest.raises(CalibrationError, match=r"shot 7 \(480.0 nm.*darker than the noise.*SNR"):
        quantum_efficiency(dim, dark, light, reflectance=rho)
    no_std = dark.drop_vars("std")
    with pytest.raises(CalibrationError, match="darker than the noise"):
        quantum_efficiency(dim, no_std, light, reflectance=rho)


def test_dark_frame_missing_or_of_another_size(white_setup) -> None:
    shots, dark, light, rho, _ = white_setup
    t = float(shots["exposure_time"][4])
    with pytest.raises(
        CalibrationError, match=rf"dark:mean has no frame for exposure_time {t} s \(shot 4\)"
    ):
        quantum_efficiency(shots, dark.drop_sel(exposure_time=t), light, reflectance=rho)
    with pytest.raises(
        CalibrationError,
        match="dark:mean frames are 24x20 px but the frames of band_signal are 24x24 px",
    ):
        band_signal(shots, dark.isel(x=slice(0, 20)))


def test_spectra_that_do_not_cover_the_bands(white_setup) -> None:
    shots, dark, light, rho, _ = white_setup
    with pytest.raises(CalibrationError, match=r"illuminant covers 450.0..720.0 nm"):
        quantum_efficiency(shots, dark, light.sel(wavelength=slice(450, None)), reflectance=rho)
    with pytest.raises(CalibrationError, match="reflectance must be positive"):
        quantum_efficiency(shots, dark, light, reflectance=0.0)
    with pytest.raises(CalibrationError, match="roi may only select y and x"):
        quantum_efficiency(shots, dark, light, roi={"shot": slice(0, 2)})
    with pytest.raises(SchemaError, match="raw/spectral contract"):
        band_signal(shots.drop_vars("wavelength"), dark)


def test_camera_matrix_and_cross_validation_mismatches() -> None:
    rgb = xr.DataArray(np.ones((24, 3)), dims=("patch", "channel"))
    spectra = xr.DataArray(
        np.ones((23, 32)), dims=("patch", "wavelength"), coords={"wavelength": WAVELENGTHS}
    )
    with pytest.raises(CalibrationError, match="rgb has 24 patches, spectra 23"):
        camera_matrix(rgb, spectra)
    with pytest.raises(SchemaError, match=r"rgb must be \(patch, channel\)"):
        camera_matrix(rgb.rename(channel="band"), spectra)
    with pytest.raises(CalibrationError, match="finite"):
        camera_matrix(rgb.isel(patch=slice(0, 23)) * np.nan, spectra)
    c = xr.DataArray(
        np.ones((3, 32)), dims=("channel", "wavelength"), coords={"wavelength": WAVELENGTHS + 5}
    )
    with pytest.raises(CalibrationError, match="spectra are at .* nm, C at"):
        predict_rgb(spectra, c)
    with pytest.raises(CalibrationError, match="measured_rgb has 24 patches, spectra 23"):
        cross_validate(rgb, spectra, c)
    with pytest.raises(CalibrationError, match=r"labels have shape \(2, 2\)"):
        patch_means(xr.DataArray(np.ones((3, 3)), dims=("y", "x")), np.zeros((2, 2), int))
    with pytest.raises(CalibrationError, match=r"patch\(es\) \[1\] have no pixel"):
        patch_means(xr.DataArray(np.ones((1, 3)), dims=("y", "x")), np.array([[0, 2, 2]]))
