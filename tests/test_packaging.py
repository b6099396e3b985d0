"""The distribution as a user installs it: every package in the wheel, a version, a working
command line from a clean virtual environment."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
import zipfile
from importlib.metadata import version
from pathlib import Path

import pytest

import spectralize

ROOT = Path(__file__).resolve().parents[1]
ROOMS = ("schemas", "store", "engine", "nodes", "datasets", "flows")


def _python_folders(room: str) -> list[Path]:
    return sorted(
        {path.parent for path in (ROOT / room).rglob("*.py") if "__pycache__" not in path.parts}
    )


def _entry_point_nodes() -> dict[str, str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    return dict(project["entry-points"]["spectralize.nodes"])


def test_every_room_is_a_top_level_package_that_setup_maps():
    found = {init.parent.name for init in ROOT.glob("*/__init__.py")} - {"spectralize"}
    assert found == set(ROOMS)
    assert all(f'"{room}"' in (ROOT / "setup.py").read_text() for room in ROOMS)


@pytest.mark.parametrize("room", ROOMS)
def test_every_folder_of_python_files_is_a_package(room):
    """setup.py finds packages by their ``__init__.py``; a folder without one would be left out
    of the wheel (as `estimators` and `scenes` once were)."""
    missing = [
        p.relative_to(ROOT).as_posix()
        for p in _python_folders(room)
        if not (p / "__init__.py").is_file()
    ]
    assert missing == []


def test_version_is_the_distribution_version():
    assert spectralize.__version__ == version("spectralize")
    assert spectralize.__version__.count(".") >= 2


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(out), str(ROOT)],
        check=True,
        capture_output=True,
        text=True,
        timeout=600,
    )
    (found,) = out.glob("spectralize-*.whl")
    return found


@pytest.mark.slow
def test_wheel_holds_every_module_and_data_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for room in ROOMS:
        for path in (ROOT / room).rglob("*.py"):
            if "__pycache__" in path.parts:
                continue
            assert "spectralize/" + path.relative_to(ROOT).as_posix() in names
    assert "spectralize/__init__.py" in names
    assert "spectralize/flows/templates/report.html.j2" in names
    assert not any(name.startswith(("tests/", "benchmarks/", "spectralize/tests/")) for name in names)


@pytest.mark.slow
def test_wheel_installs_into_a_clean_environment_and_runs_a_flow(wheel, tmp_path):
    """pip install of the wheel alone (no checkout on the path): every node loads and the demo
    flow runs on the tiny recipe."""
    venv = tmp_path / "venv"
    # without pip of its own: this pip installs into it (``--python``), as the installer only;
    # the new environment sees none of this one's packages
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    # --no-compile: pip would byte-compile every file of every dependency (about half the
    # install's time); the modules the commands below import are compiled as they load
    install = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(python),
            "install",
            "--quiet",
            "--no-compile",
            "--disable-pip-version-check",
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=1200,
    )
    assert install.returncode == 0, install.stderr[-3000:]

    work = tmp_path / "work"
    work.mkdir()
    env = {
        k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PREFECT_", "VIRTUAL_ENV"))
    }
    env["PREFECT_HOME"] = str(tmp_path / "prefect")
    env["SPECTRALIZE_CACHE_DIR"] = str(tmp_path / "cache")

    where = subprocess.run(
        [
            str(python),
            "-c",
            "import spectralize, spectralize.flows; print(spectralize.__version__, spectralize.flows.__file__)",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert where.returncode == 0, where.stderr
    assert where.stdout.split()[0] == spectralize.__version__
    assert str(venv) in where.stdout and str(ROOT) not in where.stdout

    spectralize_cli = str(venv / "bin" / "spectralize")
    nodes = subprocess.run(
        [spectralize_cli, "nodes"], cwd=work, env=env, capture_output=True, text=True, timeout=300
    )
    assert nodes.returncode == 0, nodes.stderr
    assert "failed to load" not in nodes.stdout + nodes.stderr
    for name in _entry_point_nodes():
        assert f"{name}  (version" in nodes.stdout, f"node {name} missing from the installed listing"

    demo = subprocess.run(
        [spectralize_cli, "demo", "--set", "simulate.recipe=tiny"],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert demo.returncode == 0, demo.stderr[-3000:]
    assert "reconstruct_image_sets   ran" in demo.stdout
    assert (work / "demo" / "run-report" / "index.html").is_file()
