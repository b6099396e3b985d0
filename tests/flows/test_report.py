import html
from html.parser import HTMLParser

import colour
import numpy as np
import pytest
import xarray as xr
from support.cubes import cube_dataset

from spectralize.flows.report import write_report, write_run_report
from spectralize.nodes.evaluation.capture_time import capture_time
from spectralize.nodes.evaluation.metrics import evaluate
from spectralize.schemas import RunStore, SchemaError

SHAPE = colour.SpectralShape(410, 720, 10)


def _cube(values, attrs=None):
    return cube_dataset(values, theta_o=[45.0, 45.0, 60.0], attrs=attrs)


PNG = b"\x89PNG\r\n\x1a\n"


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
        self.cells, self.title, self._in_cell, self._in_title = [], "", False, False

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "img":
            self.images.append(attrs["src"])
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

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self._in_cell = False
        elif tag == "title":
            self._in_title = False

    def handle_data(self, data):
        if self._in_cell:
            self.cells[-1] += data
        if self._in_title:
            self.title += data


def parse(path) -> Page:
    page = Page()
    page.feed(path.read_text(encoding="utf-8"))
    return page


def test_report_contains_every_figure_and_table_with_the_numbers(run, tmp_path):
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
    page = parse(index)
    assert page.title == "demo report"
    expected_images = {"histogram.png", "capture_time.png"} | {
        f"{kind}_{i:03d}.png" for kind in ("error_map", "spectra") for i in range(3)
    }
    assert set(page.images) == expected_images
    for name in page.images:  # relative links to real PNG files in the folder
        assert "/" not in name and not name.startswith("http")
        assert (index.parent / name).read_bytes()[:8] == PNG
    assert set(page.figures) == {name[:-4] for name in expected_images}
    assert page.tables == ["run", "summary", "per-image", "capture-time", "baselines"]
    cells = page.cells
    # what run it describes
    assert "demo/run.zarr" in cells and "spectra-fp-123" in cells and "reconstruct v1" in cells
    # the numbers: per-image statistics, subsets, capture time, baselines
    ev = evaluation.compute()
    for image in range(3):
        median = float(ev.nrmse_statistics[image].sel(statistic="median"))
        assert f"{median:.4g}" in cells
    assert {"with band shots", "without band shots", "all"} <= set(cells)
    assert "30.3x" in index.read_text() and "7.463" in cells
    assert {"this run (spectra)", "perfect", "biased"} <= set(cells)
    row = cells.index("perfect")
    assert cells[row + 1] == "0"  # a perfect method has nRMSE median 0


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
    assert page.tables == ["run", "summary", "per-image"]
    assert set(page.images) == {"histogram.png", "error_map_000.png", "spectra_000.png"}
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
    store.write(
        "baselines/biased",
        (truth * 1.2).drop_attrs(deep=False),
        schema="spectra",
        fingerprint="biased-fp",
    )
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
    assert page.tables == ["run", "summary", "per-image", "capture-time", "baselines"]
    assert str(store.path) in page.cells and "spectra-fp" in page.cells
    assert "biased" in page.cells and "1.6" in page.cells  # 32 shots x 0.05 s
    assert "reference: the paper's long-exposure capture" in html.unescape(index.read_text())
    assert page.cells[page.cells.index("with band shots") + 1] == str(12 * 18)  # image 0 only
    # the report folder inside the run store does not disturb the store
    assert store.validate() == [] and "report" not in store.groups()


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
    assert "cross_validation.png" in page.images
    assert (tmp_path / "cross_validation.png").read_bytes()[:8] == PNG
    assert "0.02" in page.cells


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


def test_the_page_references_every_figure_file_it_wrote(run, tmp_path):
    spectra, truth, _, evaluation = run
    capture = capture_time(7.463, evaluation=evaluation.compute())
    index = write_report(
        evaluation, spectra=spectra, truth=truth, directory=tmp_path, capture=capture, max_images=2
    )
    written = {path.name for path in tmp_path.iterdir() if path.name != "index.html"}
    page = parse(index)
    assert written == set(page.images)
    assert len(page.images) == len(set(page.images)) == 2 + 2 * 2
