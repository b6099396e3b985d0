"""The method tables and the one resolution of a method with its options (resolve_method)."""

from __future__ import annotations

import pickle

import dask
import numpy as np
import pytest

from spectralize.nodes.reconstruction import (
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
    ResolvedMethod,
    reconstruct,
    resolve_method,
)
from spectralize.nodes.reconstruction.methods import BASELINE_METHODS, get_method
from spectralize.schemas.errors import ReconstructionError
from spectralize.schemas.run import SPECTRA


def test_resolve_method_applies_the_default_once_and_takes_a_name_a_record_or_a_resolved_one():
    default = resolve_method()
    assert isinstance(default, ResolvedMethod) and default.name == DEFAULT_METHOD
    assert dict(default.settings) == dict(RECONSTRUCTION_METHODS[DEFAULT_METHOD].settings)
    assert dict(default.given) == {}
    record = RECONSTRUCTION_METHODS["guided-prior-pcg"]
    by_name, by_record = resolve_method("guided-prior-pcg"), resolve_method(record)
    assert by_name == by_record and by_name.method is record
    assert resolve_method(by_name) is by_name  # passed on, not resolved again
    assert resolve_method(None, k=4).name == DEFAULT_METHOD


def test_options_are_laid_over_the_presets_settings_and_recorded_as_given():
    resolved = resolve_method("guided-prior-pcg", prior=0.3, k=4)
    preset = RECONSTRUCTION_METHODS["guided-prior-pcg"].settings
    assert resolved.settings == {**preset, "prior": 0.3, "k": 4}
    assert dict(resolved.given) == {"prior": 0.3, "k": 4}
    assert preset["prior"] == 0.1  # the table is left as it is
    # more options on a resolved record: both sets resolved together
    more = resolve_method(resolved, k=5, tolerance=1e-2)
    assert dict(more.given) == {"prior": 0.3, "k": 5, "tolerance": 1e-2}
    assert more.settings["k"] == 5 and more.settings["prior"] == 0.3
    # used(): every option in the order of the method's options, run inputs None
    used = resolved.used()
    assert list(used) == list(resolved.options) and used["initial"] is None
    assert used == {**RECONSTRUCTION_METHODS["guided-prior-pcg"].defaults(), "prior": 0.3, "k": 4}


def test_unknown_options_name_the_closest_and_the_methods_that_take_them():
    with pytest.raises(ReconstructionError, match="did you mean 'tolerance'") as info:
        resolve_method("paper-cg", tolerence=1e-3)
    assert "its options are: " in str(info.value)
    with pytest.raises(ReconstructionError, match=r"unknown option\(s\) \['prior'\]") as info:
        resolve_method("paper-cg", prior=0.1)
    assert "'prior' is an option of" in str(info.value)
    with pytest.raises(ReconstructionError, match="unknown method 'natural-prior'.*natural-prior-pcg"):
        resolve_method("natural-prior")
    with pytest.raises(ReconstructionError, match="expected a method name"):
        resolve_method(3)


def test_values_are_checked_once_and_run_inputs_are_no_settings():
    with pytest.raises(ReconstructionError, match="set_model: expected one of"):
        resolve_method(DEFAULT_METHOD, set_model="shared")
    with pytest.raises(ReconstructionError, match="k: expected an integer >= 1"):
        resolve_method("block-jacobi-pcg", k=0)
    with pytest.raises(ReconstructionError, match="tolerance: expected a finite number > 0"):
        resolve_method("block-jacobi-pcg", tolerance=-1.0)
    with pytest.raises(ReconstructionError, match=r"\['initial'\] are inputs of one run"):
        resolve_method("block-jacobi-pcg", initial=None)
    resolved = resolve_method("block-jacobi-pcg")
    assert resolved.run_inputs(initial=None) == {"initial": None}
    with pytest.raises(ReconstructionError, match=r"unknown option\(s\) \['endmembers'\]"):
        resolved.run_inputs(endmembers=None)
    with pytest.raises(ReconstructionError, match=r"\['k'\] are settings"):
        resolved.run_inputs(k=3)


def test_a_resolved_method_pickles_and_tokenizes_by_its_settings():
    resolved = resolve_method(DEFAULT_METHOD, k=4, set_model="independent")
    again = pickle.loads(pickle.dumps(resolved))  # a dask.distributed task pickles it
    assert again == resolved and dict(again.given) == {"k": 4, "set_model": "independent"}
    assert dask.base.tokenize(again) == dask.base.tokenize(resolved)
    assert dask.base.tokenize(resolve_method(DEFAULT_METHOD, k=5)) != dask.base.tokenize(resolved)


def test_reconstruct_takes_a_name_a_record_or_a_resolved_method_alike(scene_factory):
    scene = scene_factory(size=16, n_wavelength=5, n_images=2, shots={0: [0, 1, 2, 3, 4], 1: [2]})
    data = (scene.rgb, scene.bands, scene.camera_matrix)
    by_name = reconstruct(*data, method="block-jacobi-pcg", k=4, tolerance=1e-4)
    resolved = resolve_method("block-jacobi-pcg", k=4, tolerance=1e-4)
    for method, options in (
        (resolved, {}),
        (get_method("block-jacobi-pcg"), {"k": 4, "tolerance": 1e-4}),
        (resolve_method("block-jacobi-pcg", k=4), {"tolerance": 1e-4}),
    ):
        out = reconstruct(*data, method=method, **options)
        np.testing.assert_array_equal(out.values, by_name.values)
        assert out.attrs["method"] == "block-jacobi-pcg" and out.attrs["k"] == 4
    baseline = reconstruct(*data, method=BASELINE_METHODS["wiener"])
    assert baseline.attrs["method"] == "wiener"


def test_the_spectra_attrs_come_from_the_schema(scene_factory):
    scene = scene_factory(size=12, n_wavelength=4)
    out = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method="pseudo-inverse")
    assert {n: out.attrs[n] for n in ("units", "long_name")} == SPECTRA.spec("radiance").attrs
    assert out["wavelength"].attrs == SPECTRA.spec("wavelength").attrs
    assert SPECTRA.spec("radiance").attrs == {"units": "1", "long_name": "relative spectral radiance"}
