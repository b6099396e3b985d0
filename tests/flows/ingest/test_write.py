"""Capture folders into run stores: real files (TIFF, PNG), real zarr stores, the real CLI."""

import os

import numpy as np
import pytest
import tifffile
from support.capture_folders import rows, write_rows

from spectralize.datasets.capture import CaptureError
from spectralize.datasets.capture.write import write_png
from spectralize.flows.cli import main
from spectralize.flows.ingest import ingest
from spectralize.nodes.simulation.assembly import simulate_run
from spectralize.nodes.simulation.recipes import get_recipe
from spectralize.store import RunStore

RAW = (
    "raw/rgb",
    "raw/spectral",
    "raw/dark",
    "raw/white_reference",
    "raw/colour_checker",
    "raw/registration",
)


def test_a_capture_folder_ingests_into_the_raw_groups_of_the_simulated_run(capture, tmp_path):
    report = ingest(capture, tmp_path / "run.zarr")
    store = RunStore.open(tmp_path / "run.zarr")
    assert store.validate() == []
    assert set(report.groups) == set(RAW) | {"raw/exposure_plan"}
    assert set(report.groups.values()) == {"written"}
    simulated = simulate_run(get_recipe("tiny"))
    for group in RAW:  # the pixels are the simulator's, bit for bit, in the same order
        ingested = store.read(group)
        for name, var in ingested.data_vars.items():
            if var.dtype == np.uint16:
                np.testing.assert_array_equal(var.values, simulated[group][name].values, err_msg=name)
    rgb, spectral = store.read("raw/rgb"), store.read("raw/spectral")
    np.testing.assert_allclose(rgb["theta_o"].values, simulated["raw/rgb"]["theta_o"].values)
    # band shots pair with the RGB image seen from the same angles (here: the simulator's pairing)
    np.testing.assert_array_equal(spectral["image"].values, simulated["raw/spectral"]["image"].values)
    np.testing.assert_allclose(
        spectral["filter_size"].values, simulated["raw/spectral"]["filter_size"].values
    )
    assert store.read("raw/exposure_plan").attrs["omega"] == pytest.approx(0.8)
    assert store.read("raw/colour_checker").attrs["chart"] == "colour_checker.csv"


