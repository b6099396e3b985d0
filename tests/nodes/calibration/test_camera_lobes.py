"""Tests of spectralize.nodes.calibration.camera_lobes: C as a non-negative sum of smooth lobes."""

from __future__ import annotations

import colour
import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration import camera_lobes as cl
from spectralize.nodes.calibration import camera_matrices, camera_smooth
from spectralize.schemas import CalibrationError, SchemaError

BANDS = np.arange(410.0, 721.0, 10.0)


def gauss(wl: np.ndarray, centre: float, width: float) -> np.ndarray:
    return np.exp(-0.5 * ((wl - centre) / width) ** 2)


def smooth_camera(wl: np.ndarray) -> np.ndarray:
    """(3, wavelength): skewed lobes, a secondary blue lobe in R (not a sum of the basis)."""
    red = np.where(wl < 600, gauss(wl, 600.0, 28.0), gauss(wl, 600.0, 45.0)) + 0.07 * gauss(wl, 445, 18)
    return np.stack(
        [red, gauss(wl, 532.0, 36.0), np.where(wl < 455, gauss(wl, 455, 22), gauss(wl, 455, 32))]
    )


def led(wl: np.ndarray) -> np.ndarray:
    """A phosphor LED with a narrow blue peak; its 410 nm band gets 1 % of the peak."""
    return gauss(wl, 450.0, 9.0) + 0.55 * gauss(wl, 565.0, 45.0) + 0.18 * gauss(wl, 640.0, 40.0) + 1e-3


def checker_and_white() -> np.ndarray:
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    values = [np.interp(BANDS, sd.wavelengths, sd.values) for sd in sds.values()]
    return np.vstack([*values, np.full(BANDS.size, 0.97)])


