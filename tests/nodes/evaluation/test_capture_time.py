import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.evaluation.capture_time import (
    PAPER_FAST_TIME,
    PAPER_REFERENCE_TIME,
    capture_time,
    capture_time_from_run,
    plan_exposure,
    run_capture_time,
)
from spectralize.nodes.simulation.exposure_plan import exposure_plan, reference_exposure_plan
from spectralize.schemas import SchemaError

WAVELENGTH = np.arange(410.0, 721.0, 10.0)


def plan(times, *, sets=1, rgb=(), rgb_images=0) -> xr.Dataset:
    return xr.Dataset(
        {
            "exposure_time": ("wavelength", np.asarray(times, dtype=float), {"units": "s"}),
            "rgb_exposure_time": ("rgb_exposure", np.asarray(rgb, dtype=float), {"units": "s"}),
        },
        coords={"wavelength": WAVELENGTH[: len(times)]},
        attrs={"spectral_sets": sets, "rgb_images": rgb_images},
    )


def test_the_papers_numbers_give_about_thirty_times():
    result = capture_time(PAPER_FAST_TIME, PAPER_REFERENCE_TIME)
    assert float(result.speedup) == pytest.approx(226.212 / 7.463)
    assert 30.0 < float(result.speedup) < 30.5
    assert result.total_time.sel(capture="reference").item() == pytest.approx(226.212)
    assert "30.3x" in result.attrs["summary"]
    assert result.attrs["given_as_total"] == "reference,fast"


def test_plans_are_summed_per_band_set_and_rgb_series():
    fast = plan([0.1, 0.2, 0.3], sets=2, rgb=[0.01, 0.04], rgb_images=10)
    reference = plan([3.0, 5.0, 7.0])
    assert plan_exposure(fast) == pytest.approx((1.2, 0.5, 6))
    result = capture_time(fast, reference)
    np.testing.assert_allclose(result.spectral_time, [15.0, 1.2])
    np.testing.assert_allclose(result.rgb_time, [0.0, 0.5])
    np.testing.assert_allclose(result.total_time, [15.0, 1.7])
    assert result.band_shots.values.tolist() == [3, 6]
    assert float(result.speedup) == pytest.approx(15.0 / 1.7)
    assert result.total_time.attrs["units"] == "s"
    # RGB exposure given explicitly overrides the plan's; a reference that also shoots RGB
    explicit = capture_time(
        fast, reference, rgb_exposure_times=[1.0], rgb_images=2, reference_includes_rgb=True
    )
    np.testing.assert_allclose(explicit.total_time, [17.0, 3.2])


def test_exposure_plans_of_the_simulator_are_accounted_like_their_own_totals():
    q = np.linspace(0.2, 1.0, WAVELENGTH.size)
    light = np.linspace(1.0, 0.3, WAVELENGTH.size)
    fast = exposure_plan(
        q,
        light,
        wavelength=WAVELENGTH,
        t0=0.01,
        s0=3.0,
        rgb_exposure_times=[0.01, 0.04, 0.16, 0.64],
        rgb_images=10,
    )
    reference = reference_exposure_plan(q, light, wavelength=WAVELENGTH)
    result = capture_time(fast, reference)
    assert result.total_time.sel(capture="fast").item() == pytest.approx(float(fast.total_capture_time))
    assert result.total_time.sel(capture="reference").item() == pytest.approx(
        float(reference.spectral_capture_time)
    )
    assert float(result.speedup) > 1.0


def test_accuracy_is_shown_next_to_the_speed_up():
    evaluation = xr.Dataset(
        {
            "nrmse_subset_statistics": (("subset", "statistic"), [[0.01, 0.008, 0.03, 0.05]]),
            "nrmse_subset_fraction_below": ("subset", [0.96]),
        },
        coords={"subset": ["all"], "statistic": ["mean", "median", "p95", "p99"]},
    )
    result = capture_time(PAPER_FAST_TIME, evaluation=evaluation)
    assert float(result.nrmse_median) == 0.008 and float(result.nrmse_p95) == 0.03
    assert float(result.nrmse_fraction_below) == 0.96
    assert "nRMSE median 0.0080" in result.attrs["summary"]
    with pytest.raises(SchemaError, match="nrmse_subset_statistics"):
        capture_time(PAPER_FAST_TIME, evaluation=xr.Dataset())


def test_capture_time_from_run_sums_band_shots_and_rgb_series():
    raw_spectral = xr.Dataset(
        coords={
            "exposure_time": ("shot", [0.1, 0.2, 0.3]),
            "wavelength": ("shot", [500.0, 410.0, 500.0]),
        }
    )
    raw_rgb = xr.Dataset(coords={"exposure_time": (("image", "exposure"), [[0.01, 0.02], [0.03, 0.04]])})
    measured = capture_time_from_run(raw_spectral, raw_rgb)
    assert measured.wavelength.values.tolist() == [410.0, 500.0]
    np.testing.assert_allclose(measured.exposure_time, [0.2, 0.4])
    result = capture_time(measured)
    assert result.sel(capture="fast").spectral_time.item() == pytest.approx(0.6)
    assert result.sel(capture="fast").rgb_time.item() == pytest.approx(0.1)
    assert result.sel(capture="fast").band_shots.item() == 3
    assert "spectral 0.600 s + RGB 0.100 s" in result.attrs["summary"]
    assert plan_exposure(capture_time_from_run(raw_spectral))[1] == 0.0
    with pytest.raises(SchemaError, match="raw/rgb:exposure_time") as error:
        capture_time_from_run(raw_spectral.drop_vars("wavelength"), raw_rgb=raw_spectral)
    assert len(error.value.problems) == 2  # both groups reported at once


def test_run_capture_time_takes_one_reference_set_per_image_from_the_plan():
    raw_spectral = xr.Dataset(
        coords={"exposure_time": ("shot", [0.5, 0.5]), "wavelength": ("shot", [410.0, 420.0])}
    )
    raw_rgb = xr.Dataset(coords={"exposure_time": (("image", "exposure"), np.full((4, 2), 0.25))})
    exposure_plan = xr.Dataset({"reference_capture_time": ((), 30.0, {"units": "s"})})
    result = run_capture_time(raw_spectral, raw_rgb, exposure_plan)
    np.testing.assert_allclose(result.total_time, [4 * 30.0, 1.0 + 2.0])
    assert float(result.speedup) == pytest.approx(40.0)
    assert "4 image(s) x 30.000 s" in result.attrs["reference_note"]
    paper = run_capture_time(raw_spectral, raw_rgb)
    assert float(paper.speedup) == pytest.approx(PAPER_REFERENCE_TIME / 3.0)
    assert "the paper's" in paper.attrs["summary"]


def test_invalid_captures_are_rejected_with_what_was_found():
    with pytest.raises(SchemaError, match="exposure_time"):
        capture_time(xr.Dataset({"t": ("wavelength", [1.0])}))
    with pytest.raises(ValueError, match="exposure times >= 0"):
        capture_time(plan([0.1, -0.2]))
    with pytest.raises(ValueError, match="no speed-up"):
        capture_time(0.0)
    with pytest.raises(ValueError, match="total exposure >= 0"):
        capture_time(1.0, reference=float("nan"))
