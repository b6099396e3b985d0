"""Figures of the calibration (paper Fig. 4): drawing only, no calibration science.

The numbers come from :func:`spectralize.nodes.calibration.spectral.cross_validate` (or the
``calibration/spectral`` group); this module turns them into a matplotlib figure built without
pyplot (no global state).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 and Fig. 4.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = ["plot_cross_validation"]


def plot_cross_validation(
    table: xr.Dataset, *, columns: int = 6, difference_scale: float = 10.0
) -> Figure:
    """Figure in the style of the paper's Fig. 4 from a cross-validation table.

    Panels: (a) measured RGB of the patches, (b) RGB predicted through ``C``, (c) the
    difference scaled by ``difference_scale`` (around mid grey), (d) relative error per
    patch. Swatches are normalised by the brightest measured value and gamma-encoded (1/2.2)
    for display only.

    Parameters
    ----------
    table
        ``measured``, ``predicted`` (patch, channel) and ``relative_error`` (patch), attrs
        ``mean_relative_error`` and ``max_relative_error``: a
        :func:`~spectralize.nodes.calibration.spectral.cross_validate` table.
    columns
        Swatches per row.
    difference_scale
        Gain of panel (c).

    Returns
    -------
    matplotlib.figure.Figure
        Built without pyplot (no global state; saving uses the Agg canvas).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, Fig. 4.
    """
    from matplotlib.figure import Figure

    measured = np.asarray(table["measured"].transpose("patch", "channel").values, dtype=float)
    predicted = np.asarray(table["predicted"].transpose("patch", "channel").values, dtype=float)
    n = measured.shape[0]
    rows = -(-n // columns)
    scale = max(float(np.nanmax(measured)), 1e-300)

    def grid(values: np.ndarray, fill: float) -> np.ndarray:
        out = np.full((rows * columns, values.shape[1]), fill)
        out[:n] = values
        return out.reshape(rows, columns, values.shape[1])[..., :3]

    def encode(values: np.ndarray) -> np.ndarray:
        return np.clip(values / scale, 0, 1) ** (1 / 2.2)

    diff = np.clip(0.5 + difference_scale * (predicted - measured) / scale, 0, 1)
    fig = Figure(figsize=(12, 7), layout="constrained")
    spec = fig.add_gridspec(2, 3)
    panels = [
        (encode(measured), "(a) measured RGB"),
        (encode(predicted), "(b) predicted C S"),
        (diff, f"(c) difference x{difference_scale:g}"),
    ]
    for column, (image, title) in enumerate(panels):
        ax = fig.add_subplot(spec[0, column])
        ax.imshow(grid(image, 1.0), interpolation="nearest")
        ax.set_title(title)
        ax.set_axis_off()
    bar = fig.add_subplot(spec[1, :])
    labels = (
        [str(p) for p in table["relative_error"]["patch"].values]
        if "patch" in table["relative_error"].coords
        else [str(i) for i in range(n)]
    )
    bar.bar(np.arange(n), 100 * np.asarray(table["relative_error"].values), color="0.4")
    bar.set_xticks(np.arange(n), labels, rotation=60, ha="right", fontsize=7)
    bar.set_ylabel("relative error [%]")
    bar.set_title(
        f"(d) per patch: mean {100 * table.attrs.get('mean_relative_error', np.nan):.2f}"
        f" %, max {100 * table.attrs.get('max_relative_error', np.nan):.2f} %"
    )
    return fig
