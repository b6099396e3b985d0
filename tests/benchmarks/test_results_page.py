"""docs/benchmarks.md is the generator's output for the committed JSON (no benchmark runs)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def load_generator():
    spec = importlib.util.spec_from_file_location(
        "results_page", ROOT / "benchmarks" / "results_page.py"
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("results_page", module)
    spec.loader.exec_module(module)
    return module


results_page = load_generator()


def test_committed_page_equals_the_generated_one():
    committed = (ROOT / "docs" / "benchmarks.md").read_text()
    assert committed == results_page.render(), (
        "docs/benchmarks.md is stale: run python benchmarks/results_page.py and commit it"
    )


def test_every_results_json_has_a_section_and_every_section_a_json():
    names = {path.stem for path in (ROOT / "benchmarks" / "results").glob("*.json")}
    sections = {name for name, *_ in results_page.SECTIONS}
    assert names == sections


def test_figures_on_the_page_come_from_the_json():
    page = results_page.render()
    slice_ = json.loads((ROOT / "benchmarks" / "results" / "paper_slice.json").read_text())
    assert f"commit `{slice_['commit']}`" in page
    assert f"| peak resident set | {results_page.num(slice_['peak_rss_gb'])} GB |" in page
    cli = json.loads((ROOT / "benchmarks" / "results" / "cli.json").read_text())
    assert f"| `spectralize --help` | {results_page.num(cli['help_s'])} |" in page


def test_a_changed_json_changes_the_page(tmp_path):
    results = tmp_path / "results"
    results.mkdir()
    for path in (ROOT / "benchmarks" / "results").glob("*.json"):
        (results / path.name).write_text(path.read_text())
    cli = json.loads((results / "cli.json").read_text())
    cli["help_s"] = 0.5
    (results / "cli.json").write_text(json.dumps(cli))
    page = results_page.render(results=results)
    assert "| `spectralize --help` | 0.5 |" in page
    assert page != results_page.render()


def test_notes_naming_no_benchmark_are_refused(tmp_path):
    notes = tmp_path / "notes.md"
    notes.write_text("# notes\n\n## no_such_benchmark\n\ntext\n")
    with pytest.raises(SystemExit, match="no_such_benchmark"):
        results_page.read_notes(notes)


def test_a_json_without_a_section_is_refused(tmp_path):
    (tmp_path / "new_benchmark.json").write_text("{}")
    with pytest.raises(SystemExit, match="new_benchmark"):
        results_page.render(results=tmp_path)


@pytest.mark.parametrize(
    ("value", "shown"),
    [(None, "-"), (True, "yes"), (42, "42"), (2373.4, "2373"), (46.6, "46.6"), (0.0056, "0.0056")],
)
def test_number_format(value, shown):
    assert results_page.num(value) == shown
