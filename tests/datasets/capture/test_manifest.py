"""manifest.csv text into rows: every bad cell is a problem naming its line and column."""

from spectralize.datasets.capture import MANIFEST_COLUMNS, Row
from spectralize.datasets.capture.manifest import parse_manifest
from spectralize.datasets.capture.write import write_manifest

HEADER = ",".join(MANIFEST_COLUMNS)


def test_rows_keep_their_line_numbers_and_blank_lines_are_skipped():
    text = (
        f"{HEADER},note\r\n"
        "rgb/a.png,rgb,arc15,2,7,0.01,,40,180,15,0,extra\r\n"
        "\r\n"
        "dark/d.tif,dark,mono,,,0.5,,,,,\r\n"
    )
    rows, problems = parse_manifest(text)
    assert problems == []
    assert rows == [
        Row(2, "rgb/a.png", "rgb", "arc15", 2, 7, 0.01, None, (40.0, 180.0, 15.0, 0.0)),
        Row(4, "dark/d.tif", "dark", "mono", None, None, 0.5, None, (None, None, None, None)),
    ]
    assert rows[0].where == "manifest.csv line 2 (rgb/a.png)"


def test_every_bad_cell_is_listed_and_its_row_left_out():
    text = (
        f"{HEADER}\n"
        "a.tif,rgb,c,1.5,x,0.01,,inf,0,0,0\n"
        ",flat_field,c,,,0.01,,,,,\n"
        "b.tif,dark,mono,,,0.01,,,,,\n"
    )
    rows, problems = parse_manifest(text)
    assert [r.file for r in rows] == ["b.tif"]
    text = [str(p) for p in problems]
    assert len(text) == 5
    assert any("line 2 (a.tif): rotation" in t and "a finite int" in t and "'1.5'" in t for t in text)
    assert any("line 2 (a.tif): led" in t and "'x'" in t for t in text)
    assert any("line 2 (a.tif): theta_i" in t and "a finite float" in t for t in text)
    assert any("line 3 (no file)" in t and "a file name" in t for t in text)
    assert any("line 3 (no file): kind" in t and "'flat_field'" in t for t in text)


def test_missing_columns_and_an_empty_file_are_problems_of_line_1():
    rows, problems = parse_manifest("file,kind\na.tif,rgb\n")
    assert rows == [] and len(problems) == 1
    assert "manifest.csv line 1" in str(problems[0]) and "'camera'" in str(problems[0])
    rows, problems = parse_manifest("")
    assert rows == [] and "an empty file" in str(problems[0])


def test_what_the_writer_writes_the_parser_reads(tmp_path):
    written = [
        {
            "file": "s/a.tif",
            "kind": "spectral",
            "camera": "mono",
            "rotation": 1,
            "led": 3,
            "exposure_time_s": 0.123456789012,
            "wavelength_nm": 550.0,
            "theta_i": 40.0,
            "phi_i": 359.5,
            "theta_o": 45.0,
            "phi_o": 15.0,
        },
        {"file": "d/b.tif", "kind": "dark", "camera": "mono", "exposure_time_s": 2.0},
    ]
    write_manifest(tmp_path / "manifest.csv", written)
    with open(tmp_path / "manifest.csv", newline="", encoding="utf-8-sig") as handle:
        rows, problems = parse_manifest(handle.read())
    assert problems == []
    assert rows[0] == Row(
        2, "s/a.tif", "spectral", "mono", 1, 3, 0.123456789, 550.0, (40.0, 359.5, 45.0, 15.0)
    )
    assert rows[1].exposure_time == 2.0 and rows[1].rotation is None and rows[1].angles == (None,) * 4
