"""`spectralize nodes` from its cache: the same text as a fresh listing, without importing
the science, and renewed when a plugin is installed or a node's source changes."""

import json
import os
import subprocess
import sys
import textwrap

from spectralize.flows.node_listing import _package_files, listing_key

SCIENCE = ("xarray", "dask", "zarr", "spectralize.engine", "spectralize.nodes.reconstruction")


def spectralize_nodes(*args, cache, pythonpath=None):
    """`spectralize nodes` in a fresh interpreter: its output, and which of SCIENCE it imported."""
    code = textwrap.dedent(
        f"""
        import contextlib, io, json, sys
        from spectralize.flows.cli import main
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            code = main(["nodes", *{list(args)!r}])
        print(json.dumps({{"code": code, "out": out.getvalue(),
                           "loaded": [m for m in {SCIENCE!r} if m in sys.modules]}}))
        """
    )
    env = dict(os.environ, SPECTRALIZE_CACHE_DIR=str(cache))
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(pythonpath), env.get("PYTHONPATH", "")])
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr
    import json

    return json.loads(done.stdout.splitlines()[-1])


def write_plugin(root, description):
    """A real installed distribution: a package with one node and its entry point."""
    package = root / "lab_plugin"
    package.mkdir(exist_ok=True)
    (package / "__init__.py").write_text("")
    (package / "nodes.py").write_text(
        textwrap.dedent(
            f"""
            import xarray as xr
            from spectralize.engine import Node

            def gain(dark: xr.Dataset, *, factor: float = 2.0) -> xr.Dataset:
                return dark * factor

            GAIN = Node(name="lab_gain", function=gain, inputs={{"dark": "dark"}},
                        outputs=("gained",), description={description!r})
            """
        )
    )
    info = root / "lab_plugin-1.0.dist-info"
    info.mkdir(exist_ok=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: lab-plugin\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[spectralize.nodes]\nlab_gain = lab_plugin.nodes:GAIN\n")


def test_the_cached_listing_is_the_fresh_one_without_the_science(tmp_path):
    cache = tmp_path / "cache"
    first = spectralize_nodes(cache=cache)
    assert first["code"] == 0 and "reconstruct_image_sets  (version" in first["out"]
    assert "xarray" in first["loaded"]  # rendered: every node was loaded
    assert len(list(cache.glob("nodes-*.txt"))) == 1
    # and the catalogue the command line checks --set against, from the same load
    (catalogue,) = cache.glob("catalogue-*.json")
    checks = json.loads(catalogue.read_text())
    assert checks["flows"]["btf"]["nodes"][0] == "dark_average"
    assert checks["nodes"]["dark_average"]["parameters"]["frames_per_chunk"]["minimum"] == 1

    cached = spectralize_nodes(cache=cache)
    assert cached["out"] == first["out"]
    assert cached["loaded"] == []

    fresh = spectralize_nodes("--refresh", cache=cache)
    assert fresh["out"] == first["out"]
    assert "spectralize.engine" in fresh["loaded"]


def test_an_installed_plugin_and_its_edits_renew_the_listing(tmp_path):
    cache, site = tmp_path / "cache", tmp_path / "site"
    site.mkdir()
    before = spectralize_nodes(cache=cache)["out"]
    assert "lab_gain" not in before

    write_plugin(site, "Multiply by a gain.")
    installed = spectralize_nodes(cache=cache, pythonpath=site)
    assert "lab_gain  (version 1)" in installed["out"]
    assert "Multiply by a gain." in installed["out"]
    assert "--set lab_gain.factor=2.0  (float)" in installed["out"]

    nodes_py = site / "lab_plugin" / "nodes.py"
    stat = nodes_py.stat()
    write_plugin(site, "Multiply the dark frames by a gain.")
    os.utime(nodes_py, ns=(stat.st_atime_ns, stat.st_mtime_ns + 10**9))  # a later edit
    edited = spectralize_nodes(cache=cache, pythonpath=site)
    assert "Multiply the dark frames by a gain." in edited["out"]
    assert "spectralize.engine" in edited["loaded"]  # rendered again, not read from the cache
    assert len(list(cache.glob("nodes-*.txt"))) == 1  # the stale listing is gone


def test_a_broken_plugin_warns_every_time_and_is_not_cached(tmp_path):
    cache, site = tmp_path / "cache", tmp_path / "site"
    write_plugin(site.mkdir() or site, "x")
    (site / "lab_plugin" / "nodes.py").write_text("raise ImportError('no camera driver')\n")
    for _ in range(2):
        env = dict(os.environ, SPECTRALIZE_CACHE_DIR=str(cache), PYTHONPATH=str(site))
        done = subprocess.run(
            [sys.executable, "-m", "spectralize.flows.cli", "nodes"],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
        )
        assert done.returncode == 0, done.stderr
        assert "lab_gain" in done.stderr and "no camera driver" in done.stderr
        assert "dark_average  (version" in done.stdout
    assert not list(cache.glob("nodes-*.txt"))


def test_the_key_follows_the_sources_of_a_package(tmp_path, monkeypatch):
    package = tmp_path / "lab_pkg"
    package.mkdir()
    (package / "__init__.py").write_text("")
    (package / "mod.py").write_text("X = 1\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    key = listing_key(["lab_pkg.mod"])
    assert listing_key(["lab_pkg.mod"]) == key
    (package / "mod.py").write_text("X = 12\n")  # a different size
    assert listing_key(["lab_pkg.mod"]) != key
    assert "lab_pkg" not in sys.modules  # found, not imported


def test_the_key_reads_the_room_a_node_lives_in():
    """`spectralize` is a regular package whose folder holds only its `__init__`; the rooms are
    folders of their own, so a node's sources are found in its room (a stale key once let
    `run --set` refuse a parameter that `spectralize nodes` listed)."""
    files = {p.as_posix() for p in _package_files("spectralize.nodes.calibration.declarations")}
    assert any(f.endswith("nodes/calibration/declarations.py") for f in files)
    assert any(f.endswith("nodes/reconstruction/methods.py") for f in files)
    assert not any(f.endswith("flows/cli.py") for f in files)
