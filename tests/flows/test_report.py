import base64
import html
import io
from html.parser import HTMLParser

import colour
import numpy as np
import pytest
import xarray as xr
from PIL import Image
from support.browser import screenshot
from support.cubes import cube_dataset
from support.page_layout import browser_overlaps, figure_overlaps

from spectralize.flows import report
from spectralize.flows.report import error_map_figures, write_report, write_run_report
from spectralize.nodes.evaluation.accuracy import evaluate
from spectralize.nodes.evaluation.capture_time import capture_time
from spectralize.nodes.evaluation.figures import nrmse_histograms
from spectralize.nodes.evaluation.relit_colour import relit_delta_e, relit_statistics
from spectralize.schemas import SchemaError
from spectralize.store import RunStore

SHAPE = colour.SpectralShape(410, 720, 10)


def _cube(values, attrs=None):
    return cube_dataset(values, theta_o=[45.0, 45.0, 60.0], attrs=attrs)


PNG = b"\x89PNG\r\n\x1a\n"


def led_light() -> np.ndarray:
    """The light of the ``run`` fixture's spectra on its bands (LED-B3, max 1)."""
    light = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(SHAPE).values
    return light / light.max()


@pytest.fixture(scope="module")
def run():
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    light = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(SHAPE).values
    spectra = np.array([sds[n].copy().align(SHAPE).values for n in sds]) * light / light.max()
    grid = spectra.reshape(4, 6, -1).transpose(2, 0, 1)
    cube = np.repeat(np.repeat(grid, 3, 1), 3, 2)
    truth_values = np.stack([cube, 0.8 * cube, 0.6 * cube])
    noise = np.random.default_rng(3).standard_normal(truth_values.shape)
    truth = _cube(
        truth_values,
        {
            "spectralize_fingerprint": "truth-fp",
            "spectralize_provenance": {"node": "simulate", "version": "2"},
        },
    )
    spectra = _cube(
        truth_values * (1 + 0.02 * noise),
        {
            "spectralize_fingerprint": "spectra-fp-123",
            "spectralize_provenance": {"node": "reconstruct", "version": "1"},
        },
    )
    shots = xr.Dataset(coords={"image": ("shot", [0, 0, 1])})
    evaluation = evaluate(spectra, truth, shots=shots)
    return spectra, truth, shots, evaluation


class Page(HTMLParser):
    def __init__(self):
        super().__init__()
        self.images, self.tables, self.figures, self.links = [], [], [], []
        self.figure_ids, self.headings = [], []
        self.cells, self.title, self._in_cell, self._in_title = [], "", False, False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs["src"])
            self.figure_ids.append(self.figures[-1] if self.figures else None)
        elif tag == "table":
            self.tables.append(attrs.get("id"))
        elif tag == "figure":
            self.figures.append(attrs.get("id"))
        elif tag == "a":
            self.links.append(attrs.get("href"))
        elif tag in ("td", "th"):
            self._in_cell = True
            self.cells.append("")
        elif tag == "title":
            self._in_title = True
        elif tag == "h3":
            self.headings.append("")
            self._in_heading = True

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._in_cell = False
        elif tag == "title":
            self._in_title = False
        elif tag == "h3":
            self._in_heading = False

    def handle_data(self, data):
        if self._in_cell:
            self.cells[-1] += data
        if self._in_title:
            self.title += data
        if getattr(self, "_in_heading", False):
            self.headings[-1] += data


def parse(path) -> Page:
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    return page


def embedded(page: Page) -> dict[str, bytes]:
    """Figure id -> PNG bytes of every figure embedded in the page (all must be data URIs)."""
    out = {}
    for figure_id, src in zip(page.figure_ids, page.images, strict=True):
        prefix = "data:image/png;base64,"
        assert src.startswith(prefix), src[:40]
        out[figure_id] = base64.b64decode(src[len(prefix) :])
    return out