def shape_error(c: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per channel: RMS of ``s c - truth`` over wavelength relative to its peak (``s`` per channel)."""
    s = (c * truth).sum(1) / (c * c).sum(1)
    return np.sqrt(np.mean((s[:, None] * c - truth) ** 2, axis=1)) / truth.max(1)


def patches(noise: float, seed: int = 5) -> tuple[xr.DataArray, xr.DataArray, np.ndarray]:
    spectra = checker_and_white() * led(BANDS)
    truth = smooth_camera(BANDS)
    rgb = spectra @ truth.T
    rgb = rgb * (1 + noise * np.random.default_rng(seed).standard_normal(rgb.shape))
    n = spectra.shape[0]
    return (
        xr.DataArray(
            rgb, dims=("patch", "channel"), coords={"patch": np.arange(n), "channel": list("RGB")}
        ),
        xr.DataArray(
            spectra, dims=("patch", "wavelength"), coords={"patch": np.arange(n), "wavelength": BANDS}
        ),
        truth,
    )


def test_lobes_recover_a_smooth_camera_within_5_percent_per_channel():
    """Patch means with 0.2 % noise; the second-difference fit misses by 7 % in R here."""
    rgb, spectra, truth = patches(noise=0.002)
    fitted = cl.lobe_camera_matrix(rgb, spectra)
    c = fitted["camera_matrix"]
    assert c.dims == ("channel", "wavelength") and c["channel"].values.tolist() == list("RGB")
    np.testing.assert_array_equal(c["wavelength"].values, BANDS)
    assert np.all(c.values >= 0)
    error = shape_error(c.values, truth)
    assert error.max() < 0.05, error
    assert fitted.attrs["relative_rms_residual"] < 0.02
    assert fitted["ridge"].dims == ("channel",) and np.all(fitted["ridge"].values > 0)
    assert fitted["ridge_cv"].dims == ("ridge_candidate", "channel")
    smoothness, _ = camera_smooth.cross_validated_smoothness(rgb, spectra)
    smooth = camera_smooth.camera_matrix(rgb, spectra, smoothness=smoothness)["camera_matrix"].values
    assert error.max() < shape_error(smooth, truth).max()
    # the chosen ridge is at least the one of the smallest leave-one-out score, per channel
    for k in range(3):
        scores = fitted["ridge_cv"].isel(channel=k).values
        assert fitted["ridge"].values[k] >= cl.RIDGE_CANDIDATES[int(np.argmin(scores))]
    bare = cl.cross_validated_ridge(rgb.values, spectra.values, cl.lobe_basis(BANDS), one_se=0.0)[0]
    np.testing.assert_array_equal(
        bare, [cl.RIDGE_CANDIDATES[int(np.argmin(fitted["ridge_cv"].values[:, k]))] for k in range(3)]
    )


def test_lobes_do_not_rise_where_the_light_is_weak():
    """The weakly lit red end (the LED at 2-3 % there): a lobe sum falls with the truth; its
    rows are smooth (no wiggle sharper than the narrowest lobe)."""
    rgb, spectra, truth = patches(noise=0.01, seed=9)
    c = cl.lobe_camera_matrix(rgb, spectra)["camera_matrix"].values
    c = c / c.max(axis=1, keepdims=True)
    tail = BANDS >= 690
    assert np.all(c[:, tail] < truth[:, tail] / truth.max(1, keepdims=True) + 0.1)
    assert np.abs(np.diff(c, 2, axis=1)).max() < 0.25


def test_a_given_ridge_per_channel_and_its_errors():
    rgb, spectra, _ = patches(noise=0.0)
    fitted = cl.lobe_camera_matrix(rgb, spectra, ridge=[1e-4, 1e-3, 1e-2])
    assert fitted["ridge"].values.tolist() == [1e-4, 1e-3, 1e-2] and "ridge_cv" not in fitted
    heavy = cl.lobe_camera_matrix(rgb, spectra, ridge=1.0)
    assert heavy.attrs["relative_rms_residual"] > fitted.attrs["relative_rms_residual"]
    with pytest.raises(CalibrationError, match="ridge must be >= 0"):
        cl.lobe_camera_matrix(rgb, spectra, ridge=-1.0)
    with pytest.raises(CalibrationError, match="no RGB signal"):
        cl.lobe_camera_matrix(rgb.where(rgb["patch"] != 3, 0.0), spectra)
    with pytest.raises(CalibrationError, match="at least 3 patches"):
        cl.lobe_camera_matrix(rgb.isel(patch=[0, 1]), spectra.isel(patch=[0, 1]))
    with pytest.raises(CalibrationError, match="different patches"):
        cl.lobe_camera_matrix(rgb, spectra.assign_coords(patch=spectra["patch"].values + 1))
    with pytest.raises(SchemaError, match="must be"):
        cl.lobe_camera_matrix(rgb.rename(channel="c"), spectra)


def test_lobe_basis_is_smooth_non_negative_and_reaches_beyond_the_bands():
    basis = cl.lobe_basis(BANDS)
    centres = np.arange(BANDS[0] - cl.LOBE_MARGIN, BANDS[-1] + cl.LOBE_MARGIN + 1e-9, cl.LOBE_STEP)
    assert basis.shape == (BANDS.size, centres.size * len(cl.LOBE_WIDTHS))
    assert np.all(basis >= 0) and np.all(basis <= 1)


def test_the_node_takes_either_method_from_its_table():
    assert set(camera_matrices.CAMERA_MATRIX_METHODS) == {"lobes", "smooth"}
    assert camera_matrices.CAMERA_MATRIX_METHODS["lobes"] is cl.lobe_camera_matrix


def test_c_is_held_to_zero_where_the_patches_had_no_light():
    """A camera with no sensitivity at the LED's unlit blue end (410-420 nm: 0.1 % of the
    peak): the patches cannot tell, the weak-light penalty can. Without it, the broad lobes
    of the blue row reach into those bands; with it they do not, at the same fit to the
    patches (the penalty acts where the patches see nothing)."""
    rgb, spectra, _ = patches(noise=0.002)
    truth = smooth_camera(BANDS) * (BANDS >= 430)  # a sensor blind below 430 nm
    dim = spectra.where(spectra["wavelength"] >= 430, spectra * 0.1)  # its LED dark there
    rgb = rgb.copy(data=dim.values @ truth.T)
    held = cl.lobe_camera_matrix(rgb, dim, ridge=1e-3)
    free = cl.lobe_camera_matrix(rgb, dim, ridge=1e-3, weak_light=0.0)
    assert held.attrs["weak_light"] == cl.WEAK_LIGHT_WEIGHT and free.attrs["weak_light"] == 0.0
    assert held.attrs["weak_light_floor"] == cl.WEAK_LIGHT_FLOOR
    blue = [
        c.sel(channel="B", wavelength=410).item() / c.sel(channel="B").max().item()
        for c in (held["camera_matrix"], free["camera_matrix"])
    ]
    assert blue[0] < 0.5 * blue[1], blue
    assert held.attrs["relative_rms_residual"] < free.attrs["relative_rms_residual"] + 0.005
    assert (
        shape_error(held["camera_matrix"].values, truth).max()
        < shape_error(free["camera_matrix"].values, truth).max()
    )


def test_weak_light_weights_grow_where_the_light_falls_and_refuse_bad_settings():
    _, spectra, _ = patches(noise=0.0)
    w = cl.weak_light_weights(spectra.values)
    light = np.sqrt((spectra.values**2).sum(0))
    assert w.shape == BANDS.shape and np.all(w > 0)
    assert w[np.argmin(light)] == w.max() and w[np.argmax(light)] == w.min()
    with pytest.raises(CalibrationError, match="floor must be > 0"):
        cl.weak_light_weights(spectra.values, floor=0.0)
    rgb, _, _ = patches(noise=0.0)
    with pytest.raises(CalibrationError, match="weak_light must be >= 0"):
        cl.lobe_camera_matrix(rgb, spectra, weak_light=-1.0)
    with pytest.raises(CalibrationError, match="weak_light_floor must be > 0"):
        cl.lobe_camera_matrix(rgb, spectra, weak_light_floor=0.0)