def test_reingest_reads_only_new_frames_and_skips_unchanged_groups(capture, tmp_path):
    full = rows(capture)
    # first the folder without one RGB image of the unpaired camera (4 exposures)
    missing = [
        r
        for r in full
        if r["kind"] == "rgb" and r["camera"] == "rgb15" and r["led"] == "91" and r["rotation"] == "0"
    ]
    assert len(missing) == 4
    write_rows(capture, [r for r in full if r not in missing])
    first = ingest(capture, tmp_path / "run.zarr")
    assert first.frames_read == len(full) - 4
    store = RunStore.open(tmp_path / "run.zarr")
    assert store.read("raw/rgb").sizes["image"] == 19
    fingerprints = {g: store.fingerprint(g) for g in RAW}
    # an ingested file changes on disk but keeps size and time: it is not read again
    kept = capture / next(r["file"] for r in full if r["kind"] == "rgb" and r["camera"] == "rgb45")
    stat = kept.stat()
    kept.write_bytes(b"\0" * stat.st_size)
    os.utime(kept, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    write_rows(capture, full)
    second = ingest(capture, tmp_path / "run.zarr")
    assert second.groups["raw/rgb"] == "written" and second.frames_read == 4
    # raw/spectral is rewritten too (its pairing labels moved), from the store: no file read
    assert second.groups["raw/spectral"] == "written" and second.frames_copied == 76 + 32
    unchanged = ("raw/dark", "raw/white_reference", "raw/colour_checker", "raw/registration")
    assert all(second.groups[g] == "up to date" for g in unchanged)
    assert all(store.fingerprint(g) == fingerprints[g] for g in unchanged)
    np.testing.assert_array_equal(
        store.read("raw/rgb")["counts"].values,
        simulate_run(get_recipe("tiny"))["raw/rgb"]["counts"].values,
    )
    assert store.read("raw/rgb").sizes["image"] == 20 and store.validate() == []
    third = ingest(capture, tmp_path / "run.zarr")
    assert set(third.groups.values()) == {"up to date"} and third.frames_read == 0


def test_bad_input_lists_every_problem_with_file_and_line_and_writes_nothing(capture, tmp_path, capsys):
    table = rows(capture)
    line = {r["file"]: i + 2 for i, r in enumerate(table)}  # header is line 1
    rgb = [r for r in table if r["kind"] == "rgb"]
    bands = [r for r in table if r["kind"] == "spectral"]
    (capture / rgb[0]["file"]).unlink()  # missing file
    (capture / bands[0]["file"]).write_bytes(b"not a tiff")  # unreadable
    write_png(capture / rgb[1]["file"], np.full((32, 32, 3), 4000, np.uint16))  # > 10 bits
    tifffile.imwrite(capture / bands[1]["file"], np.zeros((16, 32), np.uint16))  # wrong shape
    tifffile.imwrite(capture / bands[2]["file"], np.zeros((32, 32), np.float32))  # not 16-bit
    rgb[5]["theta_i"] = "41"  # contradicts the other exposures of its image
    bands[3]["wavelength_nm"] = ""  # a band shot without a wavelength
    table[-1]["kind"] = "flat_field"  # unknown kind
    for row in rgb[8:12]:  # an exposure series with one time
        row["exposure_time_s"] = "0.01"
    table.append(dict(table[0]))  # duplicate row
    write_rows(capture, table)
    code = main(["ingest", str(capture), str(tmp_path / "run.zarr")])
    err = capsys.readouterr().err
    assert code == 2
    assert not (tmp_path / "run.zarr").exists()  # nothing written
    expected = [
        (rgb[0]["file"], "no such file"),
        (bands[0]["file"], "readable TIFF or PNG"),
        (rgb[1]["file"], "a value of 4000"),
        (bands[1]["file"], "found 16 x 32 px"),
        (bands[2]["file"], "float32"),
        (rgb[5]["file"], "contradicting rows"),
        (bands[3]["file"], "wavelength_nm: expected the filter's wavelength for a band shot"),
        (table[-2]["file"], "flat_field"),
        (table[0]["file"], "duplicate of line 2"),
    ]
    for file, what in expected:
        hit = [text for text in err.splitlines() if file in text and what in text]
        assert hit, f"no problem for {file} mentioning {what!r} in:\n{err}"
    assert f"manifest.csv line {line[rgb[5]['file']]} ({rgb[5]['file']})" in err
    assert "an exposure series of at least two exposure times, found one time" in err
    assert f"line {len(table) + 1} ({table[0]['file']})" in err  # the duplicate's own line


def test_bad_input_never_touches_an_existing_store(capture, tmp_path):
    ingest(capture, tmp_path / "run.zarr")
    store = RunStore.open(tmp_path / "run.zarr")
    before = {g: store.fingerprint(g) for g in store.groups()}
    (capture / "calibration" / "illuminant.csv").write_text("wavelength_nm,value\n500,1\n")
    with pytest.raises(CaptureError, match="illuminant") as error:
        ingest(capture, tmp_path / "run.zarr")
    assert "nothing was written" in str(error.value)
    assert {g: store.fingerprint(g) for g in store.groups()} == before


def test_every_rgb_band_and_dark_frame_is_decoded_once(capture, tmp_path, monkeypatch):
    """The folder's check reads their headers; their pixels are decoded (and their values
    checked) only where they are written. Frames of the small groups are checked first."""
    from spectralize.datasets.capture import images
    from spectralize.flows.ingest import decode

    decoded: dict[str, int] = {}

    def counted(read):
        def read_image(path, **kwargs):
            decoded[str(path)] = decoded.get(str(path), 0) + 1
            return read(path, **kwargs)

        return read_image

    monkeypatch.setattr(images, "read_image", counted(images.read_image))
    monkeypatch.setattr(decode, "read_image", counted(decode.read_image))
    ingest(capture, tmp_path / "run.zarr")
    kinds = {str(capture / r["file"]): r["kind"] for r in rows(capture)}
    once = {k for k, kind in kinds.items() if kind in ("rgb", "spectral", "dark")}
    assert once and {decoded.get(k) for k in once} == {1}
    assert set(decoded) == set(kinds)  # every frame decoded (the others checked, then written)


def test_a_frame_whose_values_fail_as_it_is_decoded_leaves_nothing_written(capture, tmp_path):
    """A band shot above its camera's bit depth, its header fine: found while the groups are
    staged, before any is committed; the error names it; nothing is written or left staged."""
    band = next(r for r in rows(capture) if r["kind"] == "spectral")["file"]
    good = tifffile.imread(capture / band)
    tifffile.imwrite(capture / band, np.full_like(good, 1500))  # a 10-bit camera
    with pytest.raises(CaptureError, match="a value of 1500") as error:
        ingest(capture, tmp_path / "new.zarr")
    assert band in str(error.value) and "nothing was written" in str(error.value)
    assert not (tmp_path / "new.zarr").exists()
    assert not (tmp_path / ".new.zarr.spectralize").exists()
    # an existing store: the groups before the band shots' are staged, never committed
    tifffile.imwrite(capture / band, good)
    ingest(capture, tmp_path / "run.zarr")
    store = RunStore.open(tmp_path / "run.zarr")
    before = {g: store.fingerprint(g) for g in store.groups()}
    rgb = next(r for r in rows(capture) if r["kind"] == "rgb")["file"]
    tifffile.imwrite(capture / band, np.full_like(good, 1500))
    write_png(capture / rgb, store.read("raw/rgb")["counts"].values[0, 0] // 2)  # a new frame
    with pytest.raises(CaptureError, match="a value of 1500"):
        ingest(capture, tmp_path / "run.zarr")
    assert {g: store.fingerprint(g) for g in store.groups()} == before
    assert [p for p in store.staging_dir.iterdir() if p.name != "zarr.json"] == []


def test_an_ingest_stopped_once_its_groups_are_staged_commits_them_without_decoding_again(
    capture, tmp_path, monkeypatch
):
    """Stopped (Ctrl-C) after the RGB, band and dark groups are staged and before any group is
    written: nothing is committed; the next ingest adopts the staged regions and commits them,
    decoding none of those frames again; their pixels are the frames'."""
    from spectralize.flows.ingest import decode

    def stopped_at_the_first_write(message):
        if ": writing (" in message:
            raise KeyboardInterrupt

    path = tmp_path / "run.zarr"
    with pytest.raises(KeyboardInterrupt):
        ingest(capture, path, progress=stopped_at_the_first_write)
    store = RunStore.open(path)
    assert store.groups() == [] and store.staging_leftovers() != []
    decoded: list[str] = []
    real = decode.read_image
    monkeypatch.setattr(decode, "read_image", lambda p, **kw: decoded.append(str(p)) or real(p, **kw))
    report = ingest(capture, path)
    assert set(report.groups) == set(RAW) | {"raw/exposure_plan"}
    kinds = {str(capture / r["file"]): r["kind"] for r in rows(capture)}
    assert decoded and {kinds[p] for p in decoded}.isdisjoint({"rgb", "spectral", "dark"})
    assert [p for p in store.staging_dir.iterdir() if p.name != "zarr.json"] == []
    assert store.validate() == []
    simulated = simulate_run(get_recipe("tiny"))
    for group in ("raw/rgb", "raw/spectral"):  # the staged pixels, bit for bit
        np.testing.assert_array_equal(
            store.read(group)["counts"].values, simulated[group]["counts"].values
        )
