"""Several methods side by side."""

import xarray as xr
from support.checker import (
    checker_truth,
    shots_for,
)

from spectralize.nodes.evaluation.comparison import METHOD_DIM, compare_methods


def test_compare_methods_ranks_a_perfect_and_a_biased_method():
    truth = checker_truth(n_image=2)
    table = compare_methods(
        {"perfect": truth.radiance, "biased": truth.radiance * 1.1}, truth, shots=shots_for([1])
    ).compute()
    assert table[METHOD_DIM].values.tolist() == ["perfect", "biased"]
    median = table.nrmse_subset_statistics.sel(subset="all", statistic="median")
    assert float(median.sel({METHOD_DIM: "perfect"})) == 0.0
    assert float(median.sel({METHOD_DIM: "biased"})) > 0.05
    stacked = xr.concat([truth.radiance, truth.radiance * 1.1], dim=METHOD_DIM)
    from_stack = compare_methods(xr.Dataset({"radiance": stacked}), truth).compute()
    assert from_stack.sizes[METHOD_DIM] == 2
