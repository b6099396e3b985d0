"""Spectra stored at the precision their schema declares: within the stated bound, stated in
the attrs, checked by validate, the same for every region of a resumed write, and stores
written before (lossless) still valid."""

import dataclasses
import json
import warnings

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr
import zarr
from support.cubes import cube_dataset

from spectralize.schemas import Precision
from spectralize.schemas.run import SPECTRA, SPECTRA_PRECISION
from spectralize.store.precision import excess_precision, round_mantissa, round_to_peak

# the contract before the cube declared a precision: what a store written then followed
LOSSLESS_SPECTRA = dataclasses.replace(
    SPECTRA,
    variables=tuple(dataclasses.replace(s, precision=None) for s in SPECTRA.variables),
)


def radiance(images=3, size=24, seed=0):
    """Smooth spectra over five decades of brightness, with zeros and pixels without a value."""
    rng = np.random.default_rng(seed)
    wavelength = np.linspace(0, 1, 32)[None, :, None, None]
    shape = rng.random((images, 1, size, size)) * 3
    brightness = 10.0 ** rng.uniform(-3, 2, (images, 1, size, size))
    values = (brightness * (1 + 0.5 * np.sin(6 * wavelength + shape))).astype(np.float32)
    values[0, :, 0, 0] = np.nan
    values[1, :, 1, 1] = 0
    return values


def test_round_mantissa_is_bit_rounding_within_half_a_unit_of_the_last_kept_bit():
    from numcodecs import BitRound

    values = radiance()
    for keepbits in (4, 10, 16):
        rounded = round_mantissa(values, keepbits)
        assert np.array_equal(  # the standard algorithm: numcodecs' BitRound
            rounded.view(np.uint32),
            BitRound(keepbits).encode(values).view(np.uint32).reshape(values.shape),
            equal_nan=False,
        )
        nonzero = np.isfinite(values) & (values != 0)
        error = np.abs(rounded[nonzero].astype(float) - values[nonzero]) / values[nonzero]
        assert error.max() <= 2.0 ** -(keepbits + 1)
        assert excess_precision(rounded, keepbits) == 0 < excess_precision(values, keepbits)
        assert np.array_equal(round_mantissa(rounded, keepbits), rounded, equal_nan=True)
    special = np.array([np.nan, np.inf, -np.inf, 0.0, -0.0, np.finfo(np.float32).max], np.float32)
    assert np.array_equal(
        round_mantissa(special, 10).view(np.uint32), special.view(np.uint32)
    )  # kept bit for bit


@pytest.mark.parametrize("resumable", [None, "image"])
def test_a_cube_is_stored_within_the_bound_its_attrs_state(store, resumable):
    computed = radiance()
    ds = cube_dataset(computed)
    if resumable:
        ds = ds.chunk({"image": 1})
    store.write("spectra", ds, fingerprint="fp", resumable_along=resumable)

    stored = store.read("spectra")["radiance"]
    assert stored.attrs["precision_keepbits"] == SPECTRA_PRECISION.keepbits == 10
    bound = stored.attrs["precision_bound_relative"]
    assert bound == SPECTRA_PRECISION.relative_bound == 2.0**-11
    values, nonzero = stored.values, np.isfinite(computed) & (computed != 0)
    assert np.array_equal(np.isfinite(values), np.isfinite(computed))
    error = np.abs(values[nonzero].astype(float) - computed[nonzero]) / computed[nonzero]
    assert error.max() <= bound and (values[computed == 0] == 0).all()
    assert excess_precision(values, 10) == 0  # rounded, as stated
    meta = json.loads((store.path / "spectra" / "radiance" / "zarr.json").read_text())
    codecs = [c["name"] for c in meta["codecs"]]
    assert codecs == ["bytes", "blosc"] and meta["codecs"][1]["configuration"]["shuffle"] == "bitshuffle"
    # the coordinates and other arrays keep every bit
    assert np.array_equal(store.read("spectra")["theta_o"].values, ds["theta_o"].values)
    assert store.validate(deep=True) == []


def test_precision_attrs_are_only_where_the_store_rounded(store):
    """A claim copied from a rounded cube onto an array the store keeps whole is dropped."""
    ds = cube_dataset(radiance())
    ds["confidence"] = ds["radiance"].isel(wavelength=0).drop_vars("wavelength")
    ds["confidence"].attrs = {"units": "1", **Precision(10).attrs}
    store.write("spectra", ds, fingerprint="fp")
    got = store.read("spectra")
    assert "precision_keepbits" not in got["confidence"].attrs
    assert np.array_equal(got["confidence"].values, ds["confidence"].values, equal_nan=True)


