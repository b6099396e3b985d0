"""Calibration nodes on the tiny simulated run, checked against its truth/camera."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.calibration.band_radiance import calibrate_bands
from spectralize.nodes.calibration.dark import average_dark_frames
from spectralize.nodes.calibration.declarations import merge_hdr_node
from spectralize.nodes.calibration.oecf.low_snr import recover_spectral_oecf
from spectralize.nodes.calibration.oecf.robertson import recover_rgb_oecf
from spectralize.nodes.calibration.registration import estimate_registration
from spectralize.nodes.calibration.spectral import calibrate_spectral
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.schemas import CalibrationError
from spectralize.schemas.run import GROUP_SCHEMAS
from spectralize.schemas.spec import validate_dataset


def _scale(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sum(estimate * truth) / np.sum(estimate * estimate))


@pytest.fixture(scope="module")
def cal():
    run = {k: v.load() for k, v in simulate_run(get_recipe("tiny")).items() if k != "truth/spectra"} | {
        "truth/spectra": simulate_run(get_recipe("tiny"))["truth/spectra"]
    }
    dark = average_dark_frames(run["raw/dark"]).load()
    oecf_rgb = recover_rgb_oecf(run["raw/rgb"])
    oecf_spec = recover_spectral_oecf(run["raw/white_reference"], dark)
    spectral = calibrate_spectral(
        run["raw/white_reference"], run["raw/colour_checker"], dark, oecf_rgb, oecf_spec
    )
    return {
        "run": run,
        "dark": dark,
        "oecf_rgb": oecf_rgb,
        "oecf_spectral": oecf_spec,
        "spectral": spectral,
        "truth": run["truth/camera"],
    }


def test_groups_follow_their_schemas(cal):
    for group, ds in (
        ("calibration/oecf_rgb", cal["oecf_rgb"]),
        ("calibration/oecf_spectral", cal["oecf_spectral"]),
        ("calibration/spectral", cal["spectral"]),
    ):
        assert validate_dataset(ds, GROUP_SCHEMAS[group], group=group) == []


def test_rgb_oecf_matches_truth(cal):
    truth, response = cal["truth"], cal["oecf_rgb"]["response"]
    codes = response["code"].values
    for ch in "RGB":
        offset = float(truth["adc_offset"].sel(sensor=ch))
        f = response.sel(channel=ch).isel(camera=0).values
        true = np.interp(codes - offset, truth["code"].values, truth["oecf"].sel(sensor=ch).values)
        inside = (codes >= 40) & (codes <= 1015)
        error = np.abs(_scale(f[inside], true[inside]) * f[inside] / true[inside] - 1)
        assert np.median(error) < 0.005, ch
        assert error.max() < 0.05, ch


def test_spectral_oecf_matches_truth_at_the_low_end(cal):
    o, truth = cal["oecf_spectral"], cal["truth"]
    v, f = o["code"].values, o["response"].values
    assert o["response"].attrs["dark_subtracted"]
    true = np.interp(v, truth["code"].values, truth["oecf"].sel(sensor="mono").values)
    whole = (v >= 2) & (v <= 900)
    scaled = _scale(f[whole], true[whole]) * f
    low = (v >= 2) & (v <= 50)
    assert np.median(np.abs(scaled[low] / true[low] - 1)) < 0.05
    assert np.median(np.abs(scaled[whole] / true[whole] - 1)) < 0.05


def test_qe_and_camera_matrix_match_truth(cal):
    s, truth = cal["spectral"], cal["truth"]
    q, qt = s["quantum_efficiency"].values, truth["quantum_efficiency"].values
    assert np.median(np.abs(_scale(q, qt) * q / qt - 1)) < 0.06
    c = s["camera_matrix"].values
    ct = truth["camera_matrix"].sel(channel=s["channel"].values).values
    assert np.linalg.norm(_scale(c, ct) * c - ct) / np.linalg.norm(ct) < 0.25
    # per channel, RMS over wavelength relative to the channel's peak (one scale per channel):
    # lobes with the white reference as a patch (the second-difference fit: 0.085 in R)
    per_channel = (c * ct).sum(1) / (c * c).sum(1)
    error = np.sqrt(np.mean((per_channel[:, None] * c - ct) ** 2, axis=1)) / ct.max(1)
    assert np.all(c >= 0) and error[0] < 0.06 and error.max() < 0.1, error
    assert s.attrs["camera_matrix_method"] == "lobes" and s.attrs["white_patch"]
    assert len(s.attrs["ridge"]) == 3 and s["ridge_cv"].dims == ("ridge_candidate", "channel")
    # cross-validation (Fig. 4): RGB through C from the spectral capture
    assert float(s["relative_error"].mean()) < 0.05
    assert s.attrs["mean_relative_error"] == pytest.approx(float(s["relative_error"].mean()))


def test_hdr_and_bands_are_consistent_with_truth(cal):
    run = cal["run"]
    hdr = merge_hdr_node(run["raw/rgb"], cal["oecf_rgb"])
    assert validate_dataset(hdr, GROUP_SCHEMAS["hdr"], group="hdr") == []
    assert hdr["radiance"].dtype == np.float32 and "image" in hdr.coords
    truth = run["truth/spectra"]["radiance"].load()
    truth_rgb = xr.dot(run["truth/camera"]["camera_matrix"], truth, dim="wavelength")
    h = hdr["radiance"].transpose("image", "y", "x", "channel").values.astype(float)
    t = truth_rgb.transpose("image", "y", "x", "channel").sel(channel=["R", "G", "B"]).values
    ok = t > np.percentile(t, 5)
    assert np.median(np.abs(_scale(h[ok], t[ok]) * h[ok] / t[ok] - 1)) < 0.08

    registration = estimate_registration(run["raw/registration"])
    bands = calibrate_bands(
        run["raw/spectral"], cal["dark"], cal["oecf_spectral"], cal["spectral"], registration
    )
    assert bands["radiance"].chunks is not None  # lazy
    assert validate_dataset(bands, GROUP_SCHEMAS["bands"], group="bands") == []
    b = bands["radiance"].values.astype(float)
    assert (b < 0).sum() >= 0 and np.isfinite(b).all()
    tb = np.stack(
        [
            truth.sel(image=int(i), wavelength=float(w)).values
            for i, w in zip(bands["image"].values, bands["wavelength"].values, strict=True)
        ]
    )
    # same units as the truth (relative to the measured illuminant): scale close to 1
    assert _scale(b[:, 3:-3, 3:-3].ravel(), tb[:, 3:-3, 3:-3].ravel()) == pytest.approx(1, abs=0.1)
    np.testing.assert_allclose(bands["filter_size"].values, run["raw/spectral"]["filter_size"])


def test_missing_dark_frame_is_named(cal):
    dark = cal["dark"]
    t = float(cal["run"]["raw/white_reference"]["spectral_exposure_time"].values[0])
    without = dark.sel(exposure_time=[v for v in dark["exposure_time"].values if v != t])
    with pytest.raises(CalibrationError, match=r"dark:mean has no frame for exposure_time"):
        recover_spectral_oecf(cal["run"]["raw/white_reference"], without)


def test_white_reference_darker_than_noise_is_named(cal):
    white = cal["run"]["raw/white_reference"].copy()
    counts = white["spectral_counts"]
    white["spectral_counts"] = counts.where(
        counts.wavelength != 550.0, (cal["dark"]["mean"].isel(exposure_time=0).round().astype("uint16"))
    )
    with pytest.raises(
        CalibrationError, match=r"raw/white_reference:spectral_counts.*darker than the noise"
    ):
        calibrate_spectral(
            white, cal["run"]["raw/colour_checker"], cal["dark"], cal["oecf_rgb"], cal["oecf_spectral"]
        )
