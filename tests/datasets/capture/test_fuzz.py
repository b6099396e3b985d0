"""Any input to the capture-folder parsers and the image header probe gives a result or listed
problems: never a traceback, a hang or an allocation the input only claims (hypothesis)."""

import struct
import tracemalloc
import zlib

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spectralize.datasets.capture.calibration import parse_table
from spectralize.datasets.capture.config import parse_config
from spectralize.datasets.capture.images import probe, read_header
from spectralize.datasets.capture.manifest import parse_manifest
from spectralize.datasets.capture.model import MANIFEST_COLUMNS, Config, Row
from spectralize.schemas import Problem

FUZZ = settings(max_examples=300, deadline=2000, suppress_health_check=[HealthCheck.too_slow])

# CSV-ish text: the characters that matter to a CSV reader, numbers and words
CELL = st.one_of(
    st.text(alphabet=st.characters(codec="utf-8"), max_size=12),
    st.sampled_from(["", "1", "-0", "1e309", "nan", "inf", "0.5", '"', '""', "a,b", "\r", "\x00"]),
    st.floats(allow_nan=True).map(repr),
    st.integers().map(str),
)


def csv_text(header):
    row = st.lists(CELL, max_size=len(header) + 2).map(lambda cells: ",".join(cells))
    return st.tuples(st.just(",".join(header)), st.lists(row, max_size=8)).map(
        lambda parts: "\n".join([parts[0], *parts[1]])
    )


def problems_only(problems):
    assert all(isinstance(p, Problem) and str(p) for p in problems)


@FUZZ
@given(st.one_of(st.text(max_size=400), csv_text(MANIFEST_COLUMNS)))
def test_any_manifest_text_gives_rows_or_problems(text):
    rows, problems = parse_manifest(text)
    assert all(isinstance(r, Row) for r in rows)
    problems_only(problems)


TOML_VALUE = st.one_of(
    st.integers(-(2**70), 2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(lambda v: repr(v).replace("inf", "inf")),
    st.booleans().map(lambda b: str(b).lower()),
    st.text(max_size=8).map(lambda t: '"' + t.replace("\\", "").replace('"', "") + '"'),
    st.just("[]"),
    st.just('["a", "a"]'),
    st.just("{}"),
    st.just("[[[[[[[[1]]]]]]]]"),
)
TOML_KEY = st.sampled_from(
    [
        "format",
        "version",
        "name",
        "rotation_step_deg",
        "angle_tolerance_deg",
        "follow_symlinks",
        "cameras",
        "bit_depth",
        "paired_camera",
        "channels",
        "camera",
        "t0",
        "s0",
        "omega",
        "chart",
        "patch_index",
        "rgb",
        "spectral",
    ]
)
TOML_TABLE = st.sampled_from(
    ["", "[rgb]", "[spectral]", "[exposure_plan]", "[colour_checker]", "[[rgb]]"]
)
TOML = st.lists(
    st.one_of(TOML_TABLE, st.tuples(TOML_KEY, TOML_VALUE).map(lambda kv: f"{kv[0]} = {kv[1]}")),
    max_size=16,
).map("\n".join)


@FUZZ
@given(st.one_of(st.text(max_size=300), TOML))
def test_any_capture_toml_gives_a_config_or_problems(text):
    config, problems = parse_config(text, "folder")
    assert (config is None) == bool(problems)
    assert config is None or isinstance(config, Config)
    problems_only(problems)


def test_a_deeply_nested_capture_toml_is_a_problem():
    config, problems = parse_config("a = " + "[" * 100_000 + "]" * 100_000, "folder")
    assert config is None and problems


@FUZZ
@given(st.one_of(st.text(max_size=300), csv_text(["patch", "wavelength_nm", "reflectance"])))
def test_any_calibration_table_gives_a_table_or_problems(text):
    table, problems = parse_table(
        text,
        "calibration/colour_checker.csv",
        ("patch", "wavelength_nm", "reflectance"),
        text_columns=("patch",),
    )
    assert (table is None) == bool(problems)
    if table is not None:
        assert all(np.isfinite(table["wavelength_nm"])) and len(set(map(len, table.values()))) == 1
    problems_only(problems)


def png_bytes(width, height, bits, colour, body):
    ihdr = struct.pack(">IIBBBBB", width, height, bits, colour, 0, 0, 0)
    chunk = struct.pack(">I", 13) + b"IHDR" + ihdr
    chunk += struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))
    idat = zlib.compress(body)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk
        + struct.pack(">I", len(idat))
        + b"IDAT"
        + idat
        + struct.pack(">I", zlib.crc32(b"IDAT" + idat))
        + struct.pack(">I", 0)
        + b"IEND"
        + struct.pack(">I", zlib.crc32(b"IEND"))
    )


def tiff_bytes(width, height, bits, extra):
    """A little-endian TIFF with one IFD (width, length, bits per sample) and random tail."""
    entries = [
        (256, 4, 1, width),
        (257, 4, 1, height),
        (258, 3, 1, bits),
        (273, 4, 1, 8),
        (279, 4, 1, 16),
    ]
    ifd = struct.pack("<H", len(entries))
    ifd += b"".join(struct.pack("<HHII", tag, kind, count, value) for tag, kind, count, value in entries)
    ifd += struct.pack("<I", 0)
    return b"II*\x00" + struct.pack("<I", 8 + 16) + b"\x00" * 16 + ifd + extra


DIMENSION = st.one_of(st.integers(0, 64), st.integers(0, 2**32 - 1))
IMAGE = st.one_of(
    st.tuples(st.just(".png"), st.binary(max_size=200)),
    st.tuples(
        st.just(".png"),
        st.builds(
            png_bytes,
            DIMENSION,
            DIMENSION,
            st.sampled_from([1, 2, 4, 8, 16, 3]),
            st.sampled_from([0, 2, 3, 4, 6, 5]),
            st.binary(max_size=300),
        ),
    ),
    st.tuples(st.sampled_from([".tif", ".tiff"]), st.binary(max_size=200)),
    st.tuples(
        st.just(".tif"),
        st.builds(
            tiff_bytes, DIMENSION, DIMENSION, st.sampled_from([8, 16, 32, 1]), st.binary(max_size=300)
        ),
    ),
)


@FUZZ
@given(IMAGE, st.booleans(), st.integers(8, 16))
def test_any_image_file_gives_a_shape_or_a_problem_within_bounded_memory(
    tmp_path_factory, image, rgb, bits
):
    suffix, data = image
    path = tmp_path_factory.mktemp("fuzz") / f"frame{suffix}"
    path.write_bytes(data)
    tracemalloc.start()
    try:
        shape, expected, found = probe(path, rgb, bits, max_bytes=2**20)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert (shape is None) == (expected is not None)
    assert expected is None or (isinstance(expected, str) and isinstance(found, str))
    assert peak < 16 * 2**20, f"{peak / 2**20:.0f} MiB traced for a {len(data)}-byte file"


def test_a_png_header_is_read_from_its_first_bytes(tmp_path):
    path = tmp_path / "bomb.png"
    path.write_bytes(png_bytes(100_000, 100_000, 16, 2, b""))
    header = read_header(path)
    assert header.shape == (100_000, 100_000, 3) and header.dtype == np.uint16
    assert header.nbytes == 100_000 * 100_000 * 3 * 2
    shape, expected, found = probe(path, True, 12)
    assert shape is None and expected == "a frame of at most 256 MiB"
    assert found.startswith("a file declaring 100000 x 100000 x 3 uint16") and "not decoded" in found
