"""Tests of spectralize.nodes.calibration.oecf.response: applying and combining responses."""

from __future__ import annotations

import dask.array as da
import numpy as np
import xarray as xr

from spectralize.nodes.calibration import oecf


def test_combined_response_covers_the_whole_range(exposure_series, as_dataarray, low_snr_series) -> None:
    series, dark, truth = low_snr_series(side=160)
    low = oecf.recover_oecf_low_snr(series, dark, filter_size=20)
    counts, _ = exposure_series("s_curve", bit_depth=10, pixels=20_000)
    full = oecf.recover_oecf(as_dataarray(counts, 10), black_level=25)
    combined = oecf.combine_responses(low, full)["response"]
    code = combined["code"].values
    assert combined.attrs["method"] == "combined" and combined.attrs["dark_subtracted"]
    assert code[0] < 1 and code[-1] > 1000
    assert np.all(np.isfinite(combined.values)) and np.all(np.diff(code) > 0)
    f_true = truth.response(np.clip(code, 0, None) / 1023)
    f_true = f_true / truth.response((511.5 + 0.5 - 16) / 1023)
    for lo, hi, tolerance in [(1.5, 50, 0.04), (50, 1000, 0.02)]:
        keep = (code >= lo) & (code <= hi)
        assert np.median(np.abs(combined.values[keep] / f_true[keep] - 1)) < tolerance / 2
        assert np.max(np.abs(combined.values[keep] / f_true[keep] - 1)) < tolerance


# -- apply_response ---------------------------------------------------------------------------------
def test_apply_response_interpolates_matches_channels_and_stays_lazy() -> None:
    table = xr.DataArray(
        np.stack([np.arange(4.0), 2 * np.arange(4.0)]),
        dims=("channel", "code"),
        coords={"channel": ["R", "G"], "code": np.arange(4)},
    )
    values = xr.DataArray(
        np.array([[0.5, 3.5, -1.0], [1.0, 2.0, 5.0]]).T,
        dims=("pixel", "channel"),
        coords={"channel": ["R", "G"]},
    )
    out = oecf.apply_response(values, table)
    np.testing.assert_allclose(out.sel(channel="R").values, [0.5, 3.5, -1.0])
    np.testing.assert_allclose(out.sel(channel="G").values, [2.0, 4.0, 10.0])
    lazy = oecf.apply_response(values.chunk({"pixel": 1}), table)
    assert isinstance(lazy.data, da.Array)
    np.testing.assert_allclose(lazy.transpose(*out.dims).values, out.values)
