"""The image files of a capture folder: their header, their pixels, and a probe against a camera.

Image files are TIFF (tifffile; compressed ones, LZW, Deflate or PackBits as camera software
writes them, decoded by imagecodecs) or PNG (pypng: Pillow cannot read 16-bit RGB PNG), 16-bit
unsigned (8-bit for cameras of at most 8 bits), monochrome ``(y, x)`` for the spectral camera
and RGB ``(y, x, 3)`` for the RGB cameras, values right-aligned (at most
``2**bit_depth - 1``, as the ADC gives them).

Header first: a file's size, dtype and pixel count come from its header (:func:`read_header`:
tifffile's first series, or the PNG ``IHDR`` chunk) and are checked before a single pixel is
decoded, so a small file that declares a huge image (a decompression bomb) is refused for what
it declares, and decoding never needs more than :data:`MAX_FRAME_BYTES`.

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the cameras), eq. 5 (counts of a camera).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from spectralize.schemas import Problem, SpectralizeError

from .model import CaptureError

__all__ = [
    "IMAGE_SUFFIXES",
    "MAX_FRAME_BYTES",
    "Header",
    "read_header",
    "read_image",
    "reader_failure",
    "probe",
]

IMAGE_SUFFIXES: tuple[str, ...] = (".tif", ".tiff", ".png")
"""The image file names a manifest may list (case-insensitive)."""

MAX_FRAME_BYTES = 256 * 2**20
"""The largest frame decoded (its pixels as stored): a 16-bit RGB frame of 8192 x 5461 px.

Ingest's memory is bounded by its chunks (``flows/ingest/raw_groups.py``), which hold at
least one frame; a file whose header declares more than this is refused undecoded."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_PLANES = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # colour type -> samples per pixel


@dataclass(frozen=True)
class Header:
    """What an image file declares: its array shape (``(y, x)`` or ``(y, x, planes)``), dtype."""

    shape: tuple[int, ...]
    dtype: np.dtype

    @property
    def nbytes(self) -> int:
        """Bytes of the decoded pixels (Python ints: no overflow for absurd declarations)."""
        size = self.dtype.itemsize
        for n in self.shape:
            size *= int(n)
        return size