def test_a_store_written_before_the_precision_is_valid_and_read_as_it_is(store):
    """Lossless spectra (float32 + zstd, no precision attrs) meet every bound: valid, and up
    to date (the fingerprint has no part in the precision), so a flow does not recompute them."""
    from spectralize.flows.steps import expected_outputs

    computed = radiance()
    expected = expected_outputs(
        "reconstruct_image_sets",
        {},
        {"spectra": "spectra"},
        {
            g: g
            for g in ("hdr", "bands", "camera_matrix", "image_sets", "spectra_seed", "endmember_library")
        },
    )["spectra"]
    store.write("spectra", cube_dataset(computed), schema=LOSSLESS_SPECTRA, fingerprint=expected)
    meta = json.loads((store.path / "spectra" / "radiance" / "zarr.json").read_text())
    assert [c["name"] for c in meta["codecs"]] == ["bytes", "zstd"]
    stored = store.read("spectra")["radiance"]
    assert "precision_keepbits" not in stored.attrs
    assert np.array_equal(stored.values.view(np.uint32), computed.view(np.uint32))
    assert excess_precision(stored.values, 10) > 0
    assert store.validate(deep=True) == []
    assert store.fingerprint("spectra") == expected  # what the step expects: up to date


def test_a_resumed_write_rounds_the_regions_staged_before_it_alike(store):
    """Regions staged by an interrupted write (full precision, whichever version staged them)
    are rounded with the rest when the resumed write packs them: one precision per array."""
    computed = radiance(images=4)
    calls = []

    def lazy(fail_at=None):
        def block(i):
            calls.append(i)
            if i == fail_at:
                raise RuntimeError(f"crash in region {i}")
            return computed[i : i + 1]

        pieces = [da.from_delayed(dask.delayed(block)(i), (1, 32, 24, 24), np.float32) for i in range(4)]
        ds = cube_dataset(computed)
        return ds.assign(radiance=(ds.radiance.dims, da.concatenate(pieces), ds.radiance.attrs))

    with pytest.raises(RuntimeError, match="region 2"):  # the lossless contract's write
        store.write(
            "spectra",
            lazy(fail_at=2),
            schema=LOSSLESS_SPECTRA,
            fingerprint="fp",
            resumable_along="image",
        )
    calls.clear()
    store.write("spectra", lazy(), fingerprint="fp", resumable_along="image")
    assert sorted(calls) == [2, 3]  # regions 0 and 1 were adopted, not recomputed
    stored = store.read("spectra")["radiance"]
    assert excess_precision(stored.values, 10) == 0  # the adopted regions too
    nonzero = np.isfinite(computed) & (computed != 0)
    error = np.abs(stored.values[nonzero].astype(float) - computed[nonzero]) / computed[nonzero]
    assert error.max() <= stored.attrs["precision_bound_relative"]
    assert store.validate(deep=True) == []


