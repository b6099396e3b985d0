"""The suite's own order: the long modules ``make test`` hands out first exist, and its
second pass, which collects only the modules whose text marks tests ``timing``, finds every
test so marked."""

import subprocess
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_every_long_module_listed_in_conftest_exists(request):
    conftest = request.config.pluginmanager.get_plugin(str(TESTS / "conftest.py"))
    assert conftest is not None and len(conftest.LONG_MODULES) > 0
    assert [module for module in conftest.LONG_MODULES if not (TESTS / module).is_file()] == []


def test_the_timing_pass_collects_the_modules_that_mark_timing_tests(request):
    # the Makefile's TIMING_MODULES, as make expands it, against the modules holding the text
    # the collection checks (conftest.check_timing_modules) for every test marked timing
    conftest = request.config.pluginmanager.get_plugin(str(TESTS / "conftest.py"))
    found = subprocess.run(
        ["make", "-s", "--no-print-directory", "-f", "-", "print-timing-modules"],
        input="include Makefile\nprint-timing-modules:\n\t@echo $(TIMING_MODULES)\n",
        cwd=TESTS.parent,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.split()
    holding = {
        path.relative_to(TESTS.parent).as_posix()
        for path in TESTS.rglob("test_*.py")
        if conftest.TIMING_MARK in path.read_text()
    }
    assert len(holding) >= 3 and sorted(found) == sorted(holding)
