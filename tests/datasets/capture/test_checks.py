"""The rules manifest rows keep against capture.toml, by row and together."""

from support.capture_folders import GOOD_CONFIG

from spectralize.datasets.capture import Row
from spectralize.datasets.capture.checks import check_rows, check_structure, pair
from spectralize.datasets.capture.config import parse_config

CONFIG, _ = parse_config(GOOD_CONFIG, "x")


def row(line, file, kind, camera, t=0.01, wl=None, rotation=0, led=0, angles=(40.0, 10.0, 45.0, 0.0)):
    return Row(line, file, kind, camera, rotation, led, t, wl, angles)


def test_a_row_breaking_a_rule_of_its_kind_is_left_out_and_listed():
    rows = [
        row(2, "a.png", "rgb", "arc45"),
        row(3, "b.tif", "spectral", "mono"),  # no wavelength
        row(4, "c.png", "rgb", "mono"),  # not an RGB camera
        row(5, "d.tif", "dark", "mono", wl=500.0, rotation=None, led=None),  # dark has no band
        row(6, "e.tif", "spectral", "mono", wl=500.0, angles=(40.0, 10.0, 95.0, 0.0)),
        row(7, "f.jpg", "rgb", "arc15", t=0.0),
    ]
    kept, problems = check_rows(rows, CONFIG)
    assert [r.line for r in kept] == [2]
    where = sorted(p.where for p in problems)
    assert where == [
        "manifest.csv line 3 (b.tif): wavelength_nm",
        "manifest.csv line 4 (c.png): camera",
        "manifest.csv line 5 (d.tif): wavelength_nm",
        "manifest.csv line 6 (e.tif): theta_o",
        "manifest.csv line 7 (f.jpg): exposure_time_s",
        "manifest.csv line 7 (f.jpg): file",
    ]


def test_band_shots_pair_with_images_seen_from_the_same_angles_azimuth_modulo_360():
    image = row(2, "a.png", "rgb", "arc45", angles=(40.0, 359.8, 45.0, 0.1))
    paired = [(("arc45", 0, 0), image)]
    shot = row(3, "b.tif", "spectral", "mono", wl=500.0, angles=(40.2, 0.1, 45.0, 359.9))
    assert pair(shot, paired, 0.5) == ("arc45", 0, 0)
    assert pair(shot, paired, 0.1) is None
    far = row(4, "c.tif", "spectral", "mono", wl=500.0, angles=(40.0, 180.0, 45.0, 0.1))
    assert pair(far, paired, 0.5) is None


def test_duplicates_and_contradicting_rows_are_listed_with_both_lines():
    rows = [
        row(2, "a.png", "rgb", "arc45", t=0.01),
        row(3, "b.png", "rgb", "arc45", t=0.02, angles=(41.0, 10.0, 45.0, 0.0)),
        row(4, "a.png", "rgb", "arc45", t=0.04),
        row(5, "c.png", "rgb", "arc45", t=0.01),
    ]
    problems = [str(p) for p in check_structure(rows, CONFIG)]
    assert any("line 4 (a.png)" in p and "a duplicate of line 2" in p for p in problems)
    assert any("line 5 (c.png)" in p and "the same rgb frame as line 2 (a.png)" in p for p in problems)
    assert any("line 3 (b.png): theta_i" in p and "contradicting rows" in p for p in problems)
    assert any("dark frames" in p and "none" in p for p in problems)  # nothing else is there
