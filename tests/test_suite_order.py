"""The suite's own order: the long modules ``make test`` hands out first exist."""

from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_every_long_module_listed_in_conftest_exists(request):
    conftest = request.config.pluginmanager.get_plugin(str(TESTS / "conftest.py"))
    assert conftest is not None and len(conftest.LONG_MODULES) > 0
    assert [module for module in conftest.LONG_MODULES if not (TESTS / module).is_file()] == []
