"""Tests of the exposure plan (paper eq. 2 and 3)."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st

from spectralize.nodes.simulation.camera_model import ShapeMismatchError, SimulationParameterError
from spectralize.nodes.simulation.exposure_plan import (
    exposure_plan,
    reference_exposure_plan,
    t0_for_total_time,
)

WL = np.array([450.0, 550.0, 650.0])


def _da(values, wl=WL):
    return xr.DataArray(np.asarray(values, float), dims=("wavelength",), coords={"wavelength": wl})


def test_eq2_eq3_against_hand_computed_values():
    # Q L = [0.5, 0.5, 0.25]; t0 = 0.1, omega = 0.8, s0 = 2
    plan = exposure_plan(_da([0.5, 1.0, 0.25]), _da([1.0, 0.5, 1.0]), t0=0.1, s0=2.0)
    # t = (0.1 / 0.5) ** 0.8 = 0.2 ** 0.8, (0.1 / 0.25) ** 0.8 = 0.4 ** 0.8
    np.testing.assert_allclose(plan.exposure_time, [0.275946, 0.275946, 0.480450], rtol=1e-5)
    # s = 2 / (0.5 * 0.275946) = 14.4956, 2 / (0.25 * 0.480450) = 16.6510
    np.testing.assert_allclose(plan.filter_size, [14.49560, 14.49560, 16.65106], rtol=1e-5)
    np.testing.assert_allclose(plan.filter_sigma, plan.filter_size / 5)
    np.testing.assert_allclose(plan.relative_exposure, [0.137973, 0.137973, 0.120112], rtol=1e-5)
    assert plan.exposure_time.attrs["units"] == "s"
    assert plan.filter_size.attrs["units"] == "px"
    assert plan.wavelength.attrs["units"] == "nm"
    assert plan.attrs["omega"] == 0.8


def test_capture_time_summary():
    plan = exposure_plan(
        _da([0.5, 1.0, 0.25]),
        _da([1.0, 0.5, 1.0]),
        t0=0.1,
        s0=2.0,
        rgb_exposure_times=[0.001, 0.004, 0.016, 0.064],
        rgb_images=10,
        spectral_sets=2,
    )
    spectral = 2 * (2 * 0.275946 + 0.480450)
    assert float(plan.spectral_capture_time) == pytest.approx(spectral, rel=1e-5)
    assert float(plan.rgb_capture_time) == pytest.approx(10 * 0.085)
    assert float(plan.total_capture_time) == pytest.approx(spectral + 0.85, rel=1e-5)
    assert "RGB 0.850 s" in plan.attrs["cost"]
    assert plan.rgb_exposure_time.sizes["rgb_exposure"] == 4


def test_plain_arrays_need_wavelength():
    plan = exposure_plan([0.5, 1.0], [1.0, 1.0], wavelength=[500, 510], t0=0.1, s0=1.0)
    assert plan.sizes["wavelength"] == 2
    with pytest.raises(SimulationParameterError, match="wavelength"):
        exposure_plan([0.5, 1.0], [1.0, 1.0], t0=0.1, s0=1.0)


def test_omega_one_gives_equal_signal_and_reference_plan_is_long():
    q, ell = _da([0.05, 1.0, 0.3]), _da([0.2, 1.0, 0.6])
    ref = reference_exposure_plan(q, ell, target_exposure=0.8)
    np.testing.assert_allclose(ref.relative_exposure, 0.8)
    np.testing.assert_allclose(ref.filter_size, 0.0)
    assert ref.attrs["kind"] == "reference"
    t0 = t0_for_total_time(q, ell, total_time=1.0)
    noisy = exposure_plan(q, ell, t0=t0, s0=1.0)
    assert float(noisy.spectral_capture_time) == pytest.approx(1.0)
    assert float(ref.spectral_capture_time) > 10 * float(noisy.spectral_capture_time)


@settings(max_examples=40, deadline=None)
@given(
    ql=st.lists(st.floats(1e-4, 1e3), min_size=2, max_size=6),
    omega=st.floats(0.1, 1.0),
    t0=st.floats(1e-3, 10.0),
)
def test_weaker_bands_get_longer_exposures_and_larger_filters(ql, omega, t0):
    ql = np.asarray(ql)
    wl = 400.0 + 10 * np.arange(ql.size)
    plan = exposure_plan(ql, np.ones_like(ql), wavelength=wl, t0=t0, s0=3.0, omega=omega)
    order = np.argsort(ql)
    t = plan.exposure_time.values[order]
    s = plan.filter_size.values[order]
    assert np.all(np.diff(t) <= 1e-12 * t[:-1])  # non-increasing in Q L
    assert np.all(np.diff(s) <= 1e-9 * s[:-1])
    # eq. 3 with eq. 2: Q L t = t0 ** omega (Q L) ** (1 - omega)
    np.testing.assert_allclose(plan.relative_exposure, t0**omega * ql ** (1 - omega), rtol=1e-9)


@pytest.mark.parametrize("bad", [[0.5, 0.0, 1.0], [0.5, -1.0, 1.0], [0.5, np.nan, 1.0]])
def test_non_positive_quantum_efficiency_is_named(bad):
    with pytest.raises(SimulationParameterError, match="quantum_efficiency"):
        exposure_plan(_da(bad), _da([1.0, 1.0, 1.0]), t0=0.1, s0=1.0)
    with pytest.raises(ValueError, match="illuminant"):
        exposure_plan(_da([1.0, 1.0, 1.0]), _da(bad), t0=0.1, s0=1.0)


def test_bad_constants_and_axes():
    q, ell = _da([0.5, 1.0, 0.25]), _da([1.0, 0.5, 1.0])
    with pytest.raises(SimulationParameterError, match="t0"):
        exposure_plan(q, ell, t0=0.0, s0=1.0)
    with pytest.raises(SimulationParameterError, match="omega"):
        exposure_plan(q, ell, t0=0.1, s0=1.0, omega=1.5)
    with pytest.raises(SimulationParameterError, match="rgb_exposure_times"):
        exposure_plan(q, ell, t0=0.1, s0=1.0, rgb_exposure_times=[0.01, -0.01])
    with pytest.raises(SimulationParameterError, match="strictly increasing"):
        exposure_plan(_da([1, 1, 1], WL[::-1]), _da([1, 1, 1], WL[::-1]), t0=0.1, s0=1.0)
    with pytest.raises(ShapeMismatchError, match="wavelength"):
        exposure_plan(q, _da([1.0, 1.0, 1.0], WL + 5), t0=0.1, s0=1.0)
    with pytest.raises(ShapeMismatchError, match="illuminant"):
        exposure_plan([1.0, 1.0, 1.0], [1.0, 1.0], wavelength=WL, t0=0.1, s0=1.0)
    with pytest.raises(SimulationParameterError, match="target_exposure"):
        reference_exposure_plan(q, ell, target_exposure=1.5)
