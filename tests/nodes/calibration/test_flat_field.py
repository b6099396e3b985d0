"""Flat field: a lens falloff measured on hand-made white-reference series and taken out."""

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration.flat_field import (
    FlatField,
    fit_flat_field,
    flat_field_variables,
    from_calibration,
    legendre_powers,
    rgb_flat_field,
    spectral_flat_field,
)
from spectralize.nodes.calibration.flat_field_maps import smooth_across_bands
from spectralize.nodes.calibration.hdr import merge_hdr
from spectralize.nodes.calibration.result_checks import flat_field_warnings
from spectralize.schemas import CalibrationError

NY, NX = 48, 60
YY, XX = np.mgrid[0:NY, 0:NX] + 0.5
R2 = ((YY - NY / 2) ** 2 + (XX - NX / 2) ** 2) / ((NY / 2) ** 2 + (NX / 2) ** 2)
INNER = (slice(NY // 16, -NY // 16), slice(NX // 16, -NX // 16))


def falloff(corner: float) -> np.ndarray:
    """A cos^4-type falloff, 1 at the centre and ``corner`` in the corners."""
    return 1.0 / (1.0 + (corner**-0.5 - 1.0) * R2) ** 2


def fitted_map(frame: np.ndarray) -> np.ndarray:
    fit = fit_flat_field(frame)
    return FlatField(fit.coefficients[None], legendre_powers(), (NY, NX), np.array([0])).maps([0])[0]


def test_a_noisy_falloff_is_recovered_within_a_per_cent_away_from_the_border():
    truth = falloff(0.7)
    noisy = 900.0 * truth * (1 + 0.01 * np.random.default_rng(1).standard_normal(truth.shape))
    fit = fit_flat_field(noisy)
    got = fitted_map(noisy)
    assert np.abs(got / truth - 1)[INNER].max() < 0.01
    assert 0 < fit.noise < 0.01 and fit.corner == pytest.approx(0.7, abs=0.02)
    assert abs(fit.gradient) < 0.01 and abs(fit.unevenness) < 0.03


def test_an_even_white_reference_gives_a_flat_field_of_one_within_its_noise():
    frame = 500.0 * (1 + 0.01 * np.random.default_rng(2).standard_normal((NY, NX)))
    fit = fit_flat_field(frame)
    assert np.abs(fitted_map(frame) - 1).max() < 4 * fit.noise
    assert fit.corner == pytest.approx(1.0, abs=4 * fit.noise)


def test_a_tilted_and_a_shadowed_target_are_measured():
    tilted = fit_flat_field(falloff(0.8) * (1 + 0.12 * (XX / NX - 0.5)))
    assert tilted.gradient == pytest.approx(0.06, abs=0.01)
    shadow = 1 - 0.2 * np.exp(-((YY - 14) ** 2 + (XX - 40) ** 2) / (2 * 4.0**2))
    shaded = fit_flat_field(falloff(0.8) * shadow)
    assert shaded.unevenness < -0.08  # the dip, left in the residual of the robust fit
    robust = FlatField(shaded.coefficients[None], legendre_powers(), (NY, NX), np.array([0]))
    far = R2 < 0.5  # the map away from the shadow is the lens's
    assert np.abs(robust.maps([0])[0] / falloff(0.8) - 1)[far & (np.abs(XX - 40) > 12)].max() < 0.02


def test_divide_is_the_same_lazy_and_loaded_and_refuses_another_frame():
    coefficients = np.stack(
        [fit_flat_field(falloff(c)).coefficients for c in (0.8, 0.6)]
    )  # two cameras, one map each (no channel)
    flat = FlatField(coefficients, legendre_powers(), (NY, NX), np.array([3, 5]))
    data = xr.DataArray(np.ones((4, NY, NX), np.float32), dims=("image", "y", "x"))
    rows = flat.rows(np.array([5, 3, 3, 5]), "camera")
    eager = flat.divide(data, rows)
    lazy = flat.divide(data.chunk({"image": 3, "y": 20, "x": 25}), rows)
    assert lazy.chunks is not None and eager.dtype == np.float32
    np.testing.assert_allclose(lazy.values, eager.values, rtol=1e-6)
    np.testing.assert_allclose(eager.values[0][INNER], (1 / falloff(0.6))[INNER], rtol=0.01)
    with pytest.raises(CalibrationError, match=r"no map for camera \[4.0\]"):
        flat.rows(np.array([4]), "camera")
    with pytest.raises(CalibrationError, match="frames of"):
        flat.divide(data.isel(x=slice(0, 10)), rows)


def white_reference(truth: np.ndarray, cameras=(0, 1)) -> xr.Dataset:
    """A raw/white_reference of a linear 12-bit RGB camera per camera (three exposures) and a
    spectral camera of two bands (four exposures) seeing ``truth`` (y, x) as falloff."""
    rng = np.random.default_rng(3)
    rgb_times = np.array([0.01, 0.02, 0.06])
    level = np.array([600.0, 500.0, 400.0])  # DN per 10 ms, per channel
    rgb = truth[None, None, :, :, None] * level * rgb_times[None, :, None, None, None] / 0.01
    rgb = np.repeat(rgb, len(cameras), axis=0) + 64 + rng.normal(0, 2, (len(cameras), 3, NY, NX, 3))
    band_times = np.array([0.01, 0.02, 0.06, 0.12])
    band = np.array([1.0, 1.6])[:, None, None, None] * truth * band_times[None, :, None, None] * 3e4
    spectral = band + 100 + rng.normal(0, 2, band.shape)
    return xr.Dataset(
        {
            "rgb_counts": (
                ("camera", "rgb_exposure", "y", "x", "channel"),
                np.clip(np.round(rgb), 0, 4095).astype(np.uint16),
            ),
            "spectral_counts": (
                ("wavelength", "spectral_exposure", "y", "x"),
                np.clip(np.round(spectral), 0, 4095).astype(np.uint16),
            ),
        },
        coords={
            "camera": list(cameras),
            "channel": ["R", "G", "B"],
            "wavelength": [500.0, 600.0],
            "rgb_exposure_time": (("camera", "rgb_exposure"), np.tile(rgb_times, (len(cameras), 1))),
            "spectral_exposure_time": ("spectral_exposure", band_times),
        },
        attrs={"rgb_bit_depth": 12, "spectral_bit_depth": 12, "rgb_camera": cameras[-1]},
    )


def linear_oecf(cameras=(0, 1)) -> xr.Dataset:
    codes = np.arange(4096)
    response = np.tile(np.clip(codes - 64.0, 0, None) / 2000.0, (len(cameras), 3, 1))
    return xr.Dataset(
        {
            "response": (("camera", "channel", "code"), response),
            "black_level": ("camera", [70] * len(cameras)),
            "saturation": ("camera", [4000] * len(cameras)),
        },
        coords={"camera": list(cameras), "channel": ["R", "G", "B"], "code": codes},
        attrs={"bit_depth": 12},
    )


def dark_frames(times: np.ndarray) -> xr.Dataset:
    return xr.Dataset(
        {
            "mean": (("exposure_time", "y", "x"), np.full((len(times), NY, NX), 100.0, np.float32)),
            "std": (("exposure_time", "y", "x"), np.full((len(times), NY, NX), 2.0, np.float32)),
        },
        coords={"exposure_time": times},
    )


def test_rgb_and_band_flat_fields_from_a_white_reference_series():
    truth = falloff(0.75)
    white = white_reference(truth)
    flat, fits = rgb_flat_field(white, linear_oecf())
    assert flat.coefficients.shape == (2, 3, len(legendre_powers()))
    for row in range(2):
        maps = flat.maps([row])[0]
        for c in range(3):
            assert np.abs(maps[..., c] / truth - 1)[INNER].max() < 0.01
            assert fits[row][c].noise < 0.005
    bands, band_fits = spectral_flat_field(
        white, dark_frames(white["spectral_exposure_time"].values), None
    )
    for row in range(2):
        assert np.abs(bands.maps([row])[0] / truth - 1)[INNER].max() < 0.01
    # the HDR merge through the flat field makes the white reference flat
    series = white["rgb_counts"].isel(camera=[1]).rename(camera="image", rgb_exposure="exposure")
    raw = xr.Dataset(
        {"counts": series.transpose("image", "exposure", "y", "x", "channel")},
        coords={
            "exposure_time": (("image", "exposure"), white["rgb_exposure_time"].values[[1]]),
            "camera": ("image", [1]),
        },
        attrs={"bit_depth": 12},
    )
    hdr = merge_hdr(raw, linear_oecf(), flat_field=flat)["radiance"].values[0]
    assert np.abs(hdr / hdr[NY // 2, NX // 2] - 1)[INNER].max() < 0.02
    # stored and read back as calibration/spectral variables
    group = flat_field_variables(flat, fits, bands, band_fits, [0, 1, 2], {2: 0})
    back = from_calibration(group.assign_coords(channel=["R", "G", "B"]), "rgb")
    np.testing.assert_allclose(back.coefficients[2], flat.coefficients[0])  # borrowed
    assert np.isnan(group["flat_field_rgb_noise"].values[2]).all()
    assert flat_field_warnings(group.assign_coords(channel=["R", "G", "B"])) == []


def test_an_uneven_white_reference_and_strong_corners_warn_with_the_numbers():
    shadow = 1 - 0.25 * np.exp(-((YY - 14) ** 2 + (XX - 40) ** 2) / (2 * 5.0**2))
    tilt = 1 + 0.15 * (XX / NX - 0.5)
    white = white_reference(falloff(0.8) * shadow, cameras=(0,))
    flat, fits = rgb_flat_field(white, linear_oecf((0,)))
    tilted = white_reference(falloff(0.45) * tilt, cameras=(0,))
    bands, band_fits = spectral_flat_field(
        tilted, dark_frames(tilted["spectral_exposure_time"].values), None
    )
    group = flat_field_variables(flat, fits, bands, band_fits, [0]).assign_coords(
        channel=["R", "G", "B"], camera_name=("camera", ["rgb45"])
    )
    found = flat_field_warnings(group)
    assert any(
        m.startswith("camera rgb45: the white reference is not even: a local dip of") for m in found
    )
    gradient = [m for m in found if m.startswith("the spectral camera: the white reference has a")]
    assert gradient and float(gradient[0].split("+-")[1].split(" %")[0]) > 3.0  # the tilt
    assert any("the spectral camera: the flat field is 0.4" in m and "corner" in m for m in found)


def test_the_report_figure_draws_every_camera_and_the_band_profiles():
    from spectralize.nodes.evaluation.figures_calibration import plot_flat_field

    white = white_reference(falloff(0.8))
    flat, fits = rgb_flat_field(white, linear_oecf())
    bands, band_fits = spectral_flat_field(
        white, dark_frames(white["spectral_exposure_time"].values), None
    )
    group = flat_field_variables(flat, fits, bands, band_fits, [0, 1]).assign_coords(
        channel=["R", "G", "B"], camera_name=("camera", ["top", "rgb45"])
    )
    figure = plot_flat_field(group)
    titles = [ax.get_title() for ax in figure.axes]
    assert titles[0].startswith("camera top\ncorners 0.8") and titles[1].startswith("camera rgb45")
    assert titles[2].startswith("spectral, 600 nm") and "per band" in titles[3]
    assert len(figure.axes[3].lines) == 2  # one diagonal profile per band
    assert plot_flat_field(group.drop_vars("flat_field")) is None


def compressive_white_reference(truth: np.ndarray) -> tuple[xr.Dataset, np.ndarray]:
    """A raw/white_reference of one 12-bit RGB camera with a compressive response
    ``DN = 64 + 4000 y^0.8`` over an exposure series of ratios 2 and 3 seeing ``truth`` as
    falloff, and that camera's true ``f^-1`` per code."""
    rng = np.random.default_rng(4)
    times = np.array([1.0, 2.0, 6.0, 12.0, 36.0, 72.0]) * 1e-3
    gain = np.array([13.0, 10.0, 7.0])  # full scale at the centre after 77, 100, 143 ms
    y = truth[None, :, :, None] * gain * times[:, None, None, None]
    dn = 64 + 4000 * y**0.8 + rng.normal(0, 1.5, y.shape)
    codes = np.arange(4096, dtype=float)
    inverse = (np.clip(codes - 64, 0, None) / 4000) ** 1.25
    white = xr.Dataset(
        {
            "rgb_counts": (
                ("camera", "rgb_exposure", "y", "x", "channel"),
                np.clip(np.round(dn), 0, 4095).astype(np.uint16)[None],
            )
        },
        coords={
            "camera": [0],
            "channel": ["R", "G", "B"],
            "rgb_exposure_time": (("camera", "rgb_exposure"), times[None]),
        },
        attrs={"rgb_bit_depth": 12, "rgb_camera": 0},
    )
    return white, inverse


def test_a_response_ripple_does_not_read_as_falloff():
    # the recovered response ripples (8 %, a period of 0.9 in the log code); merged through
    # it, the frame's darker corners sit on another part of the ripple than its centre (the
    # flat field off by more than 1 %); the white reference's own smooth response, fitted
    # jointly with the flat field, recovers the falloff within 1 % away from the border
    truth = falloff(0.8)
    white, inverse = compressive_white_reference(truth)
    log_code = np.log(np.clip(np.arange(4096) - 64.0, 1, None))
    rippled = inverse * (1 + 0.08 * np.sin(2 * np.pi * log_code / 0.9))
    oecf = linear_oecf((0,))
    oecf["response"] = (("camera", "channel", "code"), np.tile(rippled, (1, 3, 1)))
    errors = {}
    for own in (False, True):
        flat, fits = rgb_flat_field(white, oecf, own_response=own)
        errors[own] = float(np.abs(flat.maps([0])[0][..., 0] / truth - 1)[INNER].max())
    assert errors[False] > 0.015 and errors[True] < 0.01, errors
    assert all(abs(f.unevenness) < 0.03 for f in fits[0])
    # the true response gives the same map as its own smooth one
    oecf["response"] = (("camera", "channel", "code"), np.tile(inverse, (1, 3, 1)))
    exact, _ = rgb_flat_field(white, oecf, own_response=False)
    assert np.abs(flat.maps([0])[0] / exact.maps([0])[0] - 1)[INNER].max() < 0.01


def compressive_band_series(truth: np.ndarray, hot: bool = False) -> tuple[xr.Dataset, xr.Dataset]:
    """A raw/white_reference band series of a 12-bit spectral camera with a compressive
    response ``I - dark = 4000 y^0.8`` seeing ``truth`` as falloff (two bands, six exposures
    of ratios 2 and 3), and its dark frames (100 DN, 2 DN noise); with ``hot`` one hot pixel
    whose dark current saturates it in the longest exposure."""
    rng = np.random.default_rng(5)
    times = np.array([1.0, 2.0, 6.0, 12.0, 36.0, 72.0]) * 1e-3
    gain = np.array([[13.0], [5.0]])  # full scale at the centre after 77 and 200 ms
    y = truth[None, None] * (gain * times)[..., None, None]
    dark = np.full((times.size, NY, NX), 100.0)
    if hot:
        dark[:, 30, 10] = 100.0 + 6e4 * times  # 4420 DN at 72 ms
    dn = dark + 4000 * y**0.8 + rng.normal(0, 2.0, y.shape)
    white = xr.Dataset(
        {
            "spectral_counts": (
                ("wavelength", "spectral_exposure", "y", "x"),
                np.clip(np.round(dn), 0, 4095).astype(np.uint16),
            )
        },
        coords={"wavelength": [500.0, 600.0], "spectral_exposure_time": ("spectral_exposure", times)},
        attrs={"spectral_bit_depth": 12},
    )
    darks = xr.Dataset(
        {
            "mean": (("exposure_time", "y", "x"), dark.astype(np.float32)),
            "std": (("exposure_time", "y", "x"), np.full(dark.shape, 2.0, np.float32)),
        },
        coords={"exposure_time": times},
    )
    return white, darks


def test_a_spectral_response_ripple_does_not_read_as_falloff():
    # the spectral camera's recovered response ripples (8 %, a period of 0.9 in the log code):
    # through it each band's darker corners sit on another part of the ripple than its
    # centre; one smooth response fitted on the band series by the exposures' ratios
    # recovers the falloff within 1 % away from the border, as the true response does
    truth = falloff(0.7)
    white, darks = compressive_band_series(truth)
    codes = np.arange(4096, dtype=float)
    inverse = (codes / 4000) ** 1.25
    rippled = inverse * (1 + 0.08 * np.sin(2 * np.pi * np.log(np.maximum(codes, 1)) / 0.9))

    def oecf(table: np.ndarray) -> xr.Dataset:
        return xr.Dataset(
            {"response": ("code", table, {"dark_subtracted": True})}, coords={"code": codes}
        )

    def error(flat: FlatField) -> float:
        return max(float(np.abs(flat.maps([r])[0] / truth - 1)[INNER].max()) for r in range(2))

    through_ripple, _ = spectral_flat_field(white, darks, oecf(rippled), own_response=False)
    own, fits = spectral_flat_field(white, darks, oecf(rippled))
    exact, _ = spectral_flat_field(white, darks, oecf(inverse), own_response=False)
    assert error(through_ripple) > 0.015 and error(own) < 0.01, (error(through_ripple), error(own))
    assert error(exact) < 0.01 and all(abs(f.unevenness) < 0.03 for f in fits)


def test_a_hot_pixel_saturated_by_its_dark_current_keeps_the_longest_exposure():
    # the longest exposure is the weak band's best measure of the falloff; a pixel that its
    # dark current alone saturates leaves that exposure in, without the pixel
    truth = falloff(0.7)
    clean, darks = compressive_band_series(truth)
    white, hot_darks = compressive_band_series(truth, hot=True)
    assert white["spectral_counts"].values[1, -1, 30, 10] == 4095
    _, fits = spectral_flat_field(white, hot_darks, None)
    _, clean_fits = spectral_flat_field(clean, darks, None)
    _, dropped_fits = spectral_flat_field(
        clean.isel(spectral_exposure=slice(0, -1)), darks.isel(exposure_time=slice(0, -1)), None
    )
    assert fits[1].noise == pytest.approx(clean_fits[1].noise, rel=0.1)
    assert fits[1].noise < 0.8 * dropped_fits[1].noise
    # light that saturates a pixel still leaves the exposure out
    bright = clean.copy(deep=True)
    bright["spectral_counts"][1, -1, NY // 2, NX // 2] = 4095
    _, bright_fits = spectral_flat_field(bright, darks, None)
    assert bright_fits[1].noise == pytest.approx(dropped_fits[1].noise, rel=0.01)


def test_the_weak_end_bands_borrow_their_falloff_from_their_neighbours():
    # a band series whose end bands get under 1 % of the others' light: each band's own map
    # is noisy there; fitted as a smooth function of wavelength, weighted by each band's
    # noise floor, every band is within half a per cent away from the border
    rng = np.random.default_rng(1)
    wavelengths = np.arange(450.0, 520.0, 10.0)
    corner = 0.75 - 0.1 * (wavelengths - wavelengths.mean()) / 30  # 0.85 .. 0.65
    truth = 1.0 / (1.0 + (corner[:, None, None] ** -0.5 - 1.0) * R2) ** 2
    light = np.array([0.008, 1, 1, 1, 1, 1, 0.008])
    times = np.array([0.01, 0.02, 0.06, 0.12])
    signal = light[:, None, None, None] * truth[:, None] * times[None, :, None, None] * 3e4
    counts = np.round(signal + 100 + rng.normal(0, 2, signal.shape))
    white = xr.Dataset(
        {
            "spectral_counts": (
                ("wavelength", "spectral_exposure", "y", "x"),
                np.clip(counts, 0, 4095).astype(np.uint16),
            )
        },
        coords={"wavelength": wavelengths, "spectral_exposure_time": ("spectral_exposure", times)},
        attrs={"spectral_bit_depth": 12},
    )
    errors, noise = {}, {}
    for bandwidth in (0.0, 30.0):
        flat, fits = spectral_flat_field(white, dark_frames(times), None, bandwidth=bandwidth)
        errors[bandwidth] = np.array(
            [np.abs(flat.maps([r])[0] / truth[r] - 1)[INNER].max() for r in range(wavelengths.size)]
        )
        noise[bandwidth] = np.array([f.noise for f in fits])
        np.testing.assert_allclose(
            flat.maps(range(wavelengths.size))[:, NY // 2, NX // 2], 1, atol=0.002
        )
    assert errors[0.0][[0, -1]].min() > 0.01 and errors[30.0].max() < 0.005, errors
    assert np.all(noise[30.0][[0, -1]] < 0.1 * noise[0.0][[0, -1]])
    # a map the same at every band stays that map
    same = np.repeat(fit_flat_field(falloff(0.7)).coefficients[None], wavelengths.size, axis=0)
    smoothed, _ = smooth_across_bands(same, fits, wavelengths)
    np.testing.assert_allclose(smoothed, same, atol=1e-12)
