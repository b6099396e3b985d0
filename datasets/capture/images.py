"""The image files of a capture folder: read one, and probe it against its camera.

Image files are TIFF (tifffile) or PNG (pypng: Pillow cannot read 16-bit RGB PNG), 16-bit
unsigned (8-bit for cameras of at most 8 bits), monochrome ``(y, x)`` for the spectral camera
and RGB ``(y, x, 3)`` for the RGB cameras, values right-aligned (at most
``2**bit_depth - 1``, as the ADC gives them).

References
----------
Fast Capture of Spectral Image Series, sec. 3 (the cameras), eq. 5 (counts of a camera).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["IMAGE_SUFFIXES", "read_image", "probe"]

IMAGE_SUFFIXES: tuple[str, ...] = (".tif", ".tiff", ".png")
"""The image file names a manifest may list (case-insensitive)."""


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Pixel data of a TIFF (tifffile) or PNG (pypng, 16-bit RGB included) file, as stored."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".tif", ".tiff"):
        import tifffile

        return np.asarray(tifffile.imread(path))
    if suffix == ".png":
        import png

        width, height, rows, info = png.Reader(filename=str(path)).read()
        dtype = np.uint16 if info["bitdepth"] > 8 else np.uint8
        data = np.vstack([np.asarray(row, dtype=dtype) for row in rows])
        planes = int(info["planes"])
        return data.reshape(height, width) if planes == 1 else data.reshape(height, width, planes)
    raise ValueError(f"unknown image format {suffix!r} (use .tif, .tiff or .png)")


def probe(
    path: Path, rgb: bool, bit_depth: int
) -> tuple[tuple[int, int] | None, str | None, str | None]:
    """Check one image file against its camera; decodes the pixels.

    Parameters
    ----------
    path
        The image file.
    rgb
        Whether it is an RGB camera's ``(y, x, 3)`` image (else a monochrome ``(y, x)`` one).
    bit_depth
        The camera's bit depth: pixels must be 16-bit (or 8-bit for at most 8 bits) and at
        most ``2**bit_depth - 1``.

    Returns
    -------
    shape, expected, found
        The frame shape ``(y, x)`` and ``None, None`` for a good file; else ``None`` and what
        was expected and found (a problem's wording).
    """
    if not path.is_file():
        return None, "an image file", "no such file"
    try:
        data = read_image(path)
    except Exception as error:  # any decoder error: the file is unreadable
        return None, "a readable TIFF or PNG file", f"{type(error).__name__}: {error}".strip()[:200]
    want = (3,) if rgb else ()
    if data.ndim != 2 + len(want) or data.shape[2:] != want:
        kind = "an RGB image (y, x, 3)" if rgb else "a monochrome image (y, x)"
        return None, kind, f"shape {data.shape}"
    allowed = (np.uint16, np.uint8) if bit_depth <= 8 else (np.uint16,)
    if data.dtype not in allowed:
        bits = "8- or 16-bit" if bit_depth <= 8 else "16-bit"
        return None, f"{bits} unsigned integer pixels ({bit_depth}-bit camera)", f"{data.dtype}"
    top = int(data.max()) if data.size else 0
    if top > 2**bit_depth - 1:
        return (
            None,
            f"values up to {2**bit_depth - 1} (a {bit_depth}-bit camera, right-aligned)",
            f"a value of {top}",
        )
    return (int(data.shape[0]), int(data.shape[1])), None, None
