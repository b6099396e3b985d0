"""Statistics of a metric map: known values, NaN ignored."""

import numpy as np
import xarray as xr

from spectralize.nodes.evaluation.statistics import (
    STATISTICS,
    map_statistics,
    nrmse_histogram,
    subset_statistics,
)


def test_map_statistics_known_values_ignore_nan():
    values = np.arange(1.0, 101.0).reshape(1, 10, 10)
    values[0, 0, 0] = np.nan  # 2..100 remain
    stats = map_statistics(xr.DataArray(values, dims=("image", "y", "x"), attrs={"units": "1"}))
    assert list(stats["statistic"].values) == list(STATISTICS)
    finite = np.arange(2.0, 101.0)
    np.testing.assert_allclose(
        stats.values[0],
        [finite.mean(), np.median(finite), np.quantile(finite, 0.95), np.quantile(finite, 0.99)],
    )
    all_nan = map_statistics(xr.DataArray(np.full((1, 2, 2), np.nan), dims=("image", "y", "x")))
    assert np.isnan(all_nan.values).all()


def test_nrmse_histogram_counts_finite_values_per_image():
    values = np.array([[[0.005, 0.015], [0.015, np.nan]], [[0.2, 0.025], [0.025, 0.025]]])
    nrmse = xr.DataArray(values, dims=("image", "y", "x"))
    edges = np.linspace(0.0, 0.03, 4)  # [0, 0.01), [0.01, 0.02), [0.02, 0.03]
    counts = nrmse_histogram(nrmse, edges)
    assert counts.dims == ("image", "nrmse_bin") and counts.dtype == np.int64
    assert counts.values.tolist() == [[1, 2, 0], [0, 0, 3]]  # NaN and 0.2 (above range) left out
    lazy = nrmse_histogram(nrmse.chunk({"image": 1, "y": 1}), edges)
    assert lazy.chunks is not None and lazy.values.tolist() == counts.values.tolist()


def test_subset_statistics_pool_the_pixels_of_each_subset():
    maps = {
        name: xr.DataArray(
            np.array([np.full((2, 2), 0.01), np.full((2, 2), 0.05)]), dims=("image", "y", "x")
        )
        for name in ("nrmse", "spectral_angle", "delta_e")
    }
    masks = {"all": np.array([True, True]), "first": np.array([True, False]), "none": np.zeros(2, bool)}
    out = subset_statistics(maps, masks, threshold=0.03)
    assert out["subset"].values.tolist() == ["all", "first", "none"]
    median = out["nrmse_subset_statistics"].sel(statistic="median").values
    np.testing.assert_allclose(median[:2], [0.03, 0.01])
    assert np.isnan(median[2])
    np.testing.assert_allclose(out["nrmse_subset_fraction_below"].values[:2], [0.5, 1.0])
    assert out["subset_pixel_count"].values.tolist() == [8, 4, 0]
