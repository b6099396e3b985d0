"""The example notebook runs, cell by cell (nbclient), on any run store: a small one with
ground truth, the store the capture path makes (sample capture folder -> ingest -> btf: no
truth) and a simulated run."""

import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path

import colour
import nbformat
import numpy as np
import pytest
import xarray as xr
from nbclient import NotebookClient

from spectralize.store import RunStore, compute_fingerprint

NOTEBOOK = Path(__file__).resolve().parents[2] / "notebooks" / "analyse_demo_run.ipynb"
SHAPE = colour.SpectralShape(410, 720, 10)


def image_coords(n: int) -> dict:
    deg = {"units": "degree", "long_name": "angle"}
    return {
        "camera": ("image", np.arange(n)),
        "rotation": ("image", np.zeros(n, int)),
        "led": ("image", np.arange(n)),
        "theta_i": ("image", np.full(n, 30.0), deg),
        "phi_i": ("image", np.zeros(n), deg),
        "theta_o": ("image", np.array([45.0, 45.0, 60.0]), deg),
        "phi_o": ("image", np.array([0.0, 15.0, 0.0]), deg),
    }


def spectra_group(values: np.ndarray) -> xr.Dataset:
    return xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                values.astype(np.float32),
                {"units": "1", "long_name": "relative spectral radiance"},
            )
        },
        coords={
            "wavelength": ("wavelength", SHAPE.wavelengths, {"units": "nm", "long_name": "wavelength"}),
            **image_coords(values.shape[0]),
        },
    )


def make_run(path: Path) -> RunStore:
    """3 images of the ColorChecker under LED-B3, 12 x 18 px; band shots for images 0 and 1."""
    sds = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    light = colour.SDS_ILLUMINANTS["LED-B3"].copy().align(SHAPE).values
    patches = np.array([sds[n].copy().align(SHAPE).values for n in sds]) * light / light.max()
    cube = np.repeat(np.repeat(patches.reshape(4, 6, -1).transpose(2, 0, 1), 3, 1), 3, 2)
    truth = np.stack([cube, 0.7 * cube, 0.5 * cube])
    noise = np.random.default_rng(7).standard_normal(truth.shape)
    store = RunStore.create(path)
    store.write(
        "truth/spectra", spectra_group(truth), fingerprint=compute_fingerprint("truth", "1", {}, {})
    )
    store.write(
        "spectra",
        spectra_group(truth * (1 + 0.02 * noise)).chunk({"image": 1}),
        fingerprint=compute_fingerprint("reconstruct", "1", {}, {}),
    )
    n_shots = 32
    store.write(
        "raw/spectral",
        xr.Dataset(
            {
                "counts": (
                    ("shot", "y", "x"),
                    np.full((n_shots, 12, 18), 40, np.uint16),
                    {"units": "DN", "long_name": "raw band-filtered pixel value"},
                )
            },
            coords={
                "wavelength": ("shot", SHAPE.wavelengths, {"units": "nm"}),
                "exposure_time": ("shot", np.full(n_shots, 0.1), {"units": "s"}),
                "image": ("shot", np.arange(n_shots) % 2),
                "rotation": ("shot", np.zeros(n_shots, int)),
                "led": ("shot", np.arange(n_shots) % 2),
            },
            attrs={"bit_depth": 12},
        ),
        fingerprint="raw-spectral",
    )
    store.write(
        "raw/rgb",
        xr.Dataset(
            {
                "counts": (
                    ("image", "exposure", "y", "x", "channel"),
                    np.full((3, 2, 12, 18, 3), 100, np.uint16),
                    {"units": "DN", "long_name": "raw RGB pixel value"},
                )
            },
            coords={
                "exposure_time": (("image", "exposure"), np.tile([0.01, 0.04], (3, 1)), {"units": "s"}),
                "channel": ("channel", ["R", "G", "B"]),
                **image_coords(3),
            },
            attrs={"bit_depth": 12},
        ),
        fingerprint="raw-rgb",
    )
    assert store.validate() == []
    return store


class Images(HTMLParser):
    def __init__(self):
        super().__init__()
        self.sources = []

    def handle_starttag(self, tag, attrs):
        if tag == "img":
            self.sources.append(dict(attrs)["src"])


