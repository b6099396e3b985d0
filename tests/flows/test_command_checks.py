"""What the command line checks before anything loads: names with did-you-mean, types,
bounds and allowed values from the parameters' JSON schemas, stores, dask addresses."""

import socket

import pytest

from spectralize.flows.assignments import UsageError
from spectralize.flows.command_checks import (
    check_assignments,
    check_dask_address,
    check_flow,
    check_run,
    check_store,
    shortened,
)

CATALOGUE = {
    "nodes": {
        "solve": {
            "inputs": ["hdr"],
            "parameters": {
                "tolerance": {"anyOf": [{"type": "number", "exclusiveMinimum": 0}, {"type": "null"}]},
                "method": {"type": "string", "enum": ["pcg", "cg", "mixture-pcg"]},
                "size": {"type": "array", "items": {"type": "number"}},
            },
        },
        "make": {"inputs": [], "parameters": {"frames": {"type": "integer", "minimum": 1}}},
    },
    "flows": {
        "all": {"nodes": ["make", "solve"], "inputs": []},
        "only": {"nodes": ["solve"], "inputs": ["hdr"]},
    },
}


def problems(**assignments):
    return check_assignments(assignments, ["make", "solve"], CATALOGUE)


def test_values_that_pydantic_would_take_pass():
    assert problems(**{"solve.tolerance": 1e-3, "tolerance": None, "make.frames": 4.0}) == []
    assert problems(**{"solve.method": "cg", "solve.size": [1, 2.5]}) == []


def test_names_types_bounds_and_choices_are_refused_with_what_was_meant():
    (line,) = problems(**{"solve.tolerence": 1})
    assert (
        line
        == "--set solve.tolerence: node 'solve' has no parameter 'tolerence'; did you mean 'tolerance'?"
    )
    (line,) = problems(**{"solv.tolerance": 1})
    assert "'solv' is not a node; did you mean 'solve'?" in line
    (line,) = problems(**{"make.frames": 0})
    assert line == "--set make.frames: expected an integer >= 1, got 0"
    (line,) = problems(**{"make.frames": "many"})
    assert line == "--set make.frames: expected an integer >= 1, got 'many'"
    (line,) = problems(**{"solve.tolerance": -1})
    assert line == "--set solve.tolerance: expected a number > 0 or null (None), got -1"
    (line,) = problems(**{"solve.method": "mixture-pgc"})
    assert line == (
        "--set solve.method: expected one of: pcg, cg, mixture-pcg, got 'mixture-pgc'; "
        "did you mean 'mixture-pcg'?"
    )
    (line,) = problems(frame=3)
    assert "no node of this flow has a parameter 'frame'; did you mean 'frames'?" in line


def test_flows_stores_and_addresses(tmp_path):
    assert check_flow("all", CATALOGUE) == (["make", "solve"], [])
    assert check_flow("solve", CATALOGUE) == (["solve"], ["hdr"])
    with pytest.raises(UsageError, match="unknown flow or node 'al'; did you mean 'all'?"):
        check_flow("al", CATALOGUE)
    check_run("all", tmp_path / "new.zarr", {}, catalogue=CATALOGUE)  # the flow makes the store
    with pytest.raises(UsageError, match="does not exist; 'only' reads hdr: make the store with"):
        check_run("only", tmp_path / "new.zarr", {}, catalogue=CATALOGUE)  # it reads hdr
    with pytest.raises(UsageError, match=r"2 problems:\n  - .*does not exist.*\n  - --set make"):
        check_run("only", tmp_path / "new.zarr", {"make.frames": 0}, catalogue=CATALOGUE)
    (tmp_path / "capture").mkdir()
    (tmp_path / "capture" / "capture.toml").write_text("")
    with pytest.raises(UsageError, match="spectralize ingest"):
        check_store(tmp_path / "capture")
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    with pytest.raises(UsageError, match=f"cannot reach the dask scheduler at tcp://127.0.0.1:{port}"):
        check_dask_address(f"tcp://127.0.0.1:{port}")
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        check_dask_address(f"tcp://127.0.0.1:{server.getsockname()[1]}")  # answers: fine
    assert shortened([str(i) for i in range(10)], 3) == "0, 1, 2 and 7 more"
