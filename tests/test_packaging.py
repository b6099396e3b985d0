"""The distribution as a user installs it: every package in the wheel, a version, a working
command line from a clean virtual environment."""

from __future__ import annotations

import email
import os
import re
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from importlib.metadata import Distribution, distributions, version
from pathlib import Path

import pytest
from packaging.requirements import Requirement

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


def _key(name: str) -> str:
    """A distribution's name as requirements compare it (PEP 503)."""
    return re.sub(r"[-_.]+", "-", name).lower()


def _wheel_requirements(wheel: Path) -> list[str]:
    """The ``Requires-Dist`` lines of the wheel's own metadata (not the checkout's)."""
    with zipfile.ZipFile(wheel) as archive:
        (metadata,) = [n for n in archive.namelist() if n.endswith(".dist-info/METADATA")]
        return email.message_from_bytes(archive.read(metadata)).get_all("Requires-Dist") or []


def _requirement_closure(requires: list[str], site: Path) -> tuple[dict[str, Distribution], list[str]]:
    """The distributions of ``site`` that ``requires`` needs, transitively (extras followed,
    environment markers evaluated), and the requirements an installed version misses."""
    installed = {_key(d.metadata["Name"]): d for d in distributions(path=[str(site)])}
    closure: dict[str, set[str]] = {}
    unmet: list[str] = []
    todo = [
        r for r in map(Requirement, requires) if r.marker is None or r.marker.evaluate({"extra": ""})
    ]
    while todo:
        requirement = todo.pop()
        name = _key(requirement.name)
        if name not in installed:
            unmet.append(f"{requirement} (not installed)")
            continue
        found = installed[name].version
        if not requirement.specifier.contains(found, prereleases=True):
            unmet.append(f"{requirement} (installed: {found})")
        extras = closure.get(name)
        if extras is not None and set(requirement.extras) <= extras:
            continue
        extras = closure[name] = (extras or set()) | set(requirement.extras)
        for line in installed[name].requires or []:
            needed = Requirement(line)
            if needed.marker is None or any(needed.marker.evaluate({"extra": e}) for e in extras | {""}):
                todo.append(needed)
    return {name: installed[name] for name in closure}, unmet


def _files(dists) -> set[tuple[str, ...]]:
    """The files the distributions installed into their site-packages, as path parts."""
    parts = set()
    for dist in dists:
        assert dist.files is not None, f"{dist.metadata['Name']} has no RECORD"
        for path in dist.files:
            if path.parts[0] != ".." and "__pycache__" not in path.parts:
                parts.add(tuple(path.parts))
    return parts


def _link(site: Path, target: Path, wanted: set[tuple[str, ...]], others: set[tuple[str, ...]]) -> None:
    """Symbolic links in ``target`` to the files and folders of ``site`` that hold ``wanted``
    files and none of ``others`` (a folder both share, a namespace package, is made and
    filled one level down)."""
    for name in sorted({parts[0] for parts in wanted}):
        mine = {parts[1:] for parts in wanted if parts[0] == name}
        theirs = {parts[1:] for parts in others if parts[0] == name}
        if not theirs or mine == {()}:
            (target / name).symlink_to(site / name)
        else:
            (target / name).mkdir()
            _link(site / name, target / name, mine - {()}, theirs - {()})


@pytest.mark.slow
def test_wheel_installs_into_a_clean_environment_and_runs_a_flow(wheel, prefect_api, tmp_path):
    """The wheel installed alone (no checkout on the path) into an environment that holds only
    what its metadata requires: every node loads and the demo flow runs on the tiny recipe.

    The requirements are not downloaded again: the environment gets links to this one's
    installed copies of the wheel's requirements, followed transitively, each checked against
    the wheel's version ranges; nothing else of this environment (the test tools, the
    checkout's editable install) is linked, so a missing requirement still fails the flow.
    The demo runs on the session's Prefect API (no embedded server to start: the first demo
    of tests/flows/test_cli.py runs on its own one).
    """
    from prefect.settings import PREFECT_API_URL

    requires = _wheel_requirements(wheel)
    assert any(line.startswith("prefect") for line in requires)  # the metadata is the wheel's
    site = Path(sysconfig.get_paths()["purelib"])
    needed, unmet = _requirement_closure(requires, site)
    assert unmet == []
    assert "spectralize" not in needed and "pytest" not in needed

    venv = tmp_path / "venv"
    # without pip of its own: this pip installs into it (``--python``), as the installer only;
    # the new environment sees none of this one's packages but the linked requirements
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    python = venv / "bin" / "python"
    (venv_site,) = venv.glob("lib/python*/site-packages")
    others = [d for d in distributions(path=[str(site)]) if _key(d.metadata["Name"]) not in needed]
    _link(site, venv_site, _files(needed.values()), _files(others))
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
            "--no-deps",
            "--no-index",
            "--disable-pip-version-check",
            str(wheel),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert install.returncode == 0, install.stderr[-3000:]

    work = tmp_path / "work"
    work.mkdir()
    env = {
        k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PREFECT_", "VIRTUAL_ENV"))
    }
    env["PREFECT_HOME"] = str(tmp_path / "prefect")
    env["PREFECT_API_URL"] = PREFECT_API_URL.value()
    env["SPECTRALIZE_CACHE_DIR"] = str(tmp_path / "cache")

    where = subprocess.run(
        [
            str(python),
            "-c",
            "import importlib.util, spectralize, spectralize.flows; print(spectralize.__version__, "
            "spectralize.__file__, spectralize.flows.__file__, importlib.util.find_spec('pytest'))",
        ],
        cwd=work,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert where.returncode == 0, where.stderr
    installed_version, package, flows, pytest_spec = where.stdout.split()
    assert installed_version == spectralize.__version__
    assert all(Path(p).is_relative_to(venv_site) for p in (package, flows))  # not the checkout
    assert pytest_spec == "None"  # the suite's tools are out of the environment's reach

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