def execute(store: Path, report: Path, cwd: Path, monkeypatch) -> list:
    """Run the notebook on ``store``; its code cells, every one executed without error."""
    monkeypatch.setenv("SPECTRALIZE_RUN", str(store))
    monkeypatch.setenv("SPECTRALIZE_REPORT_DIR", str(report))
    monkeypatch.delenv("MPLBACKEND", raising=False)  # the kernel's inline backend shows figures
    notebook = nbformat.read(NOTEBOOK, as_version=4)
    client = NotebookClient(
        notebook, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}
    )
    client.execute()  # raises CellExecutionError if any cell fails
    code = [cell for cell in notebook.cells if cell.cell_type == "code"]
    assert all(cell.execution_count for cell in code)  # every code cell ran
    assert [out for cell in code for out in cell.outputs if out.output_type == "error"] == []
    return code


def printed(code: list) -> str:
    return "\n".join(
        out.get("text", "") for cell in code for out in cell.outputs if out.output_type == "stream"
    )


def pictures(code: list) -> list:
    return [out for cell in code for out in cell.outputs if "image/png" in out.get("data", {})]


@pytest.mark.filterwarnings("ignore::zarr.errors.UnstableSpecificationWarning")  # channel labels
def test_notebook_executes_against_a_run_with_truth(tmp_path, monkeypatch):
    store = make_run(tmp_path / "run.zarr")
    report = tmp_path / "report"
    code = execute(store.path, report, tmp_path, monkeypatch)
    text = printed(code)
    assert "simulated, with ground truth" in text
    # 32 band shots of 0.1 s + 3 RGB series of 0.05 s against the paper's 226.212 s
    assert f"{226.212 / 3.35:.1f}x faster" in text
    assert "Warning" not in text
    assert f"report written to {report / 'index.html'}" in text
    assert len(pictures(code)) >= 5  # renders, spectra, error maps, Figure 5/6 pair, histogram
    page = Images()
    page.feed((report / "index.html").read_text(encoding="utf-8"))
    assert len(page.sources) >= 4  # histogram, capture time, error map and spectra of an image
    assert all(source.startswith("data:image/png;base64,") for source in page.sources)  # one file


def cli(*args: str, cwd: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stderr[-3000:]


def run_without_report(name: str, store: Path, parameters: dict | None = None) -> None:
    """The steps of flow ``name`` on ``store``, as ``run_flow`` runs them (in this process, on
    the session's Prefect API), but without the flow's HTML report: the notebook writes its
    own report from the store and reads nothing of the flow's (which the first demo of
    tests/test_packaging.py and the btf runs of tests/flows/test_safety_corpus.py check)."""
    from spectralize.flows.pipelines import get_flow, step_parameters
    from spectralize.flows.runtime import run_steps

    problems: list = []
    steps = step_parameters(get_flow(name).steps, dict(parameters or {}), problems=problems)
    run_steps(store, steps, flow_name=name, problems=problems)


@pytest.fixture(scope="module")
def capture_store(prefect_api, tmp_path_factory) -> Path:
    """The capture path, as a user takes it: a sample capture folder, ingested (both on the
    command line), the btf flow's steps run on it."""
    work = tmp_path_factory.mktemp("capture-path")
    cli("spectralize.datasets.capture.sample", "capture", "--recipe", "tiny", cwd=work)
    cli("spectralize.flows.cli", "ingest", "capture", "run.zarr", cwd=work)
    run_without_report("btf", work / "run.zarr")
    return work / "run.zarr"


@pytest.mark.slow
def test_notebook_executes_on_the_store_the_capture_path_makes(capture_store, tmp_path, monkeypatch):
    assert not RunStore.open(capture_store).has("truth/spectra")
    code = execute(capture_store, tmp_path / "report", tmp_path, monkeypatch)
    text = printed(code)
    assert "no ground truth" in text
    assert "colour checker: mean relative error" in text  # calibration
    assert "estimated nRMSE over all pixels of all images: median" in text  # confidence
    assert "no accuracy; the confidence above is the measure" in text
    assert "faster" in text  # capture time without truth
    assert f"report written to {tmp_path / 'report' / 'index.html'}" in text
    assert len(pictures(code)) >= 4  # QE and C, renders, spectra, confidence


@pytest.mark.slow
def test_notebook_executes_on_a_simulated_run(prefect_api, tmp_path, monkeypatch):
    run_without_report("demo", tmp_path / "run.zarr", parameters={"simulate.recipe": "tiny"})
    code = execute(tmp_path / "run.zarr", tmp_path / "report", tmp_path, monkeypatch)
    text = printed(code)
    assert "simulated, with ground truth" in text
    assert "estimated nRMSE over all pixels" in text and "colour checker" in text
    assert len(pictures(code)) >= 8  # the above and error maps, spectra, histograms
