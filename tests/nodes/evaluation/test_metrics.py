import colour
import numpy as np
import pytest
import xarray as xr
from support.cubes import cube_dataset

from spectralize.engine import Step, check_graph
from spectralize.nodes.evaluation.declarations import EVALUATE
from spectralize.nodes.evaluation.metrics import (
    METHOD_DIM,
    STATISTICS,
    band_shot_images,
    colour_difference,
    compare_methods,
    evaluate,
    map_statistics,
    normalised_rmse,
    representative_spectra,
    spectral_angle,
)
from spectralize.schemas import ParameterError, SchemaError, validate_dataset
from spectralize.schemas.run import EVALUATION
from spectralize.store import RunStore

SHAPE = colour.SpectralShape(410, 720, 10)  # the paper's 32 bands
WAVELENGTH = SHAPE.wavelengths
OBSERVER = "CIE 1931 2 Degree Standard Observer"


def _cube(values):
    return cube_dataset(values, first_led=10)


def checker_reflectance() -> np.ndarray:
    """(24, 32) reflectances of the ColorChecker (N Ohta) on the paper's bands."""
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    return np.array([sds[name].copy().align(SHAPE).values for name in sds])


def checker_truth(n_image: int = 3, block: int = 3) -> xr.Dataset:
    """The 24 patches under D65 (max 1) as a 4 x 6 grid of ``block``-pixel squares."""
    light = colour.SDS_ILLUMINANTS["D65"].copy().align(SHAPE).values
    grid = (checker_reflectance() * light / light.max()).reshape(4, 6, -1).transpose(2, 0, 1)
    cube = np.repeat(np.repeat(grid, block, 1), block, 2)
    return _cube(np.stack([cube * (1.0 + 0.5 * i) for i in range(n_image)]))


def shots_for(images) -> xr.Dataset:
    n = len(images)
    return xr.Dataset(
        coords={
            "image": ("shot", np.asarray(images, dtype=np.int64)),
            "wavelength": ("shot", np.full(n, 550.0)),
        }
    )


def raw_spectral_for(images) -> xr.Dataset:
    """A ``raw/spectral`` group (what the node's input check asks for) pairing shots with images."""
    n = len(images)
    return xr.Dataset(
        {"counts": (("shot", "y", "x"), np.zeros((n, 2, 2), np.uint16), {"units": "DN"})},
        coords={
            "wavelength": ("shot", np.full(n, 550.0), {"units": "nm"}),
            "exposure_time": ("shot", np.full(n, 0.05), {"units": "s"}),
            "image": ("shot", np.asarray(images, dtype=np.int64)),
            "rotation": ("shot", np.zeros(n, int)),
            "led": ("shot", np.zeros(n, int)),
        },
        attrs={"bit_depth": 12},
    )


# -- nRMSE ---------------------------------------------------------------------------------
def test_nrmse_of_a_constant_offset_is_offset_over_the_image_mean():
    truth = checker_truth()
    spectra = truth.copy(deep=True)
    spectra["radiance"] = truth.radiance + np.float32(0.01)
    nrmse = normalised_rmse(spectra, truth)
    assert nrmse.dims == ("image", "y", "x") and nrmse.dtype == np.float32
    assert nrmse.attrs["units"] == "1"
    means = truth.radiance.astype(np.float64).mean(("wavelength", "y", "x")).values
    for image in range(3):
        np.testing.assert_allclose(nrmse[image].values, 0.01 / means[image], rtol=1e-4)
    # the normaliser is per image: image 2 is twice as bright as image 0
    assert nrmse[2].values.mean() == pytest.approx(nrmse[0].values.mean() / 2, rel=1e-4)


def test_nrmse_is_rms_over_wavelength_of_a_relative_error():
    truth = _cube(np.ones((1, 32, 2, 2)))
    error = np.zeros((1, 32, 2, 2))
    error[0, :16, 0, 0] = 0.2  # half the bands off by 0.2 -> rmse sqrt(0.02) = 0.1414
    error[0, ::2, 1, 1] = -0.4  # every second band off by -0.4 -> rmse sqrt(0.08)
    spectra = _cube(1.0 + error)
    nrmse = normalised_rmse(spectra, truth).values[0]
    np.testing.assert_allclose(nrmse, [[np.sqrt(0.02), 0.0], [0.0, np.sqrt(0.08)]], rtol=1e-5)