def test_report_is_one_file_with_every_figure_and_table_and_the_numbers(run, tmp_path):
    spectra, truth, shots, evaluation = run
    capture = capture_time(7.463, evaluation=evaluation.compute())
    index = write_report(
        evaluation,
        spectra=spectra,
        truth=truth,
        directory=tmp_path / "report",
        capture=capture,
        shots=shots,
        run="demo/run.zarr",
        title="demo report",
        baselines={"perfect": truth.radiance, "biased": truth.radiance * 1.2},
    )
    assert index == tmp_path / "report" / "index.html"
    assert [p.name for p in index.parent.iterdir()] == ["index.html"]  # self-contained
    page = parse(index)
    assert page.title == "demo report"
    figures = embedded(page)
    expected = {"histogram", "capture_time"} | {
        f"{k}_{i:03d}" for k in ("error_map", "spectra") for i in range(3)
    }
    assert set(figures) == expected
    assert all(png[:8] == PNG for png in figures.values())
    assert page.tables == ["summary", "per-image", "capture-time", "baselines", "run"]
    text = index.read_text()
    # headline numbers first: before the first section
    ev = evaluation.compute()
    median = float(ev.nrmse_subset_statistics.sel(subset="all", statistic="median"))
    assert text.index('id="headline"') < text.index("<section")
    assert f"{median:.4g}" in text[: text.index("<section")]
    cells = page.cells
    assert "demo/run.zarr" in cells and "spectra-fp-123" in cells and "reconstruct v1" in cells
    for image in range(3):
        image_median = float(ev.nrmse_statistics.sel(image=image, statistic="median"))
        assert f"{image_median:.4g}" in cells
    assert {"with band shots", "without band shots", "all"} <= set(cells)
    assert "30.3x" in text and "7.463" in cells
    assert {"this run (spectra)", "perfect", "biased"} <= set(cells)
    assert cells[cells.index("perfect") + 1] == "0"  # a perfect method has nRMSE median 0


def test_truth_and_reconstruction_panels_show_the_same_image_whatever_the_order(run, tmp_path):
    spectra, truth, shots, _ = run
    # three clearly different images; the reconstruction is stored in image-set order 2, 0, 1
    values = truth["radiance"].values * np.array([1.0, 0.3, 0.05])[:, None, None, None]
    truth = truth.copy(data={"radiance": values}).assign_coords(image=[0, 1, 2])
    order = [2, 0, 1]
    spectra = truth.sel(image=order)
    # spectra and evaluation in image-set order, truth in label order: the report's old bug
    evaluation = evaluate(spectra, truth, shots=shots).compute().sel(image=order)
    assert evaluation["image"].values.tolist() == order
    for label, error_map, _ in error_map_figures(evaluation, spectra, truth, [0, 1, 2]):
        truth_panel, recon_panel = (ax.images[0].get_array() for ax in error_map.axes[:2])
        np.testing.assert_allclose(recon_panel, truth_panel, atol=1)  # the same image
        brightness = float(np.asarray(truth_panel, dtype=float).mean())
        assert error_map._suptitle.get_text().startswith(f"image {label},")
        assert float(np.nanmax(evaluation["nrmse"].sel(image=label))) < 1e-5
        if label == 0:
            bright = brightness
        elif label == 2:
            assert brightness < bright  # label 2 is the dim image, not position 2
    index = write_report(evaluation, spectra=spectra, truth=truth, directory=tmp_path, shots=shots)
    page = parse(index)
    start = page.cells.index("image")
    width = page.cells.index("NaN px", start) - start + 1
    table = page.cells[start + width : start + 4 * width]
    first_column = table[::width]
    assert first_column == ["0", "1", "2"]  # per-image table in label order, named by label
    assert [h.split(",")[0] for h in page.headings] == ["image 0", "image 1", "image 2"]


def test_histogram_covers_every_pixel_with_an_overflow_bin_and_fractions(run):
    spectra, truth, shots, _ = run
    worse = spectra.copy(data={"radiance": spectra["radiance"].values * 1.6})  # nRMSE far above 0.12
    evaluation = evaluate(worse, truth, shots=shots).compute()
    assert int(evaluation["nrmse_above_range"].sum()) > 0  # the stored histogram misses pixels
    above = evaluation["nrmse_above_range"].values
    total = (evaluation["nrmse_histogram"].sum("nrmse_bin") + evaluation["nrmse_above_range"]).values
    has = evaluation["has_band_shots"].values
    for label, table in nrmse_histograms(evaluation).items():
        mask = has if label == "with band shots" else ~has
        assert table["fraction"].sum() + table["overflow"] == pytest.approx(1.0)  # every pixel
        assert table["pixels"] == int(np.isfinite(evaluation["nrmse"].values[mask]).sum())
        hidden = above[mask].sum() / total[mask].sum()  # what the 0..0.12 axis used to hide
        assert hidden > 0.2 and table["overflow"] < 0.05
        assert table["edges"][-1] > 0.12


