"""Tests of the evaluation figures (paper Figures 5-8): data in, matplotlib Figure out."""

import colour
import numpy as np
import pytest
import xarray as xr
from matplotlib.figure import Figure
from support.cubes import cube_dataset

from spectralize.nodes.evaluation.accuracy import evaluate
from spectralize.nodes.evaluation.capture_time import capture_time
from spectralize.nodes.evaluation.colorimetry import render_srgb
from spectralize.nodes.evaluation.figures import (
    ERROR_COLORMAP,
    image_label,
    plot_capture_time,
    plot_error_map,
    plot_histograms,
    plot_spectra,
)


def _cube(values):
    return cube_dataset(values, theta_o=[45.0, 45.0, 60.0])


SHAPE = colour.SpectralShape(410, 720, 10)


@pytest.fixture(scope="module")
def run():
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    light = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(SHAPE).values
    spectra = np.array([sds[n].copy().align(SHAPE).values for n in sds]) * light / light.max()
    grid = spectra.reshape(4, 6, -1).transpose(2, 0, 1)
    cube = np.repeat(np.repeat(grid, 3, 1), 3, 2)
    truth_values = np.stack([cube, 0.8 * cube, 0.6 * cube])
    noise = np.random.default_rng(3).standard_normal(truth_values.shape)
    truth = _cube(truth_values)
    spectra = _cube(truth_values * (1 + 0.02 * noise))
    shots = xr.Dataset(coords={"image": ("shot", [0, 0, 1])})
    evaluation = evaluate(spectra, truth, shots=shots)
    return spectra, truth, shots, evaluation


def test_figures(run):
    spectra, truth, _, evaluation = run
    ev = evaluation.compute()
    srgb = render_srgb(truth)
    error_map = plot_error_map(ev, 1, truth_srgb=srgb, reconstruction_srgb=render_srgb(spectra))
    images = [ax for ax in error_map.axes if ax.get_images()]
    assert len(images) == 3  # truth, reconstruction, nRMSE
    assert images[-1].get_images()[0].get_cmap().name == "cubehelix"
    assert error_map.get_suptitle().startswith("image 1, camera 1, view (45°, 15°)")
    assert error_map.get_suptitle().endswith(", with band shots")
    other = plot_error_map(ev, 2, truth_srgb=srgb)
    assert other.get_suptitle().endswith("without band shots")
    assert len([ax for ax in other.axes if ax.get_images()]) == 2
    lines = plot_spectra(ev, 0).axes[0].get_lines()
    assert [line.get_linestyle() for line in lines[:2]] == ["-", ":"]  # truth solid, dotted
    assert len(lines) == 2 * ev.sizes["sample"]
    histogram = plot_histograms(ev).axes[0]
    assert histogram.get_yscale() == "log"
    labels = [t.get_text() for t in histogram.get_legend().get_texts()]
    assert any(label.startswith("with band shots") for label in labels)
    assert any(label.startswith("without band shots") for label in labels)
    bars = plot_capture_time(capture_time(7.463)).axes[0]
    assert "30.3x" in bars.get_title()


def test_figures_are_pure_agg_figures_not_registered_with_pyplot(run):
    import matplotlib.pyplot as plt

    _, truth, _, evaluation = run
    ev = evaluation.compute()
    before = plt.get_fignums()
    figures = [
        plot_error_map(ev, 0, truth_srgb=render_srgb(truth)),
        plot_spectra(ev, 0),
        plot_histograms(ev),
        plot_capture_time(capture_time(7.463, evaluation=ev)),
    ]
    assert all(isinstance(figure, Figure) for figure in figures)
    assert plt.get_fignums() == before
    assert ERROR_COLORMAP == "cubehelix"


def test_histograms_and_labels_without_band_shot_information(run):
    _, _, _, evaluation = run
    ev = evaluation.compute().drop_vars("has_band_shots")
    labels = [t.get_text() for t in plot_histograms(ev).axes[0].get_legend().get_texts()]
    n_pixels = ev.sizes["image"] * ev.sizes["y"] * ev.sizes["x"]
    assert labels[0].startswith(f"all images ({n_pixels} px")
    assert image_label(ev, 0) == "image 0, camera 0, view (45°, 0°), light (30°, 0°)"
    assert image_label(evaluation, 0).endswith(", with band shots")
