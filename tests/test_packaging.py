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
from dataclasses import dataclass
from importlib.metadata import Distribution, distributions, version
from pathlib import Path

import pytest
from packaging.requirements import Requirement

import spectralize
from spectralize.store import RunStore

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


@dataclass
class Installed:
    """The wheel installed into a new environment, and how to run its command line."""

    venv: Path
    site: Path  # its site-packages
    unmet: list[str]  # the wheel's requirements this environment's versions miss
    env: dict[str, str]  # the environment of its commands: none of the suite's Prefect settings
    work: Path  # their working folder

    def run(self, *args: str, api: str | None = None, timeout: int = 300, **env: str):
        """``spectralize *args`` of the new environment, with ``env`` added to its variables;
        with ``api``, on that Prefect API, else on its own embedded one, as a user's first run."""
        if api is not None:
            env["PREFECT_API_URL"] = api
        return subprocess.run(
            [str(self.venv / "bin" / "spectralize"), *args],
            cwd=self.work,
            env={**self.env, **env},
            capture_output=True,
            text=True,
            timeout=timeout,
        )


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Installed:
    """The wheel installed alone (no checkout on the path) into an environment that holds only
    what its metadata requires.

    The requirements are not downloaded again: the environment gets links to this one's
    installed copies of the wheel's requirements, followed transitively from the wheel's own
    metadata; nothing else of this environment (the test tools, the checkout's editable
    install) is linked, so a requirement missing from the metadata still fails the flow.
    """
    root = tmp_path_factory.mktemp("installed")
    site = Path(sysconfig.get_paths()["purelib"])
    needed, unmet = _requirement_closure(_wheel_requirements(wheel), site)
    venv = root / "venv"
    # without pip of its own: this pip installs into it (``--python``), as the installer only;
    # the new environment sees none of this one's packages but the linked requirements
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=300)
    (venv_site,) = venv.glob("lib/python*/site-packages")
    others = [d for d in distributions(path=[str(site)]) if _key(d.metadata["Name"]) not in needed]
    _link(site, venv_site, _files(needed.values()), _files(others))
    install = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "--python",
            str(venv / "bin" / "python"),
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
    env = {
        k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "PREFECT_", "VIRTUAL_ENV"))
    }
    env["PREFECT_HOME"] = str(root / "prefect")
    env["SPECTRALIZE_CACHE_DIR"] = str(root / "cache")
    (root / "work").mkdir()
    return Installed(venv, venv_site, unmet, env, root / "work")


@pytest.fixture(scope="module")
def first_demo(installed):
    """``spectralize demo`` of the installed wheel on the tiny recipe, as a user runs it first:
    on its own embedded Prefect server. Run once for the module: the tests below read its
    output and its store (the demo run is the longest command of the suite)."""
    return installed.run("demo", "--set", "simulate.recipe=tiny", timeout=900)


