"""Docstrings and comments of library code say what and why, and their examples run.

The contract (``docs/CONTRACT.md``): measurements live in ``docs/benchmarks_notes.md`` and the
benchmarks' JSON, history in ``CHANGELOG.md``. A docstring or comment that carries an issue
number, a temporary path or a measured figure goes stale the day the code or the machine
changes, so this test rejects them in the library's folders. The public entry points'
examples run as doctests.
"""

from __future__ import annotations

import ast
import doctest
import importlib
import io
import re
import tokenize
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("schemas", "store", "engine", "nodes", "datasets", "flows", "spectralize")

_FIGURE = r"(?<![\w.^])\d+(?:[.,]\d+)*(?:\s?-\s?\d+(?:[.,]\d+)*)?\s?"
RULES = {
    "an issue number": re.compile(r"\bissues?\s+#?\d+|(?<![\w&/])#\d+\b", re.IGNORECASE),
    "a temporary path": re.compile(r"/tmp/|/var/tmp/"),
    "a measured time": re.compile(_FIGURE + r"(?:s|ms|µs|min|h)\b(?!-)"),
    "a measured size": re.compile(_FIGURE + r"(?:[kMGT]i?B)\b"),
    "a speed-up": re.compile(r"(?<![\w.^])\d+(?:\.\d+)?(?:-\d+(?:\.\d+)?)?x\b"),
    "a benchmark count": re.compile(r"\b\d+ of (?:the )?(?:benchmark'?s? )?\d+ (?:rows|scenes|cells)"),
    "a benchmark percentage": re.compile(
        r"(?=.*" + _FIGURE + r"%)(?=.*\b(?:median|p95|benchmark|woven|halftone|glossy)\b)",
        re.IGNORECASE,
    ),
}
"""What a docstring or comment of library code must not hold."""

ALLOWED = (
    re.compile(r"``[^`]*``"),  # a literal: an example of what a message or format looks like
)
"""Parts of a line that are left out before the rules apply."""

PAPER = re.compile(r"\bpaper\b|\bFig(?:ure|\.)|\bsec\.|\bsection\b", re.IGNORECASE)
"""A line that quotes the paper's own figures (its capture times) is a citation, not a
measurement of this project."""


def _texts(path: Path) -> Iterator[tuple[int, str]]:
    """Every comment and every string statement (docstrings, attribute docstrings) of a
    module, line by line, with its line number."""
    source = path.read_text()
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type == tokenize.COMMENT:
            yield token.start[0], token.string
    for node in ast.walk(ast.parse(source)):
        if (
            isinstance(node, ast.Expr)
            and isinstance(node.value, ast.Constant)
            and isinstance(node.value.value, str)
        ):
            for offset, line in enumerate(node.value.value.splitlines()):
                yield node.lineno + offset, line


def violations(path: Path, root: Path = ROOT) -> list[str]:
    """``path:line: what: text`` for each line of a module's comments and docstrings that
    breaks a rule of :data:`RULES`."""
    found = []
    for line_number, text in _texts(path):
        if PAPER.search(text):
            continue
        kept = text
        for allowed in ALLOWED:
            kept = allowed.sub(" ", kept)
        for what, rule in RULES.items():
            if rule.search(kept):
                where = path.relative_to(root)
                found.append(f"{where}:{line_number}: {what}: {text.strip()}")
    return found


def _library_modules() -> list[Path]:
    return sorted(path for room in LIBRARY for path in (ROOT / room).rglob("*.py"))


def test_library_docstrings_and_comments_hold_no_measurements_or_history():
    found = [line for path in _library_modules() for line in violations(path)]
    assert not found, (
        "docstrings and comments say what and why; measurements go to "
        "docs/benchmarks_notes.md, history to CHANGELOG.md:\n" + "\n".join(found)
    )


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("# the batch took 60 s (issue 27)", "an issue number"),
        ("# see #27", "an issue number"),
        ("study in /tmp/pooled/notes.md", "a temporary path"),
        ("# 2048^2 peaks at 7.7 GB", "a measured size"),
        ("a refit of 0.26 s per set", "a measured time"),
        ("1.21-1.31x the default alone", "a speed-up"),
        ("lower median on 7 of 8 rows", "a benchmark count"),
        ("the median falls 17-26 % on woven sets", "a benchmark percentage"),
    ],
)
def test_each_rule_catches_what_it_names(tmp_path, text, what):
    module = tmp_path / "probe.py"
    module.write_text(f"x = 1  {text}\n" if text.startswith("#") else f'"""{text}"""\n')
    found = violations(module, tmp_path)
    assert any(f": {what}: " in line for line in found), found


@pytest.mark.parametrize(
    "text",
    [
        "wavelengths 410-720 nm in 10 nm steps",
        "the paper's reference capture of one image (226.212 s)",
        "a progress line reads ``iteration 12 (40 % of its work), about 8 s left``",
        "a 3 x 3 matrix per image",
        "Default: 10 % of the top of the stretched interval.",
    ],
)
def test_physics_paper_quotes_and_format_examples_are_allowed(tmp_path, text):
    module = tmp_path / "probe.py"
    module.write_text(f'"""{text}"""\n')
    assert violations(module, tmp_path) == []


DOCTESTED = (
    "spectralize.nodes.reconstruction.api",
    "spectralize.nodes.reconstruction.methods",
    "spectralize.store.run_store",
)
"""The public entry points whose examples a user copies first: ``reconstruct``, the method
tables, ``open_run``."""


@pytest.mark.parametrize("name", DOCTESTED)
def test_the_examples_of_the_public_entry_points_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # an example that writes a store writes it here
    module = importlib.import_module(name)
    finder = doctest.DocTestFinder()
    runner = doctest.DocTestRunner(
        optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE, verbose=False
    )
    tests = [test for test in finder.find(module, name) if test.examples]
    run = [
        example for test in tests for example in test.examples if not example.options.get(doctest.SKIP)
    ]
    assert run, f"{name} has no example that runs (all are missing or skipped)"
    output = io.StringIO()
    for test in tests:
        runner.run(test, out=output.write)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, output.getvalue()