def test_optional_sections_are_left_out_and_figures_limited(run, tmp_path):
    spectra, truth, _, evaluation = run
    index = write_report(
        evaluation.drop_vars("has_band_shots"),
        spectra=spectra,
        truth=truth,
        directory=tmp_path,
        max_images=1,
    )
    page = parse(index)
    assert page.tables == ["summary", "per-image", "run"]
    assert set(embedded(page)) == {"histogram", "error_map_000", "spectra_000"}
    assert "(not given)" in page.cells
    assert "Figures for the first 1 of 3 images." in index.read_text()


def test_report_refuses_what_is_not_an_evaluation(run, tmp_path):
    spectra, truth, _, evaluation = run
    with pytest.raises(SchemaError, match="evaluation:nrmse_histogram"):
        write_report(
            evaluation.drop_vars("nrmse_histogram"), spectra=spectra, truth=truth, directory=tmp_path
        )
    assert not (tmp_path / "index.html").exists()


def test_write_run_report_reads_everything_from_the_store(run, tmp_path):
    spectra, truth, _, _ = run
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("truth/spectra", truth.drop_attrs(deep=False), fingerprint="truth-fp")
    store.write("spectra", spectra.drop_attrs(deep=False), fingerprint="spectra-fp")
    n = 32
    store.write(
        "raw/spectral",
        xr.Dataset(
            {"counts": (("shot", "y", "x"), np.zeros((n, 12, 18), np.uint16), {"units": "DN"})},
            coords={
                "wavelength": ("shot", SHAPE.wavelengths, {"units": "nm"}),
                "exposure_time": ("shot", np.full(n, 0.05), {"units": "s"}),
                "image": ("shot", np.zeros(n, np.int64)),
                "rotation": ("shot", np.zeros(n, int)),
                "led": ("shot", np.zeros(n, int)),
            },
            attrs={"bit_depth": 12},
        ),
        fingerprint="raw-fp",
    )
    index = write_run_report(store.path, max_images=1)
    assert index == store.path / "report" / "index.html"
    page = parse(index)
    assert page.tables == ["summary", "per-image", "capture-time", "run"]
    assert str(store.path) in page.cells and "spectra-fp" in page.cells
    assert "1.6" in page.cells  # 32 shots x 0.05 s
    assert "reference: the paper's long-exposure capture" in html.unescape(index.read_text())
    assert page.cells[page.cells.index("with band shots") + 1] == str(12 * 18)  # image 0 only
    assert {"renders-0", "camera_spectra"} <= set(embedded(page))  # the reconstruction section
    # the report folder inside the run store does not disturb the store
    assert store.validate() == [] and "report" not in store.groups()


def relative(ds: xr.Dataset) -> xr.Dataset:
    for var in ds.data_vars.values():
        var.attrs["units"] = "1"
    return ds


def spectral_calibration(measured: np.ndarray, predicted: np.ndarray) -> xr.Dataset:
    """A calibration/spectral group of 24 patches: the chart's measured and predicted RGB, Q,
    a flat C and the LED light."""
    return xr.Dataset(
        {
            "quantum_efficiency": ("wavelength", np.linspace(0.2, 1.0, SHAPE.wavelengths.size)),
            "camera_matrix": (("channel", "wavelength"), np.ones((3, SHAPE.wavelengths.size))),
            "measured_rgb": (("patch", "channel"), measured),
            "predicted_rgb": (("patch", "channel"), predicted),
            "relative_error": ("patch", np.full(24, 0.02)),
            "illuminant": ("wavelength", led_light()),
        },
        coords={
            "wavelength": ("wavelength", SHAPE.wavelengths, {"units": "nm"}),
            "patch": np.arange(24),
            "channel": ["R", "G", "B"],
        },
        attrs={"mean_relative_error": 0.02, "max_relative_error": 0.02},
    ).pipe(relative)