@pytest.mark.slow
def test_wheel_installs_into_a_clean_environment_and_runs_a_flow(wheel, installed, first_demo, tmp_path):
    """pip install of the wheel alone (no checkout on the path), into an environment of only
    its requirements, each in its version range: every node loads and the demo flow runs on
    the tiny recipe."""
    requires = _wheel_requirements(wheel)
    assert any(line.startswith("prefect") for line in requires)  # the metadata is the wheel's
    assert installed.unmet == []
    where = subprocess.run(
        [
            str(installed.venv / "bin" / "python"),
            "-c",
            "import importlib.util, spectralize, spectralize.flows; print(spectralize.__version__, "
            "spectralize.__file__, spectralize.flows.__file__, importlib.util.find_spec('pytest'))",
        ],
        cwd=installed.work,
        env=installed.env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert where.returncode == 0, where.stderr
    installed_version, package, flows, pytest_spec = where.stdout.split()
    assert installed_version == spectralize.__version__
    assert all(Path(p).is_relative_to(installed.site) for p in (package, flows))  # not the checkout
    assert pytest_spec == "None"  # the suite's tools are out of the environment's reach

    # an empty cache: the listing is made by loading every node (not the demo's cached one)
    nodes = installed.run("nodes", SPECTRALIZE_CACHE_DIR=str(tmp_path / "cache"))
    assert nodes.returncode == 0, nodes.stderr
    assert "failed to load" not in nodes.stdout + nodes.stderr
    for name in _entry_point_nodes():
        assert f"{name}  (version" in nodes.stdout, f"node {name} missing from the installed listing"

    assert first_demo.returncode == 0, first_demo.stderr[-3000:]
    assert "reconstruct_image_sets   ran" in first_demo.stdout
    assert (installed.work / "demo" / "run-report" / "index.html").is_file()


def tree(path: Path):
    return sorted(
        (p.relative_to(path).as_posix(), p.stat().st_mtime_ns) for p in path.rglob("*") if p.is_file()
    )


@pytest.mark.slow
def test_demo_runs_then_skips(installed, first_demo, prefect_api):
    """The command line end to end, from the installed wheel (real Prefect, real zarr): the
    first demo (the module's, shared with the test above rather than run twice), the runs
    after it on the session's API, as what they check (skips, a changed parameter) is the
    store's; bad input."""
    from prefect.settings import PREFECT_API_URL

    api = PREFECT_API_URL.value()
    work = installed.work
    first = first_demo
    assert first.returncode == 0, first.stderr
    assert "simulate                 ran" in first.stdout
    assert "dark_average             ran" in first.stdout
    store = work / "demo" / "run.zarr"
    assert f"results: {store}" in first.stdout
    for node in ("recover_rgb_oecf", "calibrate_bands", "reconstruct_image_sets", "evaluate"):
        assert f"{node:<24} ran" in first.stdout
    report = work / "demo" / "run-report" / "index.html"
    assert f"report: {report}" in first.stdout and report.is_file()
    # not a terminal: progress as plain lines on stderr, the images written (the time left
    # from the second region on: tests/flows/test_progress.py); Prefect's INFO lines stay off
    assert "[1/14] simulate" in first.stderr and "[14/14] report" in first.stderr
    written = re.findall(
        r"reconstruct_image_sets: spectra: ([\d,]+)/([\d,]+) images written", first.stderr
    )
    assert len(written) >= 2 and written[0][0] != written[0][1] and written[-1][0] == written[-1][1]
    assert "Finished in state" not in first.stderr and "| INFO" not in first.stderr

    second = installed.run("demo", "--set", "simulate.recipe=tiny", api=api)
    assert second.returncode == 0, second.stderr
    assert "simulate                 skipped" in second.stdout
    assert "dark_average             skipped" in second.stdout
    assert "ran " not in second.stdout

    valid = installed.run("validate", str(store))
    assert valid.returncode == 0 and "valid" in valid.stdout

    # bad input: unknown flow, unknown parameter, bad value -> non-zero, all listed, no writes
    before = tree(store)
    unknown = installed.run("run", "nope", str(store))
    assert unknown.returncode == 2
    assert "unknown flow or node 'nope'" in unknown.stderr
    assert "flows: btf, calibrate, dark, demo" in unknown.stderr  # nodes: counted, not listed
    bad = installed.run(
        "run", "dark", str(store), "--set", "bogus=1", "--set", "dark_average.frames_per_chunk=0"
    )
    assert bad.returncode == 2
    assert "--set bogus" in bad.stderr and "dark_average.frames_per_chunk" in bad.stderr
    assert tree(store) == before

    # a changed parameter re-runs the node through `run`
    rerun = installed.run("run", "dark", str(store), "--set", "ddof=0", "-v", api=api)
    assert rerun.returncode == 0, rerun.stderr
    assert "| INFO" in rerun.stderr  # -v: Prefect's lines instead of the progress lines
    assert not re.search(r"^\[1/1\] dark_average", rerun.stderr, re.MULTILINE)
    assert "dark_average             ran" in rerun.stdout
    assert RunStore.open(store).provenance("dark")["parameters"]["ddof"] == 0
