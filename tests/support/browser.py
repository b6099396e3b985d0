"""A real headless browser for tests: Debian's chromium-headless-shell (``make browser``)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import png

BROWSERS = ("chromium-headless-shell", "chromium", "chromium-browser")


def browser() -> str:
    """The browser binary; installed by ``make browser`` (``make test`` depends on it)."""
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    raise AssertionError(
        "no headless browser found: run `make browser` (apt-get install chromium-headless-shell)"
    )


def screenshot(page: Path, out: Path, *, width: int = 1280, height: int = 2400) -> np.ndarray:
    """Render ``page`` in headless Chromium and return the screenshot as (y, x, channel) uint8."""
    done = subprocess.run(
        [
            browser(),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            f"--window-size={width},{height}",
            f"--screenshot={out}",
            page.absolute().as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0 and out.is_file(), done.stderr[-2000:]
    w, h, rows, info = png.Reader(filename=str(out)).asRGBA8()
    return np.vstack([np.asarray(row, np.uint8) for row in rows]).reshape(h, w, 4)[..., :3]