def foreign_spectra(store, values, attrs, filters=()):
    """A spectra group written by other means (plain xarray): imported, checked by its schema."""
    ds = cube_dataset(values, attrs={"spectralize_schema": "spectra"})
    ds["radiance"].attrs.update(attrs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # numcodecs' codecs are not in the zarr 3 specification
        ds.to_zarr(
            store.path,
            group="spectra",
            mode="w",
            zarr_format=3,
            consolidated=False,
            encoding={"radiance": {"filters": filters}} if filters else None,
        )


def test_validate_finds_values_finer_than_stated_and_codecs_coarser(store):
    computed = radiance()
    foreign_spectra(store, computed, Precision(10).attrs)  # stated, never rounded
    (problem,) = store.validate()
    assert str(problem).startswith(
        "spectra:radiance: expected values rounded to 10 mantissa bits (relative error <= 0.0488 %)"
    )
    assert "in the chunks checked (first and last) with more mantissa bits" in str(problem)
    (problem,) = store.validate(deep=True)
    assert f"{excess_precision(computed, 10)} value(s) in all" in str(problem)

    from zarr.codecs.numcodecs import BitRound

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        foreign_spectra(store, round_mantissa(computed, 6), Precision(10).attrs, (BitRound(keepbits=6),))
        found = [str(p) for p in store.validate()]
        assert len(found) == 1 and "bit rounding to >= 10 mantissa bits" in found[0], found
        assert '"numcodecs.bitround"' in found[0] and '"keepbits": 6' in found[0]
        # bit rounding with no precision stated: lossy without saying so
        foreign_spectra(store, round_mantissa(computed, 12), {}, (BitRound(keepbits=12),))
        (problem,) = store.validate()
        assert "no precision stated: lossless" in str(problem)
        foreign_spectra(
            store, round_mantissa(computed, 12), Precision(12).attrs, (BitRound(keepbits=12),)
        )
        assert store.validate(deep=True) == []  # finer than the contract, and stated so


def test_arrays_without_a_declared_precision_are_stored_as_before(store):
    """Only the cube: the seed set's spectra (warm starts) and the ground truth keep every bit."""
    computed = radiance()
    seed = cube_dataset(computed, attrs={"seed_set": 0}).assign(iterations=("image", [1, 2, 3]))
    store.write("spectra_seed", seed)
    store.write("truth/spectra", cube_dataset(computed))
    for group in ("spectra_seed", "truth/spectra"):
        stored = store.read(group)["radiance"]
        assert np.array_equal(stored.values.view(np.uint32), computed.view(np.uint32))
        assert "precision_keepbits" not in stored.attrs
        meta = json.loads((store.path / group / "radiance" / "zarr.json").read_text())
        assert [c["name"] for c in meta["codecs"]] == ["bytes", "zstd"]


def test_an_edited_precision_claim_fails_validation(store):
    store.write("spectra", cube_dataset(radiance()), fingerprint="fp")
    # plain xarray reads what the store states
    ds = xr.open_zarr(store.path, group="spectra", consolidated=True)
    assert ds.radiance.attrs["precision_keepbits"] == 10
    # claiming 8 bits (coarser than the contract) is a problem even where the values hold it
    path = store.path / "spectra" / "radiance" / "zarr.json"
    meta = json.loads(path.read_text())
    meta["attributes"].update(Precision(8).attrs)
    path.write_text(json.dumps(meta))
    with warnings.catch_warnings():  # the manifest beside the group is not zarr
        warnings.simplefilter("ignore")
        zarr.consolidate_metadata(str(store.path / "spectra"))
        zarr.consolidate_metadata(str(store.path))
    found = [str(p) for p in store.validate()]
    assert found[0].startswith("spectra/radiance/zarr.json: expected ")  # edited after commit
    assert found[1:] == [
        "spectra:radiance.attrs: expected precision_keepbits an integer in [10, 23] "
        "(10 mantissa bits (relative error <= 0.0488 %) or finer), found 8"
    ]


# the contract with a quantum per spectrum instead (Precision(..., along="wavelength"))
PEAK_SPECTRA = dataclasses.replace(
    SPECTRA,
    variables=tuple(
        dataclasses.replace(s, precision=Precision(10, along="wavelength")) for s in SPECTRA.variables
    ),
)


def test_a_quantum_per_spectrum_keeps_every_value_within_the_bound_of_its_peak():
    values = radiance()
    rounded = round_to_peak(values, 10, axis=1)
    finite = np.isfinite(values)
    assert np.array_equal(finite, np.isfinite(rounded))
    peak = np.abs(np.where(finite, rounded, 0)).max(axis=1, keepdims=True)  # 0: no value
    error = np.where(finite, np.abs(rounded.astype(float) - values), 0)
    assert (error <= 2.0**-11 * peak).all()
    # the peak is stored as bit rounding stores it; the rest share its quantum
    computed_peak = np.abs(np.where(finite, values, 0)).max(axis=1)
    assert np.array_equal(peak[:, 0], round_mantissa(computed_peak, 10))
    assert np.array_equal(round_to_peak(rounded, 10, axis=1), rounded, equal_nan=True)  # idempotent
    assert excess_precision(rounded, 10, axis=1) == 0 < excess_precision(values, 10, axis=1)
    # fewer bits than per value where a band is far below its peak, never more
    assert excess_precision(round_mantissa(values, 10), 10, axis=1) > 0
    assert excess_precision(rounded, 10) == 0


@pytest.mark.parametrize("resumable", [None, "image"])
def test_a_cube_stored_with_a_quantum_per_spectrum_states_it_and_validates(store, resumable):
    from spectralize.schemas import validate_dataset
    from spectralize.store.precision import precision_problems

    computed = radiance()
    ds = cube_dataset(computed)
    store.write(
        "spectra",
        ds.chunk({"image": 1}) if resumable else ds,
        schema=PEAK_SPECTRA,
        fingerprint="fp",
        resumable_along=resumable,
    )
    stored = store.read("spectra")
    radiance_ = stored["radiance"]
    assert radiance_.attrs["precision_relative_to_peak_along"] == "wavelength"
    assert radiance_.attrs["precision_bound_relative"] == 2.0**-11
    values = radiance_.values
    finite = np.isfinite(computed)
    peak = np.abs(np.where(finite, values, 0)).max(axis=1, keepdims=True)
    assert (np.where(finite, np.abs(values.astype(float) - computed), 0) <= 2.0**-11 * peak).all()
    raw = store.read("spectra", friendly=False)
    root = store.path / "spectra"
    assert validate_dataset(raw, PEAK_SPECTRA) == []
    assert precision_problems(root, raw, PEAK_SPECTRA, "spectra", deep=True) == []
    # coarser than the registered contract (a bound relative to each value): reported
    found = [str(p) for p in store.validate()]
    assert found == [
        "spectra:radiance.attrs: expected precision_relative_to_peak_along absent (a bound "
        "relative to each value), found 'wavelength'"
    ]
