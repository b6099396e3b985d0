"""The calibration figures as a scientist reads them: patch names, registration residuals
against the estimate's precision, tick labels that do not overlap; the pixels that show a
camera's range."""

import numpy as np
import xarray as xr
from support.page_layout import figure_overlaps

from spectralize.nodes.evaluation.figures import representative_pixels
from spectralize.nodes.evaluation.figures_calibration import (
    camera_calibration_rows,
    patch_names,
    plot_camera_matrices,
    plot_cross_validation,
    plot_registration,
    registration_precision,
)


def registration(pair_shift, upsample_factor=50):
    pairs = np.asarray(pair_shift, float)
    shift = np.median(pairs, axis=0)
    return xr.Dataset(
        {
            "shift": ("axis", shift),
            "pair_shift": (("pair", "axis"), pairs),
            "residual": ("pair", np.abs(pairs - shift).max(axis=1)),
        },
        coords={
            "axis": ["y", "x"],
            "rgb_rotation": ("pair", np.arange(len(pairs))),
            "spectral_rotation": ("pair", np.arange(len(pairs)) + 1),
        },
        attrs={"upsample_factor": upsample_factor},
    )


def test_a_residual_at_the_quantisation_step_is_shown_as_agreement_and_ticks_do_not_overlap():
    # the demo's two pairs: x shifts 0.02 px apart, one step of the 1/50 px upsampling
    reg = registration([[0.32, -0.64], [0.32, -0.66]])
    assert registration_precision(reg) == 0.02
    figure = plot_registration(reg)
    titles = [ax.get_title() for ax in figure.axes]
    assert titles[1] == "residual per pair: every pair agrees within the precision"
    assert figure_overlaps(figure) == []  # was "-0.660-0.657-0.655..." on one line
    # pairs that really disagree say by how much
    titles = [ax.get_title() for ax in plot_registration(registration([[0.0, 0.0], [0.0, 0.5]])).axes]
    assert titles[1] == "residual per pair (max 0.25 px)"


def test_the_cross_validation_names_its_patches_and_their_labels_do_not_overlap():
    names = [f"neutral {v} ({d} D)" for v, d in zip(range(24), range(24), strict=True)]
    measured = np.random.default_rng(1).uniform(0.1, 1.0, (24, 3))
    table = xr.Dataset(
        {
            "measured": (("patch", "channel"), measured),
            "predicted": (("patch", "channel"), measured * 1.02),
            "relative_error": ("patch", np.full(24, 0.02)),
        },
        coords={"patch": np.arange(24), "patch_name": ("patch", names), "channel": ["R", "G", "B"]},
        attrs={"mean_relative_error": 0.02, "max_relative_error": 0.02},
    )
    assert patch_names(table["relative_error"]) == names
    figure = plot_cross_validation(table)
    assert [t.get_text() for t in figure.axes[-1].get_xticklabels()] == names
    assert figure_overlaps(figure) == []


def test_representative_pixels_span_the_brightness_and_find_the_least_confident():
    brightness = np.arange(2 * 10 * 10, dtype=float).reshape(2, 10, 10)
    confidence = np.zeros_like(brightness)
    confidence[1, 3, 4] = 0.5
    picks = dict((kind, rest) for kind, *rest in representative_pixels(brightness, confidence))
    assert picks["near saturation"] == [1, 9, 9]  # the top of the range
    assert picks["dark"] == [0, 0, 4]  # the 2nd percentile of 200 values: the 5th
    assert picks["least confident"] == [1, 3, 4]
    assert "least confident" not in dict(
        (kind, rest) for kind, *rest in representative_pixels(brightness, None)
    )


def test_each_camera_s_calibration_is_flagged_where_it_fails():
    """Flags: chart cross-validation above 3 %; C more than 5 % from its model's other camera."""
    wl = np.arange(410.0, 721.0, 10.0)
    lobe = lambda centre: np.exp(-0.5 * ((wl - centre) / 30.0) ** 2)  # noqa: E731
    nikon = np.stack([lobe(600), lobe(530), lobe(460)])
    shifted = np.stack([lobe(620), lobe(530), lobe(460)])  # R 20 nm off: not its model's shape
    calibration = xr.Dataset(
        {
            "camera_matrices": (
                ("camera", "channel", "wavelength"),
                np.stack([nikon, 2 * nikon, shifted]),
            ),
            "camera_mean_relative_error": ("camera", [0.01, 0.05, 0.02]),
            "camera_max_relative_error": ("camera", [0.02, 0.09, 0.04]),
        },
        coords={
            "camera": [0, 1, 2],
            "camera_name": ("camera", ["top", "paired", "side"]),
            "camera_model": ("camera", ["nikon", "nikon", "nikon"]),
            "c_source": ("camera", ["own chart frames"] * 3),
            "channel": ["R", "G", "B"],
            "wavelength": wl,
        },
    )
    rows = {r["camera"]: r for r in camera_calibration_rows(calibration)}
    assert rows["paired"]["flags"] == ["cross-validation above 3 %"]  # a gain alone is no flag
    assert any("differs from its model" in f for f in rows["side"]["flags"])
    assert rows["side"]["model_difference"] > 0.05 and rows["top"]["model_difference"] < 1e-9
    assert rows["top"]["flags"] == []
    assert camera_calibration_rows(calibration.drop_vars("camera_matrices")) == []
    figure = plot_camera_matrices(calibration)
    assert len(figure.axes) == 3 and "[flagged]" in figure.axes[1].get_title()
    assert figure_overlaps(figure) == []