def read_header(path: str | os.PathLike[str]) -> Header:
    """The shape and dtype an image file declares, read without decoding a pixel.

    TIFF: the first series of :class:`tifffile.TiffFile` (what :func:`read_image` decodes).
    PNG: the ``IHDR`` chunk (the 29 first bytes): width, height, bit depth, colour type.

    Raises
    ------
    CaptureError
        For an unknown suffix or a header that cannot be read, naming the file (a decoder's
        own ``ValueError`` and an ``OSError`` pass through).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        import tifffile

        with tifffile.TiffFile(path) as tif:
            if not tif.series:
                raise CaptureError.single(
                    str(path), "a TIFF file with an image", "a TIFF file without images"
                )
            series = tif.series[0]
            return Header(tuple(int(n) for n in series.shape), np.dtype(series.dtype))
    if suffix == ".png":
        with open(path, "rb") as file:
            head = file.read(29)
        if len(head) < 29 or head[:8] != _PNG_SIGNATURE or head[12:16] != b"IHDR":
            raise CaptureError.single(
                str(path), "a PNG file", "not a PNG file (no PNG signature and IHDR chunk)"
            )
        width, height, bits, colour = struct.unpack(">IIBB", head[16:26])
        if width == 0 or height == 0 or bits not in (1, 2, 4, 8, 16) or colour not in _PNG_PLANES:
            raise CaptureError.single(
                str(path),
                "a PNG header of at least 1 x 1 px, 1, 2, 4, 8 or 16 bits, colour type 0, 2, 3, 4 or 6",
                f"a PNG header of {width} x {height} px, {bits} bits, colour type {colour}",
            )
        planes = _PNG_PLANES[colour]
        shape = (height, width) if planes == 1 else (height, width, planes)
        return Header(shape, np.dtype(np.uint16 if bits > 8 else np.uint8))
    raise CaptureError.single(
        str(path), "a .tif, .tiff or .png file", f"unknown image format {suffix!r}"
    )


def read_image(
    path: str | os.PathLike[str],
    *,
    shape: tuple[int, ...] | None = None,
    max_bytes: int = MAX_FRAME_BYTES,
) -> np.ndarray:
    """Pixel data of a TIFF (tifffile) or PNG (pypng, 16-bit RGB included) file, as stored.

    The header is read first: a file declaring more than ``max_bytes`` of pixels, or (when
    ``shape`` is given) another shape, raises :class:`~.model.CaptureError` (naming the file,
    what was expected and what it declares) before anything is decoded.
    """
    path = Path(path)
    header = read_header(path)
    if header.nbytes > max_bytes:
        raise CaptureError.single(
            str(path),
            f"a frame of at most {max_bytes / 2**20:.0f} MiB",
            f"{_declares(header)}: more than {max_bytes / 2**20:.0f} MiB, not decoded",
        )
    if shape is not None and header.shape != tuple(shape):
        raise CaptureError.single(
            str(path),
            f"a frame of shape {tuple(shape)}",
            f"the file declares shape {header.shape} (not decoded)",
        )
    if path.suffix.lower() == ".png":
        import png

        width, height, rows, info = png.Reader(filename=str(path)).read()
        data = np.empty((height, width * int(info["planes"])), dtype=header.dtype)
        count = 0
        for count, row in enumerate(rows, start=1):
            if count > height:
                break
            data[count - 1] = np.asarray(row, dtype=header.dtype)
        if count != height:
            raise CaptureError.single(
                str(path), f"a PNG file with {height} rows", f"{count} rows could be read"
            )
        data = data.reshape(header.shape)
    else:
        import tifffile

        with tifffile.TiffFile(path) as tif:
            data = np.asarray(tif.series[0].asarray())
    if data.shape != header.shape:
        raise CaptureError.single(
            str(path), f"pixels of the declared shape {header.shape}", f"decoded {data.shape}"
        )
    return data


def _declares(header: Header) -> str:
    size = " x ".join(str(n) for n in header.shape)
    return f"a file declaring {size} {header.dtype} ({header.nbytes / 2**20:,.0f} MiB)"


def reader_failure(error: Exception) -> str:
    """What a reader's error found wrong with a file, without the file's path (a problem names it).

    A :class:`~.model.CaptureError` of :func:`read_header` or :func:`read_image` gives what it
    found; a decoder's own error (tifffile, pypng, ``OSError``) its type and message.
    """
    if isinstance(error, SpectralizeError) and error.problems:
        return "; ".join(p.found if isinstance(p, Problem) else str(p) for p in error.problems)
    return f"{type(error).__name__}: {error}".strip()[:200]


def probe(
    path: Path,
    rgb: bool,
    bit_depth: int,
    *,
    frame_shape: tuple[int, int] | None = None,
    decode: bool = True,
    max_bytes: int = MAX_FRAME_BYTES,
) -> tuple[tuple[int, int] | None, str | None, str | None]:
    """Check one image file against its camera: its header first, then (``decode``) its values.

    Parameters
    ----------
    path
        The image file.
    rgb
        Whether it is an RGB camera's ``(y, x, 3)`` image (else a monochrome ``(y, x)`` one).
    bit_depth
        The camera's bit depth: pixels must be 16-bit (or 8-bit for at most 8 bits) and at
        most ``2**bit_depth - 1``.
    frame_shape
        The run's frame shape ``(y, x)``: a file declaring another one is refused undecoded.
    decode
        Decode the pixels to check their values (``False``: the header only).
    max_bytes
        A file declaring more bytes of pixels than this is refused undecoded.

    Returns
    -------
    shape, expected, found
        The frame shape ``(y, x)`` and ``None, None`` for a good file; else ``None`` and what
        was expected and found (a problem's wording).
    """
    if not path.is_file():
        return None, "an image file", "no such file"
    try:
        header = read_header(path)
    except Exception as error:  # any parser error: the file is unreadable
        return None, "a readable TIFF or PNG file", reader_failure(error)
    want = (3,) if rgb else ()
    if len(header.shape) != 2 + len(want) or header.shape[2:] != want:
        kind = "an RGB image (y, x, 3)" if rgb else "a monochrome image (y, x)"
        return None, kind, f"shape {header.shape}"
    allowed = (np.uint16, np.uint8) if bit_depth <= 8 else (np.uint16,)
    if header.dtype not in allowed:
        bits = "8- or 16-bit" if bit_depth <= 8 else "16-bit"
        return None, f"{bits} unsigned integer pixels ({bit_depth}-bit camera)", f"{header.dtype}"
    shape = (int(header.shape[0]), int(header.shape[1]))
    if header.nbytes > max_bytes:
        return (
            None,
            f"a frame of at most {max_bytes / 2**20:.0f} MiB",
            f"{_declares(header)}, not decoded",
        )
    if frame_shape is not None and shape != tuple(frame_shape):
        return (
            None,
            f"frames of {frame_shape[0]} x {frame_shape[1]} px like the others",
            f"{shape[0]} x {shape[1]} px (declared in its header, not decoded)",
        )
    if not decode:
        return shape, None, None
    try:
        data = read_image(path, shape=header.shape, max_bytes=max_bytes)
    except Exception as error:  # any decoder error: the file is unreadable
        return None, "a readable TIFF or PNG file", reader_failure(error)
    top = int(data.max()) if data.size else 0
    if top > 2**bit_depth - 1:
        return (
            None,
            f"values up to {2**bit_depth - 1} (a {bit_depth}-bit camera, right-aligned)",
            f"a value of {top}",
        )
    return shape, None, None