def test_nrmse_is_nan_for_nan_pixels_and_for_a_black_truth_image():
    values = np.ones((2, 32, 2, 2))
    values[1] = 0.0
    truth = _cube(values)
    spectra_values = values.copy()
    spectra_values[0, 5, 1, 0] = np.nan
    nrmse = normalised_rmse(_cube(spectra_values), truth).values
    assert np.isnan(nrmse[0, 1, 0]) and np.isfinite(nrmse[0, 0, 0])
    assert np.isnan(nrmse[1]).all()


# -- spectral angle ------------------------------------------------------------------------
def test_spectral_angle_known_answers():
    truth = np.zeros((1, 32, 1, 4))
    spectra = np.zeros((1, 32, 1, 4))
    truth[0, 0, 0, :] = 1.0
    spectra[0, 0, 0, 0] = 3.0  # same direction: 0 degree
    spectra[0, :2, 0, 1] = 1.0  # (1, 1) vs (1, 0): 45 degree
    spectra[0, 1, 0, 2] = 2.0  # orthogonal: 90 degree
    # pixel 3: zero spectrum -> undefined
    angle = spectral_angle(_cube(spectra), _cube(truth))
    assert angle.attrs["units"] == "degree"
    values = angle.values[0, 0]
    np.testing.assert_allclose(values[:3], [0.0, 45.0, 90.0], atol=1e-4)
    assert np.isnan(values[3])


def test_spectral_angle_is_accurate_for_tiny_angles_and_scale_invariant():
    truth = checker_truth(n_image=1)
    angle = spectral_angle(truth.radiance * 7.0, truth)
    assert float(np.nanmax(angle.values)) < 1e-3
    t = np.zeros((1, 32, 1, 1))
    s = np.zeros((1, 32, 1, 1))
    t[0, 0] = 1.0
    s[0, 0], s[0, 1] = 1.0, 1e-3  # atan(1e-3) = 0.0573 degree
    small = spectral_angle(_cube(s), _cube(t)).values.item()
    assert small == pytest.approx(np.degrees(np.arctan(1e-3)), rel=1e-3)


# -- CIEDE2000 -----------------------------------------------------------------------------
@pytest.mark.filterwarnings("ignore::colour.utilities.ColourRuntimeWarning")
def test_colour_difference_matches_colour_science_for_two_patches():
    reflectance = checker_reflectance()
    dark_skin, light_skin = reflectance[0], reflectance[1]
    truth = _cube(np.broadcast_to(dark_skin[None, :, None, None], (1, 32, 2, 2)))
    spectra = _cube(np.broadcast_to(light_skin[None, :, None, None], (1, 32, 2, 2)))
    delta = colour_difference(spectra, truth, illuminant="D65")
    assert delta.dims == ("image", "y", "x") and delta.attrs["illuminant"] == "D65"

    cmfs = colour.MSDS_CMFS[OBSERVER]
    d65 = colour.SDS_ILLUMINANTS["D65"]

    def xyz(values):
        return (
            colour.msds_to_XYZ(values, cmfs=cmfs, illuminant=d65, method="Integration", shape=SHAPE)
            / 100
        )

    white = colour.XYZ_to_xy(xyz(np.ones(32)))  # the perfect reflector on the same bands

    def lab(values):
        return colour.XYZ_to_Lab(xyz(values), white)

    expected = colour.delta_E(lab(light_skin), lab(dark_skin), method="CIE 2000")
    np.testing.assert_allclose(delta.values, expected, rtol=1e-5)
    assert 10 < expected < 40  # a big, visible difference
    # and close to colour-science's spectral-distribution path (1 nm interpolation)
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    lab_sd = [
        colour.XYZ_to_Lab(
            colour.sd_to_XYZ(sds[n], cmfs=cmfs, illuminant=d65, method="Integration") / 100,
            colour.CCS_ILLUMINANTS[OBSERVER]["D65"],
        )
        for n in ("light skin", "dark skin")
    ]
    assert float(delta.values[0, 0, 0]) == pytest.approx(
        float(colour.delta_E(*lab_sd, method="CIE 2000")), abs=0.5
    )


def test_colour_difference_is_zero_for_identical_spectra_and_depends_on_illuminant():
    truth = checker_truth(n_image=1)
    assert float(np.abs(colour_difference(truth, truth).values).max()) < 1e-6
    brighter = truth.radiance * 1.1
    under_d65 = colour_difference(brighter, truth, illuminant="D65").values
    under_a = colour_difference(brighter, truth, illuminant="A").values
    assert under_d65.min() > 0
    assert not np.allclose(under_d65, under_a)
    with pytest.raises(ValueError, match="not a colour-science illuminant"):
        colour_difference(truth, truth, illuminant="D-nonsense")


# -- statistics ----------------------------------------------------------------------------
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


