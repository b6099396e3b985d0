"""The evaluate node's function: known answers per image and subset, lazy equals eager, every mismatch at once, a run-store round trip."""

import numpy as np
import pytest
import xarray as xr
from support.checker import (
    checker_truth,
    cube,
    raw_spectral_for,
    shots_for,
)

from spectralize.nodes.evaluation.accuracy import evaluate
from spectralize.nodes.evaluation.declarations import EVALUATE
from spectralize.nodes.evaluation.pixel_metrics import normalised_rmse
from spectralize.nodes.evaluation.statistics import STATISTICS
from spectralize.schemas import SchemaError, validate_dataset
from spectralize.schemas.run import EVALUATION, SPECTRA_PRECISION
from spectralize.store import RunStore
from spectralize.store.precision import round_mantissa


def test_evaluate_known_answers_per_image_and_per_subset():
    truth = checker_truth(n_image=3)
    means = truth.radiance.astype(np.float64).mean(("wavelength", "y", "x")).values
    offsets = np.array([0.015, 0.055, 0.015]) * means  # nRMSE 0.015, 0.055, 0.015 everywhere
    spectra = truth.copy(deep=True)
    spectra["radiance"] = truth.radiance + xr.DataArray(offsets.astype(np.float32), dims="image")
    ev = evaluate(
        spectra, truth, shots=shots_for([0, 2, 2]), histogram_bins=10, histogram_max=0.1
    ).compute()

    np.testing.assert_allclose(
        ev.nrmse_statistics.sel(statistic="median"), [0.015, 0.055, 0.015], rtol=1e-3
    )
    np.testing.assert_allclose(ev.nrmse_fraction_below, [1.0, 0.0, 1.0])
    np.testing.assert_allclose(ev.truth_mean, means)
    assert ev.has_band_shots.values.tolist() == [True, False, True]
    assert list(ev.subset.values) == ["all", "with_band_shots", "without_band_shots"]
    subset = ev.nrmse_subset_statistics.sel(statistic="median")
    np.testing.assert_allclose(
        subset.sel(subset=["with_band_shots", "without_band_shots"]), [0.015, 0.055], rtol=1e-3
    )
    pixels = truth.sizes["y"] * truth.sizes["x"]
    assert ev.subset_pixel_count.values.tolist() == [3 * pixels, 2 * pixels, pixels]
    np.testing.assert_allclose(ev.nrmse_subset_fraction_below, [2 / 3, 1.0, 0.0])
    # histograms: image 0 and 2 in bin [0.01, 0.02), image 1 in [0.05, 0.06)
    assert ev.nrmse_histogram.sum("nrmse_bin").values.tolist() == [pixels] * 3
    assert int(ev.nrmse_histogram[1, 5]) == pixels and int(ev.nrmse_histogram[0, 1]) == pixels
    assert ev.nrmse_above_range.values.tolist() == [0, 0, 0]
    np.testing.assert_allclose(ev.nrmse_bin_lower[:2], [0.0, 0.01])
    # per-image coords are kept, with the attrs the report needs
    assert ev.phi_o.values.tolist() == [0.0, 15.0, 30.0]
    assert ev.nrmse.attrs["units"] == "1" and ev.spectral_angle.attrs["units"] == "degree"
    assert validate_dataset(ev, EVALUATION) == []


def test_evaluate_without_shots_summarises_all_images_only():
    truth = checker_truth(n_image=2)
    ev = evaluate(truth, truth)
    assert list(ev.subset.values) == ["all"] and "has_band_shots" not in ev
    assert float(ev.nrmse.max()) == 0.0
    assert ev.attrs["band_shots_known"] == 0


def test_evaluate_is_lazy_over_images_and_equals_the_eager_result():
    truth = checker_truth(n_image=3)
    spectra = truth.copy(deep=True)
    spectra["radiance"] = truth.radiance * np.float32(1.02) + np.float32(0.001)
    eager = evaluate(spectra, truth, shots=shots_for([1])).compute()
    lazy = evaluate(
        spectra.chunk({"image": 1, "y": 4, "x": 9}),
        truth.chunk({"image": 1, "y": 4, "x": 9}),
        shots=shots_for([1]),
    )
    assert lazy.nrmse.chunks is not None and lazy.nrmse_statistics.chunks is not None
    assert lazy.sample_truth.chunks[0] == (1, 1, 1)  # one image per task
    xr.testing.assert_allclose(lazy.compute(), eager)


