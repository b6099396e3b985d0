"""``validate --flow btf`` saturates at each RGB camera's white level, as ``run btf`` does.

The tiny simulated run with its RGB frames (scene and targets) clipped at ``WHITE`` < 1023, the
top code of its 10-bit cameras, capture.toml saying nothing of it: the white level is found
from the data (a pile-up of codes in the longest exposures). A frame entirely at the white
level carries no information, as one entirely at the top code: ``validate --flow btf`` lists
it and ``run btf`` refuses it in the same words before computing the response.
"""

import functools

import numpy as np
import pytest
import xarray as xr

from spectralize.flows import cli
from spectralize.flows.preflight import flow_value_problems
from spectralize.store import RunStore

WHITE = 1000
TARGETS = ("raw/colour_checker", "raw/white_reference")


@functools.cache
def clipped_run() -> dict[str, xr.Dataset]:
    """The raw groups btf reads, every RGB value clipped at WHITE."""
    from spectralize.flows.pipelines import flow_inputs
    from spectralize.nodes.simulation.assembly import simulate_run
    from spectralize.nodes.simulation.recipes import get_recipe

    run = simulate_run(get_recipe("tiny"))
    groups = {group: run[group].load() for group in flow_inputs("btf")}
    for group, name in (("raw/rgb", "counts"), *((t, "rgb_counts") for t in TARGETS)):
        ds = groups[group]
        groups[group] = ds.assign({name: ds[name].clip(max=WHITE).astype(ds[name].dtype)})
    return groups


def clipped_store(path, saturated_frame: bool) -> RunStore:
    """A store of :func:`clipped_run`; ``saturated_frame``: image 2, exposure 1 entirely at WHITE."""
    store = RunStore.create(path)
    for group, ds in clipped_run().items():
        if group == "raw/rgb" and saturated_frame:
            ds = ds.copy(deep=True)
            ds["counts"][{"image": 2, "exposure": 1}] = WHITE
        store.write(group, ds, fingerprint=f"sim-{group}")
    return store


def listed(stderr: str) -> list[str]:
    """The problems ``validate`` lists (its ``  - `` lines)."""
    return [line[4:] for line in stderr.splitlines() if line.startswith("  - ")]


def test_a_clipped_capture_without_such_frames_passes_validate(tmp_path):
    assert flow_value_problems(clipped_store(tmp_path / "run.zarr", False), "btf") == []


@pytest.mark.slow
def test_a_frame_entirely_at_the_white_level_is_refused_by_validate_and_run_alike(
    prefect_api, tmp_path, capsys
):
    store = clipped_store(tmp_path / "run.zarr", True)
    validate = cli.main(["validate", str(store.path), "--flow", "btf"])
    checked = capsys.readouterr().err
    run = cli.main(["run", "btf", str(store.path)])
    ran = capsys.readouterr().err
    assert validate == 1, checked
    problems = listed(checked)
    saturation = WHITE - 3  # the white level less its noise margin (3 DN at 10 bits)
    assert problems[0].startswith(
        "recover_rgb_oecf: raw/rgb:counts: frame image=2, exposure=1, channel=0 "
        f"(exposure_time 0.003 s) is entirely saturated (>= saturation = {saturation})"
    ), checked
    assert run == 2 and "in node 'recover_rgb_oecf' (computing)" in ran, ran
    for line in problems:  # the same text, line by line: the refusal run gives
        assert line in ran, (line, ran)
    assert not store.has("calibration/oecf_rgb")
    assert np.all(store.read("raw/rgb")["counts"].values <= WHITE)
