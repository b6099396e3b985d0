"""Calibration tables: parsed from text, put on the bands, the patch label image checked."""

import numpy as np
import pytest

from spectralize.datasets.capture.calibration import check_patch_index, on_bands, parse_table

WHERE = "calibration/illuminant.csv"


def test_a_table_is_read_by_column_name_blank_rows_skipped():
    text = "value,wavelength_nm,note\r\n1.0,400,a\r\n\r\n0.5,500,b\r\n"
    table, problems = parse_table(text, WHERE, ("wavelength_nm", "value"))
    assert problems == [] and table == {"wavelength_nm": [400.0, 500.0], "value": [1.0, 0.5]}
    table, _ = parse_table("patch,x\nA1,3\n", WHERE, ("patch", "x"), text_columns=("patch",))
    assert table == {"patch": ["A1"], "x": [3.0]}


@pytest.mark.parametrize(
    "text, where, found",
    [
        ("wavelength_nm,value\n400,1\n500,x\n", f"{WHERE} line 3: value", "'x'"),
        ("wavelength_nm\n400\n", f"{WHERE} line 1", "['wavelength_nm']"),
        ("", f"{WHERE} line 1", "[]"),
        ("wavelength_nm,value\n", WHERE, "none"),
        # lines are the file's: blank rows count (line 5 below, not 4)
        ("wavelength_nm,value\n400,1\n\n\n500,x\n", f"{WHERE} line 5: value", "'x'"),
        ("wavelength_nm,value\n400,nan\n", f"{WHERE} line 2: value", "'nan'"),
        ("wavelength_nm,value\n1e999,1\n", f"{WHERE} line 2: wavelength_nm", "'1e999'"),
    ],
)
def test_a_bad_table_is_one_problem(text, where, found):
    table, problems = parse_table(text, WHERE, ("wavelength_nm", "value"))
    assert table is None and [(p.where, p.found) for p in problems] == [(where, found)]


def test_spectra_are_interpolated_onto_the_bands_they_cover():
    bands = np.array([450.0, 500.0])
    values, problems = on_bands("w", np.array([500.0, 400.0]), np.array([2.0, 1.0]), bands)
    assert problems == [] and values == pytest.approx([1.5, 2.0])
    values, problems = on_bands("w", np.array([460.0, 500.0]), np.array([1.0, 1.0]), bands)
    assert values is None and "missing [450.0]" in str(problems[0])
    values, problems = on_bands("w", np.array([400.0, 400.0, 500.0]), np.ones(3), bands)
    assert values is None and "duplicate wavelengths" in str(problems[0])


def test_the_patch_label_image_becomes_patch_indices():
    labels = np.array([[0, 1], [2, 24]], np.uint16)
    index, problems = check_patch_index("p.png", labels, (2, 2), 24)
    assert problems == [] and index.dtype == np.int16
    np.testing.assert_array_equal(index, [[-1, 0], [1, 23]])
    index, problems = check_patch_index("p.png", labels, (2, 3), 24)
    assert index is None and "shape (2, 2)" in str(problems[0])
    index, problems = check_patch_index("p.png", labels, (2, 2), 18)
    assert index is None and "a label 24" in str(problems[0])