@pytest.mark.slow
def test_a_run_without_ground_truth_gets_a_report_that_a_browser_shows(run, tmp_path, monkeypatch):
    spectra, _, _, _ = run
    store = RunStore.create(tmp_path / "run.zarr")
    confidence = xr.DataArray(
        np.linspace(0, 1, 3 * 12 * 18, dtype=np.float32).reshape(3, 12, 18),
        dims=("image", "y", "x"),
        attrs={"units": "1", "long_name": "confidence"},
    )
    store.write(
        "spectra",
        spectra.drop_attrs(deep=False).assign(confidence=confidence).isel(image=[1, 2, 0]),
        fingerprint="spectra-fp",
    )
    measured = np.random.default_rng(0).uniform(0.1, 1.0, (24, 3))
    store.write(
        "calibration/spectral",
        spectral_calibration(measured, measured * 1.02),
        fingerprint="calibration-fp",
    )
    drawn = {}
    keep = report._figure

    def recording(figure, figure_id, caption):
        drawn[figure_id] = figure
        return keep(figure, figure_id, caption)

    monkeypatch.setattr(report, "_figure", recording)
    index = write_run_report(store.path, directory=tmp_path / "report", pixels=[(1, 2), (10, 15)])
    page = parse(index)
    figures = embedded(page)
    thumbnails = {f"renders-{k}" for k in range(3)} | {f"confidence-{k}" for k in range(3)}
    assert thumbnails | {"cross_validation", "quantum_efficiency", "camera_spectra"} <= set(figures)
    assert "pixel_spectra_000" in figures  # the pixels asked for, on the first image
    assert "cross-validation" in page.tables and "2.00 %" in page.cells  # in %, like the headline
    text = html.unescape(index.read_text())
    headline = text[text.index('id="headline"') : text.index("<section")]
    assert "images reconstructed" in headline and "2.00 %" in headline
    # no truth: the quality headline is the confidence's (estimated nRMSE), with its meaning
    values = np.linspace(0, 1, 3 * 12 * 18)
    assert (
        f"estimated nRMSE median {np.median(values):.4f}, 95th percentile "
        f"{np.percentile(values, 95):.4f}; {100 * np.mean(values > 0.03):.1f} % of pixels above 0.03"
    ) in headline
    assert "what that means" in headline
    # thumbnails named by image, camera and angles, in label order
    assert "image 0 · camera 1 · view θo 45°, φo 15° · light θi 30°, φi 0°" in text
    assert text.index("image 0 · camera") < text.index("image 1 · camera") < text.index("image 2 ·")
    # the confidence's colour scale spans its 2 % to 98 % percentiles, not its extremes
    shown = np.linspace(0, 1, 3 * 12 * 18)
    low, high = np.percentile(shown, [2, 98])
    assert f"{low:.4f} (dark) to {high:.4f} (bright)" in text
    # no truth: the first images relit under A, FL11 and D65 beside the capture's render
    relit = {k: v for k, v in figures.items() if k.startswith("relit-")}
    assert set(relit) == {f"relit-{label}-{k}" for label in range(3) for k in range(4)}
    assert "calibration/spectral:illuminant" in text and "relit-colour" not in page.tables
    for label in range(3):
        captions = [html.unescape(c) for c in _captions(text, f"relit-{label}")]
        assert captions[0].startswith(f"image {label} · camera") and captions[0].endswith("as captured")
        assert captions[1:] == [f"image {label} · under {name}" for name in ("A", "FL11", "D65")]
    warmth = {}
    for k, name in enumerate(("captured", "A", "FL11", "D65")):
        pixels = np.asarray(Image.open(io.BytesIO(relit[f"relit-0-{k}"])), dtype=float)
        assert pixels.shape == (12, 18, 3) and pixels.std() > 5  # a picture, not a flat field
        warmth[name] = pixels[..., 0].mean() / pixels[..., 2].mean()
    assert warmth["A"] > 1.2 * warmth["D65"]  # tungsten renders warmer than daylight
    # a real browser lays it out: every image decodes, no two text lines or images overlap
    layout = browser_overlaps(index, tmp_path)
    assert layout["images"] == len(page.images) and layout["broken"] == 0
    assert layout["boxes"] > 100 and layout["overlaps"] == []
    # nor do the texts inside the figures (tick labels, titles, legends)
    assert {name: figure_overlaps(figure) for name, figure in drawn.items()} == {
        name: [] for name in drawn
    }
    # and a screenshot that is not blank
    shot = screenshot(index, tmp_path / "report.png", width=1200, height=1600)
    assert shot.shape[0] >= 1000 and shot.shape[1] >= 1000
    colours = np.unique(shot.reshape(-1, 3) // 16, axis=0)
    assert len(colours) > 50  # text, tables and figures, not a blank page
    assert (shot < 128).any(axis=-1).mean() > 0.01


def _captions(text: str, gallery: str) -> list[str]:
    """The thumbnail captions of a gallery, in page order."""
    start = text.index(f'<figure class="gallery" id="{gallery}">')
    block = text[start : text.index("</div>\n</figure>", start)]
    return [part.split("</figcaption>")[0] for part in block.split("<figcaption>")[2:]]


def test_with_truth_and_the_light_the_report_tabulates_the_relit_colour(run, tmp_path):
    spectra, truth, shots, evaluation = run
    index = write_report(
        evaluation, spectra=spectra, truth=truth, directory=tmp_path, shots=shots, illuminant=led_light()
    )
    page = parse(index)
    assert page.tables == ["summary", "relit-colour", "per-image", "run"]
    expected = relit_statistics(relit_delta_e(spectra, truth, led_light()))
    cells = page.cells
    start = cells.index("pixels left out") + 1
    rows = [cells[start + 4 * k : start + 4 * k + 4] for k in range(3)]
    assert [row[0] for row in rows] == ["A", "FL11", "D65"]
    for row in rows:
        stats = expected[row[0]]
        assert row[1:3] == [f"{stats['median']:.4g}", f"{stats['p95']:.4g}"]
        assert 0.05 < stats["median"] < 5  # a 2 % noise is a visible, not a huge, difference
    text = html.unescape(index.read_text())
    headline = text[text.index('id="headline"') : text.index("<section")]
    medians = " / ".join(f"{expected[name]['median']:.3g}" for name in ("A", "FL11", "D65"))
    assert f"CIEDE2000 relit under A / FL11 / D65 (median)</dt><dd>{medians}" in headline
    assert "the illuminant given" in text and "99th percentile" in text
    # a light on other wavelengths: the report says why it cannot relight, and is written
    shifted = xr.DataArray(led_light(), dims="wavelength", coords={"wavelength": SHAPE.wavelengths + 5})
    index = write_report(
        evaluation, spectra=spectra, truth=truth, directory=tmp_path / "shifted", illuminant=shifted
    )
    assert "relit-colour" not in parse(index).tables
    assert "not measured" in index.read_text() and "illuminant_L:wavelength" in index.read_text()
    # without the light: said so, no table
    index = write_report(evaluation, spectra=spectra, truth=truth, directory=tmp_path / "none")
    assert "Colour under other lights is not measured" in index.read_text()


def test_a_run_store_with_truth_relights_with_its_calibrated_light(run, tmp_path):
    spectra, truth, _, _ = run
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("truth/spectra", truth.drop_attrs(deep=False), fingerprint="truth-fp")
    store.write("spectra", spectra.drop_attrs(deep=False), fingerprint="spectra-fp")
    index = write_run_report(store.path, max_images=2)
    assert "relit-colour" not in parse(index).tables  # no light in the store
    store.write(
        "calibration/spectral",
        spectral_calibration(np.full((24, 3), 0.5), np.full((24, 3), 0.51)),
        fingerprint="calibration-fp",
    )
    index = write_run_report(store.path, max_images=2)
    page = parse(index)
    assert "relit-colour" in page.tables and "calibration/spectral:illuminant" in index.read_text()
    stored = store.read("spectra").load()  # the spectra as kept (to their stated precision)
    expected = relit_statistics(relit_delta_e(stored, truth, led_light()))
    assert f"{expected['FL11']['p95']:.4g}" in page.cells
    # relit renders of the 2 images shown: the capture's and three lights each
    assert {f"relit-{label}-{k}" for label in range(2) for k in range(4)} <= set(embedded(page))


def test_calibration_cross_validation_is_tabulated_and_drawn(run, tmp_path):
    spectra, truth, _, evaluation = run
    measured = np.random.default_rng(0).uniform(0.1, 1.0, (24, 3))
    calibration = xr.Dataset(
        {
            "measured_rgb": (("patch", "channel"), measured),
            "predicted_rgb": (("patch", "channel"), measured * 1.02),
            "relative_error": ("patch", np.full(24, 0.02)),
        },
        coords={"patch": np.arange(24), "channel": ["R", "G", "B"]},
    )
    index = write_report(
        evaluation,
        spectra=spectra,
        truth=truth,
        directory=tmp_path,
        max_images=1,
        calibration=calibration,
    )
    page = parse(index)
    assert "cross-validation" in page.tables
    assert embedded(page)["cross_validation"][:8] == PNG
    assert "2.00 %" in page.cells


def test_labels_are_escaped_by_the_template(run, tmp_path):
    spectra, truth, _, evaluation = run
    attack = '<script>alert("x")</script>'
    index = write_report(
        evaluation,
        spectra=spectra,
        truth=truth,
        directory=tmp_path,
        max_images=1,
        title=f"run {attack}",
        run=f"{attack}.zarr",
        baselines={attack: truth.radiance},
    )
    text = index.read_text(encoding="utf-8")
    assert "<script" not in text
    assert "&lt;script&gt;" in text
    page = parse(index)
    assert page.title == f"run {attack}"  # shown as text, not run as markup
    assert attack in page.cells and f"{attack}.zarr" in page.cells


@pytest.mark.timing
def test_the_report_of_a_demo_sized_run_takes_under_five_seconds(tmp_path):
    """99 images of 64 x 64 px with confidence, the colour checker and the registration, as
    the demo's capture path makes them; 24 images with figures."""
    import time

    rng = np.random.default_rng(4)
    n = 99
    values = rng.uniform(0.05, 1.0, (n, SHAPE.wavelengths.size, 64, 64)).astype(np.float32)
    spectra = cube_dataset(values).assign(
        confidence=(
            ("image", "y", "x"),
            rng.gamma(1.0, 0.01, (n, 64, 64)).astype(np.float32),
            {"units": "1"},
        )
    )
    store = RunStore.create(tmp_path / "run.zarr")
    store.write("spectra", spectra.chunk({"image": 11}), fingerprint="spectra-fp")
    measured = rng.uniform(0.1, 1.0, (24, 3))
    store.write(
        "calibration/spectral",
        xr.Dataset(
            {
                "quantum_efficiency": ("wavelength", np.linspace(0.2, 1.0, SHAPE.wavelengths.size)),
                "camera_matrix": (("channel", "wavelength"), np.ones((3, SHAPE.wavelengths.size))),
                "measured_rgb": (("patch", "channel"), measured),
                "predicted_rgb": (("patch", "channel"), measured * 1.02),
                "relative_error": ("patch", np.full(24, 0.02)),
            },
            coords={
                "wavelength": ("wavelength", SHAPE.wavelengths, {"units": "nm"}),
                "patch": np.arange(24),
                "channel": ["R", "G", "B"],
            },
            attrs={"mean_relative_error": 0.02, "max_relative_error": 0.02},
        ).pipe(relative),
        fingerprint="calibration-fp",
    )
    start, cpu = time.perf_counter(), time.process_time()
    index = write_run_report(store.path, directory=tmp_path / "report")
    seconds, cpu = time.perf_counter() - start, time.process_time() - cpu
    assert len(parse(index).images) >= 2 * 24 + 3  # renders and confidence of 24, figures
    # the work, all threads: under 5 s; the wall clock too, unless other work shares the cores
    assert cpu < 5.0, f"{cpu:.1f} s of CPU"
    assert seconds < max(5.0, 3 * cpu), f"{seconds:.1f} s"


def test_error_maps_show_the_range_of_the_images_not_the_first_ones(run, tmp_path, monkeypatch):
    spectra, truth, shots, _ = run
    values = np.concatenate([truth["radiance"].values] * 3)  # nine images ...
    truth = cube_dataset(values).assign_coords(image=np.arange(9))
    noise = np.random.default_rng(2).standard_normal(values.shape)
    gains = np.linspace(0.0, 0.08, 9)[[3, 0, 8, 1, 5, 2, 7, 4, 6]]  # ... of scrambled error
    spectra = truth.copy(data={"radiance": values * (1 + gains[:, None, None, None] * noise)})
    evaluation = evaluate(spectra, truth).compute()
    monkeypatch.setattr(report, "MAX_ERROR_MAPS", 3)
    index = write_report(evaluation, spectra=spectra, truth=truth, directory=tmp_path)
    mapped = [h.split(",")[0] for h in parse(index).headings]
    # the best (gain 0: label 1), the median (gain 0.04: label 7) and the worst (label 2)
    assert mapped == ["image 1", "image 2", "image 7"]
    assert "Error maps for 3 of these 9 images" in index.read_text()


# -- a report's time does not grow with the image count ---------------------------------------


def test_the_confidence_statistics_of_a_large_run_read_images_spread_over_it():
    """1,000 images, at most 3,200 pixels: 200 images spread evenly, the first and the last
    among them; at most STATISTICS_IMAGES images however small the frames; frames larger
    than the limit: two images, every few pixels."""
    labels = np.arange(1000, dtype=float)
    confidence = xr.DataArray(
        np.broadcast_to(labels[:, None, None], (1000, 4, 4)).copy(), dims=("image", "y", "x")
    ).chunk({"image": 50})
    sample, images = report._spread_sample(confidence, limit=3200)
    read = np.unique(np.asarray(sample.values))
    assert images == 200 and np.array_equal(read, np.round(np.linspace(0, 999, 200)))
    assert read[0] == 0 and read[-1] == 999 and sample.size <= 3200
    capped, count = report._spread_sample(confidence, limit=3200, images=20)
    assert count == 20 and np.array_equal(np.unique(capped.values), np.round(np.linspace(0, 999, 20)))
    whole, count = report._spread_sample(confidence, limit=16_000)
    assert count == 1000 and whole.size == confidence.size  # small enough: all of it
    large = xr.DataArray(np.zeros((3, 64, 64)), dims=("image", "y", "x")).chunk({"image": 1})
    strided, count = report._spread_sample(large, limit=2048)
    assert count == 2 and strided.shape == (2, 32, 32)  # every 2nd pixel of the first and last


def test_the_confidence_as_stored_reads_only_the_chunks_of_the_images_sampled(tmp_path, monkeypatch):
    """2,000 one-image chunks in 20 shards: the headline's sample reads its images' chunks in
    3 shards spread over the run (first, middle, last), not a chunk per image or every shard."""
    from spectralize.store.integrity import CheckedLocalStore

    n = 2000
    store = RunStore.create(tmp_path / "run.zarr")
    data = xr.Dataset(
        {
            "confidence": (
                ("image", "y", "x"),
                np.repeat(np.arange(n, dtype=np.float32), 16).reshape(n, 4, 4),
            )
        },
        coords={"image": np.arange(n)},
    )
    store.write(
        "spectra_like",
        data.chunk({"image": 100}),
        schema=None,
        encoding={"confidence": {"chunks": (1, 4, 4), "shards": (100, 4, 4)}},
    )
    read: list[tuple[str, bool]] = []
    real_get = CheckedLocalStore.get

    async def counted(self, key, prototype=None, byte_range=None):
        read.append((key, byte_range is not None))
        return await real_get(self, key, prototype, byte_range)

    stored = report._stored_variable(store, "spectra_like", "confidence")
    monkeypatch.setattr(CheckedLocalStore, "get", counted)
    sample, images = report._spread_sample(stored, limit=400 * 16)
    values = np.unique(np.asarray(sample.values))
    shards = {int(v) // 100 for v in values}
    assert images == 300 and shards == {0, 10, 19}  # the 3 shards' 300 images: fewer than 400
    assert values[0] == 0 and values[-1] == n - 1
    touched = {key for key, _ in read if "/confidence/c/" in key}
    assert len(touched) == 3  # shard files
    assert sum(ranged for key, ranged in read if key in touched) <= 2 * images + 3


def test_the_confidence_headline_of_a_run_too_large_to_read_says_what_it_was_computed_over():
    rng = np.random.default_rng(5)
    n, side = 300, 128  # 4.9 million pixels: more than STATISTICS_PIXELS
    confidence = xr.DataArray(
        rng.gamma(1.0, 0.01, (n, side, side)).astype(np.float32), dims=("image", "y", "x")
    ).chunk({"image": 10})
    (quality, _) = report._confidence_headline(confidence)
    images = report.STATISTICS_PIXELS // side**2  # as many whole images as fit
    assert quality[1].endswith(
        f"(over {images * side**2:,} of the {n * side * side:,} pixels: {images} of the 300 "
        "images, spread over the run)"
    )
    (small, _) = report._confidence_headline(confidence.isel(image=slice(0, 20)))
    assert "spread" not in small[1]  # a run this small: every pixel


def test_the_per_image_table_of_a_large_run_has_its_first_images(run, monkeypatch):
    _, _, _, evaluation = run
    monkeypatch.setattr(report, "MAX_TABLE_IMAGES", 2)
    table = report._per_image_table(evaluation.isel(image=[2, 0, 1]))
    assert [row[0] for row in table["rows"]] == ["0", "1"]
    assert table["caption"].endswith("the first 2 of 3 images (all in the evaluation group)")
