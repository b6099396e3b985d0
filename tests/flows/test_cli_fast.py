"""The command line answers without Prefect (and mostly without matplotlib), its help says
defaults and allowed values, and every default `spectralize nodes` prints parses back."""

import contextlib
import io
import json
import os
import re
import shlex
import socket
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from support.cubes import WAVELENGTH, cube_dataset

from spectralize.engine import registry
from spectralize.flows.assignments import parse_assignments
from spectralize.flows.cli import build_parser, main
from spectralize.flows.pipelines import FLOW_DESCRIPTIONS, FLOWS
from spectralize.store import RunStore

HEAVY = ("prefect", "matplotlib", "rich", "spectralize.engine", "spectralize.flows.runtime")
# What listing the nodes must not import (each costs 0.1-2 s): the flow runtime, reports and
# colour-science (matplotlib), scipy's image filters and optimisers, scikit-image
NOT_FOR_NODES = (
    "prefect",
    "rich",
    "matplotlib",
    "colour",
    "scipy.ndimage",
    "scipy.optimize",
    "skimage",
    "spectralize.flows.runtime",
)


def loaded_after(argv, cwd, modules=HEAVY):
    """Run ``main(argv)`` in a fresh interpreter; the exit code, output, and which of
    ``modules`` were imported."""
    code = textwrap.dedent(
        f"""
        import contextlib, io, json, sys
        from spectralize.flows.cli import main
        out = io.StringIO()
        with contextlib.redirect_stdout(out):
            try:
                code = main({argv!r})
            except SystemExit as exit:
                code = exit.code
        print(json.dumps({{
            "code": code,
            "out": out.getvalue(),
            "loaded": [m for m in {tuple(modules)!r} if m in sys.modules],
        }}))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    run = RunStore.create(tmp_path_factory.mktemp("cli") / "run.zarr")
    values = np.random.default_rng(1).uniform(0.0, 1.0, (2, WAVELENGTH.size, 4, 5))
    run.write("spectra", cube_dataset(values), fingerprint="spectra-fp")
    return run.path


def test_importing_the_cli_imports_nothing_heavy(tmp_path):
    code = f"import sys, spectralize.flows.cli; print([m for m in {HEAVY!r} if m in sys.modules])"
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


@pytest.mark.parametrize("argv", [["--help"], ["run", "--help"], ["export", "--help"]])
def test_help_imports_neither_prefect_nor_the_engine(argv, tmp_path):
    found = loaded_after(argv, tmp_path)
    assert found["code"] == 0
    assert found["loaded"] == []
    assert "usage: spectralize" in found["out"]


@pytest.mark.slow
def test_flows_nodes_validate_and_export_do_not_import_prefect(store, tmp_path):
    flows = loaded_after(["flows"], tmp_path)
    assert flows["code"] == 0 and "btf: full-BTF processing" in flows["out"]
    assert "prefect" not in flows["loaded"] and "matplotlib" not in flows["loaded"]
    assert "spectralize.flows.runtime" not in flows["loaded"]

    nodes = loaded_after(["nodes"], tmp_path)
    assert nodes["code"] == 0 and "--set dark_average.frames_per_chunk=16" in nodes["out"]
    assert not {"prefect", "matplotlib", "spectralize.flows.runtime"} & set(nodes["loaded"])

    valid = loaded_after(["validate", str(store)], tmp_path)
    assert valid["code"] == 0 and "valid" in valid["out"]
    assert not {"prefect", "matplotlib", "spectralize.flows.runtime"} & set(valid["loaded"])
    missing = loaded_after(["validate", str(store), "--flow", "dark"], tmp_path)
    assert missing["code"] == 1  # the dark flow's raw/dark is missing: a problem, not a crash
    assert not {"prefect", "spectralize.flows.runtime"} & set(missing["loaded"])

    export = loaded_after(
        ["export", str(store), str(tmp_path / "cube.nc"), "--format", "netcdf"], tmp_path
    )
    assert export["code"] == 0 and (tmp_path / "cube.nc").is_file()
    assert not {"prefect", "matplotlib", "spectralize.flows.runtime"} & set(export["loaded"])


def test_nodes_lists_every_node_and_parameter_without_heavy_imports(tmp_path):
    found = loaded_after(["nodes"], tmp_path, NOT_FOR_NODES)
    assert found["code"] == 0
    assert found["loaded"] == []
    out = found["out"]
    for name, entry in registry().items():
        assert f"{name}  (version {entry.node.version})" in out
        for field in entry.node.parameters.model_fields:
            assert f"--set {name}.{field}=" in out or f"--set '{name}.{field}=" in out, field
    # the choices of the evaluate node's illuminant, known without colour-science
    import colour

    assert "--set evaluate.illuminant=D65  (str)" in out
    assert f"one of: {', '.join(sorted({'E', *colour.SDS_ILLUMINANTS}))}\n" in out


def test_the_written_out_illuminant_names_are_colour_sciences():
    import colour

    from spectralize.nodes.evaluation.illuminants import ILLUMINANTS

    assert set(ILLUMINANTS) == {"E", *colour.SDS_ILLUMINANTS}
    assert len(ILLUMINANTS) == len(set(ILLUMINANTS))
    # the distributions are colour-science's, loaded on first use ("E" as colour-science has it)
    assert ILLUMINANTS["D65"] is colour.SDS_ILLUMINANTS["D65"]
    assert ILLUMINANTS["E"] is colour.SDS_ILLUMINANTS.get("E")
    assert "D65" in ILLUMINANTS and "D66" not in ILLUMINANTS
    with pytest.raises(KeyError):
        ILLUMINANTS["D66"]


def test_every_printed_default_parses_back_to_the_default(capsys):
    assert main(["nodes"]) == 0
    printed = {}
    for line in capsys.readouterr().out.splitlines():
        if line.strip().startswith("--set "):
            # the word after --set, as a shell hands it over (the description is not read)
            words = shlex.shlex(line.split("--set ", 1)[1], posix=True, punctuation_chars=False)
            words.whitespace_split = True
            setting = words.get_token()
            printed.update(parse_assignments([setting]))
    nodes = registry()
    expected = {
        f"{name}.{field}"
        for name, entry in nodes.items()
        for field in entry.node.parameters.model_fields
    }
    assert set(printed) == expected
    for key, value in printed.items():
        name, _, field = key.partition(".")
        node = nodes[name].node
        parsed = getattr(node.parse_parameters({field: value}), field)
        default = node.parameters.model_fields[field].get_default(call_default_factory=True)
        assert parsed == default, key


def help_of(*argv):
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        build_parser().parse_args([*argv, "--help"])
    return " ".join(out.getvalue().split())  # argparse wraps lines


def test_help_shows_defaults_and_allowed_values():
    run = help_of("run")
    for name in FLOWS:
        assert f"{name} {FLOW_DESCRIPTIONS[name]}" in run
    assert "--retries RETRIES Prefect task retries per node (default: 0)" in run
    export = help_of("export")
    assert "--format {envi,netcdf} one of: envi, netcdf" in export
    assert "cube group (default: spectra)" in export
    serve = help_of("serve")
    assert "(default: 0 2 * * *)" in serve and "(default: 5.0)" in serve
    assert "-v, --verbose" in help_of()


# -- errors in under a second: checked before Prefect and the engine load ------------------


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private listing cache, filled (as after the first `spectralize nodes` or run)."""
    folder = tmp_path_factory.mktemp("cache")
    done = subprocess.run(
        [sys.executable, "-m", "spectralize.flows.cli", "nodes"],
        env={**os.environ, "SPECTRALIZE_CACHE_DIR": str(folder)},
        capture_output=True,
        timeout=300,
    )
    assert done.returncode == 0
    return folder


def timed_error(argv, cwd, cache):
    """Exit code, stderr and the least wall time [s] of three runs of the real command."""
    env = {**os.environ, "SPECTRALIZE_CACHE_DIR": str(cache)}
    best, done = float("inf"), None
    for _ in range(3):
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "spectralize.flows.cli", *argv],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        best = min(best, time.perf_counter() - start)
    return done.returncode, done.stderr, best