def test_band_shot_images():
    has = band_shot_images(shots_for([0, 0, 2]), 4)
    assert has.dims == ("image",) and has.values.tolist() == [True, False, True, False]
    with pytest.raises(SchemaError, match="shots:image"):
        band_shot_images(xr.Dataset(coords={"wavelength": ("shot", [500.0])}), 4)


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


def test_representative_spectra_are_picked_at_low_and_high_error():
    truth = checker_truth(n_image=2)
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(truth.radiance.shape).astype(np.float32)
    spectra = truth.copy(deep=True)
    spectra["radiance"] = truth.radiance * (1 + 0.03 * noise)
    nrmse = normalised_rmse(spectra, truth)
    picks = representative_spectra(nrmse, spectra, truth, quantiles=(0.0, 0.5, 1.0)).compute()
    for image in range(2):
        errors = nrmse[image].values
        y, x = int(picks.sample_y[image, 2]), int(picks.sample_x[image, 2])
        assert errors[y, x] == errors.max()  # worst pixel
        y0, x0 = int(picks.sample_y[image, 0]), int(picks.sample_x[image, 0])
        assert errors[y0, x0] == errors.min()  # best pixel
        np.testing.assert_array_equal(picks.sample_truth[image, 2], truth.radiance[image, :, y, x])
        np.testing.assert_array_equal(
            picks.sample_reconstruction[image, 2], spectra.radiance[image, :, y, x]
        )
        assert float(picks.sample_nrmse[image, 1]) == pytest.approx(
            float(np.quantile(errors, 0.5)), abs=float(np.ptp(errors)) / 20
        )
    assert picks.sample_quantile.values.tolist() == [0.0, 0.5, 1.0]
    with pytest.raises(ValueError, match="ascending"):
        representative_spectra(nrmse, spectra, truth, quantiles=(0.9, 0.1))


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
    ev = evaluate(_cube(values * 1.01), truth).compute()
    assert int(ev.invalid_count[0]) == 1
    assert np.isfinite(ev.nrmse_statistics.values).all()
    assert int(ev.subset_pixel_count[0]) == truth.sizes["y"] * truth.sizes["x"] - 1


def test_evaluate_reports_every_mismatch_at_once():
    truth = checker_truth(n_image=2)
    other = _cube(np.ones((3, 32, 2, 2)))
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
    expected = evaluate(spectra, truth, shots=shots_for([0]))
    # a read adds pixel coordinates x, y (0, 1, ...) for xarray selection
    assert back.x.values.tolist() == list(range(back.sizes["x"]))
    assert back.y.values.tolist() == list(range(back.sizes["y"]))
    xr.testing.assert_allclose(
        back.drop_vars(["y", "x"]).compute().drop_attrs(), expected.compute().drop_attrs()
    )
    assert back.has_band_shots.values.tolist() == [True, False, False]
    assert list(back.statistic.values) == list(STATISTICS)
    assert back.attrs["spectra_fingerprint"] == "spectra"


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


def test_node_declaration_runs_and_validates_parameters():
    truth = checker_truth(n_image=2)
    result = EVALUATE(
        {"spectra": truth, "truth": truth, "shots": raw_spectral_for([0])},
        {"threshold": 0.02, "sample_quantiles": [0.5, 1.0]},
    )
    assert set(result) == {"evaluation"}
    assert result["evaluation"].sizes["sample"] == 2
    assert result["evaluation"].attrs["threshold"] == 0.02
    assert EVALUATE.inputs == {"spectra": "spectra", "truth": "truth/spectra", "shots": "raw/spectral"}
    with pytest.raises(ParameterError, match="illuminant"):
        EVALUATE.parse_parameters({"illuminant": "D-nonsense"})
    with pytest.raises(ParameterError, match="unknown parameter"):
        EVALUATE.parse_parameters({"colour": 1})
    with pytest.raises(ParameterError, match="ascending"):
        EVALUATE.parse_parameters({"sample_quantiles": [0.9, 0.1]})
    assert "D65" in EVALUATE.parameter_choices()["illuminant"]
    assert "E" in EVALUATE.parameter_choices()["illuminant"]
    assert set(EVALUATE.parameters.model_fields) == {
        "illuminant",
        "threshold",
        "histogram_bins",
        "histogram_max",
        "sample_quantiles",
    }
    planned = check_graph(
        [Step("evaluate")],
        nodes={"evaluate": EVALUATE},
        available={
            "spectra": "spectra",
            "truth/spectra": "truth/spectra",
            "raw/spectral": "raw/spectral",
        },
    )
    assert [p.outputs for p in planned] == [{"evaluation": "evaluation"}]
