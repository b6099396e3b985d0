"""Real Prefect flow runs (embedded API, SQLite) against real zarr stores."""

import numpy as np
import pytest
import xarray as xr
from pydantic import Field

from spectralize.datasets.dark_stack import make_raw_dark
from spectralize.engine import Node, Parameters, RegisteredNode, Step
from spectralize.engine import discovery as engine
from spectralize.flows import run_flow
from spectralize.flows.runtime import run_steps
from spectralize.schemas import PipelineError, StoreError
from spectralize.store import RunStore

RUNS = {"dark_average": 0, "dark_level": 0}


class DarkLevelParameters(Parameters):
    percentile: float = Field(50.0, ge=0, le=100)


def dark_level(dark: xr.Dataset, *, percentile: float = 50.0) -> xr.Dataset:
    """A downstream node: one dark level per exposure time."""
    RUNS["dark_level"] += 1
    level = dark["mean"].quantile(percentile / 100, dim=("y", "x")).drop_vars("quantile")
    return xr.Dataset({"level": level.astype(np.float32).assign_attrs(units="DN")})


DARK_LEVEL = Node(
    name="dark_level",
    function=dark_level,
    inputs={"dark": "dark"},
    outputs=("dark_level",),
    parameters=DarkLevelParameters,
)


@pytest.fixture
def nodes(monkeypatch):
    """The installed nodes plus a test-only downstream node, counting the real runs."""
    installed = dict(engine.registry(refresh=True))
    dark = installed["dark_average"].node
    counted = Node(**{**dark.__dict__, "function": _counting(dark.function)})
    installed["dark_average"] = RegisteredNode(counted, installed["dark_average"].source)
    installed["dark_level"] = RegisteredNode(DARK_LEVEL, "test")
    monkeypatch.setattr(engine, "_installed", lambda: installed)
    RUNS.update(dark_average=0, dark_level=0)
    return installed


def _counting(function):
    def wrapper(raw_dark, **kwargs):
        RUNS["dark_average"] += 1
        return function(raw_dark, **kwargs)

    wrapper.__signature__ = __import__("inspect").signature(function)
    return wrapper


@pytest.fixture
def store(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    store.write(
        "raw/dark",
        make_raw_dark(frames=6, shape=(5, 6), exposure_times=(0.1, 0.3)),
        fingerprint="raw-v1",
    )
    return store


STEPS = [Step("dark_average"), Step("dark_level")]


def statuses(report):
    return {s.node: s.status for s in report.steps}


def test_flow_runs_then_resumes_and_reruns_dependants(prefect_api, nodes, store):
    first = run_steps(store.path, STEPS)
    assert statuses(first) == {"dark_average": "ran", "dark_level": "ran"}
    assert store.groups() == ["dark", "dark_level", "raw/dark"]
    level_fp = store.fingerprint("dark_level")

    second = run_steps(store.path, STEPS)
    assert statuses(second) == {"dark_average": "skipped", "dark_level": "skipped"}
    assert RUNS == {"dark_average": 1, "dark_level": 1}

    # a changed parameter re-runs the node and everything downstream
    changed = [Step("dark_average", parameters={"ddof": 0}), Step("dark_level")]
    third = run_steps(store.path, changed)
    assert statuses(third) == {"dark_average": "ran", "dark_level": "ran"}
    assert store.fingerprint("dark_level") != level_fp

    # a downstream-only change re-runs only the downstream node
    fourth = run_steps(store.path, [changed[0], Step("dark_level", parameters={"percentile": 90})])
    assert statuses(fourth) == {"dark_average": "skipped", "dark_level": "ran"}
    assert RUNS == {"dark_average": 2, "dark_level": 3}

    # a changed input (new raw data) re-runs everything
    store.write(
        "raw/dark",
        make_raw_dark(frames=6, shape=(5, 6), exposure_times=(0.1, 0.3), seed=9),
        fingerprint="raw-v2",
    )
    fifth = run_steps(store.path, changed)
    assert statuses(fifth) == {"dark_average": "ran", "dark_level": "ran"}


def test_results_in_the_store_match_the_plain_function(prefect_api, nodes, store):
    run_flow("dark", store.path, parameters={"frames_per_chunk": 2})
    stack = store.read("raw/dark").frames.values.astype(float)
    np.testing.assert_allclose(store.read("dark")["mean"].values, stack.mean(axis=1), rtol=1e-6)
    provenance = store.provenance("dark")
    assert provenance["node"] == "dark_average"
    # two exposure times: too few for the line in exposure time, so each time's mean
    assert provenance["parameters"] == {"frames_per_chunk": 2, "ddof": 1, "model": "linear"}
    assert provenance["inputs"] == {"raw/dark": "raw-v1"}


def test_bad_graph_fails_before_anything_is_written(nodes, store):
    before = sorted(p.relative_to(store.path) for p in store.path.rglob("*"))
    with pytest.raises(PipelineError) as info:
        run_flow("dark", store.path, parameters={"frames_per_chunk": 0, "bogus": 1})
    assert "frames_per_chunk" in str(info.value) and "--set bogus" in str(info.value)
    assert sorted(p.relative_to(store.path) for p in store.path.rglob("*")) == before


def test_store_must_exist_when_the_first_node_needs_input(nodes, tmp_path):
    with pytest.raises(StoreError, match="absent.zarr' does not exist .*reads raw/dark"):
        run_flow("dark", tmp_path / "absent.zarr")
    assert not (tmp_path / "absent.zarr").exists()


def test_task_retries_are_configurable(prefect_api, nodes, store, monkeypatch):
    attempts = {"n": 0}
    original = nodes["dark_level"].node

    def flaky(dark, *, percentile=50.0):
        attempts["n"] += 1
        if attempts["n"] == 1:
            raise OSError("transient file-system hiccup")
        return dark_level(dark, percentile=percentile)

    flaky_node = Node(**{**original.__dict__, "function": flaky})
    nodes["dark_level"] = RegisteredNode(flaky_node, "test")
    report = run_steps(store.path, STEPS, retries=1, retry_delay_seconds=0)
    assert statuses(report)["dark_level"] == "ran" and attempts["n"] == 2


def test_not_a_store_is_an_error(nodes, tmp_path):
    (tmp_path / "plain").mkdir()
    with pytest.raises(StoreError, match="not a zarr v3 store"):
        run_flow("dark", tmp_path / "plain")


def test_nightly_flow_processes_every_store_and_resumes(prefect_api, nodes, tmp_path):
    from spectralize.flows.schedule import find_run_stores, process_new_runs

    for name in ("a.zarr", "b.zarr"):
        RunStore.create(tmp_path / name).write(
            "raw/dark", make_raw_dark(frames=4, shape=(4, 4), exposure_times=(0.1,)), fingerprint=name
        )
    (tmp_path / "notes.zarr").mkdir()  # not a run store: ignored
    assert [p.name for p in find_run_stores(tmp_path)] == ["a.zarr", "b.zarr"]
    first = process_new_runs(str(tmp_path), flow_name="dark")
    assert sorted(first.values()) == ["1 node(s) ran, 0 up to date"] * 2
    second = process_new_runs(str(tmp_path), flow_name="dark")
    assert sorted(second.values()) == ["0 node(s) ran, 1 up to date"] * 2