def refused_port() -> int:
    """A local TCP port nothing listens on."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


ERRORS = {
    "store path": (["run", "btf", "{tmp}/nope.zarr"], "run store '{tmp}/nope.zarr' does not exist"),
    "flow name": (["run", "btff", "{store}"], "unknown flow or node 'btff'; did you mean 'btf'?"),
    "parameter name": (
        ["run", "btf", "{store}", "--set", "reconstruct_image_sets.tolerence=1e-3"],
        "node 'reconstruct_image_sets' has no parameter 'tolerence'; did you mean 'tolerance'?",
    ),
    "parameter type": (
        ["run", "dark", "{store}", "--set", "dark_average.frames_per_chunk=many"],
        "--set dark_average.frames_per_chunk: expected an integer >= 1, got 'many'",
    ),
    "parameter range": (
        ["run", "btf", "{store}", "--set", "reconstruct_image_sets.tolerance=-1"],
        "--set reconstruct_image_sets.tolerance: expected a number > 0 or null (None), got -1",
    ),
    "method": (
        ["run", "btf", "{store}", "--set", "reconstruct_image_sets.method=mixture-prior-pgc"],
        "got 'mixture-prior-pgc'; did you mean 'mixture-prior-pcg'",
    ),
    "dask address": (
        ["run", "dark", "{store}", "--dask-address", "tcp://127.0.0.1:{port}"],
        "cannot reach the dask scheduler at tcp://127.0.0.1:{port}",
    ),
    "capture folder": (
        ["validate", "{tmp}/capture"],
        "is a capture folder, not a run store; ingest it first: spectralize ingest",
    ),
}


@pytest.mark.timing
@pytest.mark.parametrize("case", ERRORS)
def test_command_line_errors_come_in_under_a_second_and_a_half(case, store, cache, tmp_path):
    (tmp_path / "capture").mkdir()
    (tmp_path / "capture" / "manifest.csv").write_text("file,kind\n")
    words = {"tmp": str(tmp_path), "store": str(store), "port": str(refused_port())}
    argv, message = ERRORS[case]
    code, err, seconds = timed_error([a.format(**words) for a in argv], tmp_path, cache)
    assert code == 2, err
    assert message.format(**words) in err
    assert "Traceback" not in err and err.count("\n") <= 3  # one short message
    assert seconds < 1.5, f"{case}: {seconds:.2f} s"


def test_the_early_errors_load_neither_prefect_nor_the_engine(store, cache, tmp_path, monkeypatch):
    monkeypatch.setenv("SPECTRALIZE_CACHE_DIR", str(cache))
    argv = ["run", "btf", str(store), "--set", "reconstruct_image_sets.tolerence=1e-3"]
    found = loaded_after(argv, tmp_path, (*HEAVY, "xarray", "numpy"))
    assert found["code"] == 2 and found["loaded"] == []


def test_help_has_no_markup_and_lists_each_command_once():
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        build_parser().parse_args(["--help"])
    text = out.getvalue()
    assert "``" not in text and "`" not in text
    for command in ("nodes", "flows", "validate", "clean", "run", "serve", "ingest", "report"):
        assert len(re.findall(rf"^\s+{command}\s", text, re.MULTILINE)) == 1, command
