import numpy as np
import pytest
import xarray as xr

from spectralize.schemas import SchemaError, check_dataset, validate_dataset
from spectralize.schemas.run import RAW_DARK, RAW_SPECTRAL, SPECTRA, render_table


def raw_dark(**overrides):
    ds = xr.Dataset(
        {
            "frames": (
                ("exposure_time", "frame", "y", "x"),
                np.zeros((2, 3, 4, 5), np.uint16),
                {"units": "DN"},
            )
        },
        coords={"exposure_time": ("exposure_time", [0.1, 0.2], {"units": "s"})},
        attrs={"camera": "spectral", "bit_depth": 10},
    )
    return ds


def test_valid_group_has_no_problems():
    assert validate_dataset(raw_dark(), RAW_DARK) == []


def test_every_problem_is_listed_at_once():
    ds = raw_dark()
    ds["frames"] = ds.frames.astype(np.float64).transpose("frame", "exposure_time", "y", "x")
    ds["frames"].attrs = {"units": "counts"}
    ds = ds.drop_vars("exposure_time")
    ds.attrs = {}
    problems = [str(p) for p in validate_dataset(ds, RAW_DARK)]
    text = "\n".join(problems)
    assert (
        "raw/dark:frames: expected dims ('exposure_time', 'frame', 'y', 'x'), found dims ('frame', 'exposure_time', 'y', 'x')"
        in text
    )
    assert "raw/dark:frames: expected dtype uint16, found dtype float64" in text
    assert "raw/dark:frames: expected attrs['units'] == 'DN', found units 'counts'" in text
    assert (
        "raw/dark:exposure_time: expected coordinate with dims ('exposure_time',), found nothing" in text
    )
    assert "attr 'camera'" in text and "attr 'bit_depth'" in text
    assert len(problems) == 6


def test_check_dataset_raises_schema_error_naming_the_group():
    ds = raw_dark().rename({"frames": "frame_stack"})
    with pytest.raises(
        SchemaError, match=r"group 'raw/dark'[\s\S]*raw/dark:frames: expected data variable"
    ):
        check_dataset(ds, RAW_DARK)


def test_value_ranges_and_finiteness_of_coords_are_checked():
    ds = xr.Dataset(
        {"counts": (("shot", "y", "x"), np.zeros((2, 3, 3), np.uint16), {"units": "DN"})},
        coords={
            "wavelength": ("shot", [410.0, np.nan], {"units": "nm"}),
            "exposure_time": ("shot", [-1.0, 0.1], {"units": "s"}),
            "image": ("shot", [0, 1]),
            "rotation": ("shot", [0, 0]),
            "led": ("shot", [1, 2]),
        },
        attrs={"bit_depth": 10},
    )
    text = "\n".join(map(str, validate_dataset(ds, RAW_SPECTRAL)))
    assert "raw/spectral:wavelength: expected finite values, found 1 NaN/inf value(s)" in text
    assert "raw/spectral:exposure_time: expected values in [0, 10000], found range [-1, 0.1]" in text


def test_coordinate_given_as_data_variable_is_named():
    ds = xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                np.zeros((1, 2, 2, 2), np.float32),
                {"units": "1"},
            )
        }
    )
    problems = validate_dataset(ds, SPECTRA)
    assert any("spectra:wavelength" in str(p) for p in problems)
    assert any("spectra:theta_i" in str(p) for p in problems)


def test_readme_table_is_rendered_from_the_contract():
    from pathlib import Path

    readme = Path(__file__).parents[2] / "schemas" / "README.md"
    assert render_table() in readme.read_text(), (
        "schemas/README.md is out of date: regenerate it with `python -m spectralize.schemas --update-readme`"
    )


def spectra_with(attrs):
    from support.cubes import cube_dataset

    ds = cube_dataset(np.ones((1, 32, 2, 2)))
    ds["radiance"].attrs.update(attrs)
    return ds


def test_the_precision_a_cube_states_is_checked_against_its_contract():
    from spectralize.schemas import Precision
    from spectralize.schemas.run import SPECTRA_PRECISION

    assert SPECTRA.spec("radiance").precision == SPECTRA_PRECISION
    assert SPECTRA_PRECISION.keepbits >= 10 and SPECTRA_PRECISION.relative_bound <= 5e-4
    assert Precision(10).attrs == {"precision_keepbits": 10, "precision_bound_relative": 2.0**-11}
    # nothing stated: stored losslessly (a store written before the precision), valid
    assert validate_dataset(spectra_with({}), SPECTRA) == []
    assert validate_dataset(spectra_with(Precision(10).attrs), SPECTRA) == []
    assert validate_dataset(spectra_with(Precision(16).attrs), SPECTRA) == []  # finer: valid
    coarse = [str(p) for p in validate_dataset(spectra_with(Precision(8).attrs), SPECTRA)]
    assert coarse == [
        "spectra:radiance.attrs: expected precision_keepbits an integer in [10, 23] "
        "(10 mantissa bits (relative error <= 0.0488 %) or finer), found 8"
    ]
    wrong_bound = {"precision_keepbits": 10, "precision_bound_relative": 1e-3}
    (problem,) = validate_dataset(spectra_with(wrong_bound), SPECTRA)
    assert "precision_bound_relative == 0.00048828125" in str(problem) and "found 0.001" in str(problem)
    (problem,) = validate_dataset(spectra_with({"precision_keepbits": 10}), SPECTRA)
    assert "no 'precision_bound_relative'" in str(problem)
    # the table says so
    assert "stored to 10 mantissa bits" in render_table([SPECTRA])