def test_evaluate_counts_nan_pixels_and_ignores_them_in_statistics():
    truth = checker_truth(n_image=1)
    values = truth.radiance.values.copy()
    values[0, 3, 2, 2] = np.nan
    ev = evaluate(cube(values * 1.01), truth).compute()
    assert int(ev.invalid_count[0]) == 1
    assert np.isfinite(ev.nrmse_statistics.values).all()
    assert int(ev.subset_pixel_count[0]) == truth.sizes["y"] * truth.sizes["x"] - 1


def test_evaluate_reports_every_mismatch_at_once():
    truth = checker_truth(n_image=2)
    other = cube(np.ones((3, 32, 2, 2)))
    with pytest.raises(SchemaError, match="spectra:radiance") as error:
        evaluate(other, truth)
    assert "image" in str(error.value)
    # what one group's schema says is checked by the engine before the node runs (below);
    # the public metric functions, which also take bare arrays, check it themselves
    wrong_dims = truth.radiance.transpose("image", "y", "x", "wavelength").to_dataset()
    with pytest.raises(SchemaError) as error:
        normalised_rmse(wrong_dims, xr.Dataset({"counts": truth.radiance}))
    messages = [str(p) for p in error.value.problems]
    assert any("spectra:radiance" in m and "dims" in m for m in messages)
    assert any("truth:radiance" in m and "counts" in m for m in messages)
    with pytest.raises(SchemaError) as error:
        EVALUATE(
            {
                "spectra": wrong_dims,
                "truth": xr.Dataset({"counts": truth.radiance}),
                "shots": raw_spectral_for([0]),
            }
        )
    messages = [str(p) for p in error.value.problems]
    assert any("spectra" in m and "radiance" in m and "dims" in m for m in messages)
    assert any("truth" in m and "radiance" in m for m in messages)
    shifted = truth.assign_coords(wavelength=truth.wavelength + 5.0)
    with pytest.raises(SchemaError, match="wavelength"):
        evaluate(shifted, truth)
    labelled = truth.assign_coords(image=[3, 4])
    with pytest.raises(SchemaError, match="spectra:image"):
        evaluate(labelled.assign_coords(image=[4, 5]), labelled)
    # a cube written set by set lists the same images in another order: aligned by label
    swapped = labelled.isel(image=[1, 0])
    out = evaluate(swapped, labelled)
    assert out["image"].values.tolist() == [4, 3]
    assert float(out["nrmse"].max()) == 0.0
    # options are checked against the constraints of evaluate's signature, by the node
    with pytest.raises(ValueError, match="threshold"):
        EVALUATE.parse_parameters({"threshold": 0.0})


@pytest.mark.filterwarnings("ignore::zarr.errors.UnstableSpecificationWarning")
def test_evaluation_group_round_trips_through_a_run_store(tmp_path):
    truth = checker_truth(n_image=3)
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("truth/spectra", truth, fingerprint="truth", chunks={"image": 1, "y": 5, "x": 7})
    spectra = truth.copy()
    spectra["radiance"] = truth.radiance * np.float32(1.05)
    store.write("spectra", spectra, fingerprint="spectra", chunks={"image": 2, "y": 6, "x": 6})
    lazy = evaluate(store.read("spectra"), store.read("truth/spectra"), shots=shots_for([0]))
    assert lazy.nrmse.chunks is not None
    store.write("evaluation", lazy, schema=EVALUATION, fingerprint="test")
    back = store.read("evaluation")
    assert validate_dataset(back, EVALUATION) == []
    # of the spectra the store keeps (their precision: 10 mantissa bits)
    kept = round_mantissa(spectra.radiance.values, SPECTRA_PRECISION.keepbits)
    expected = evaluate(
        spectra.assign(radiance=spectra.radiance.copy(data=kept)), truth, shots=shots_for([0])
    )
    # a read adds pixel coordinates x, y (0, 1, ...) for xarray selection
    assert back.x.values.tolist() == list(range(back.sizes["x"]))
    assert back.y.values.tolist() == list(range(back.sizes["y"]))
    xr.testing.assert_allclose(
        back.drop_vars(["y", "x"]).compute().drop_attrs(), expected.compute().drop_attrs()
    )
    assert back.has_band_shots.values.tolist() == [True, False, False]
    assert list(back.statistic.values) == list(STATISTICS)
    assert back.attrs["spectra_fingerprint"] == "spectra"
