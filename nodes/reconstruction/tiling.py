"""Tiled set reconstruction: eq. 1 solved tile by tile over all images of a set.

Eq. 1 couples every pixel of every image of a set, so a whole set at the paper's resolution
(20 images of 2048 x 2048 px) does not fit in memory. Its terms are local or nearly so: a
filter constraint ``F_i`` reaches ``s_i`` pixels (a Gaussian of ``sigma_i = s_i / 5``
truncated at ``5 sigma_i``, paper section 3, "Filtering"), the RGB term is per pixel, and the
appearance neighbourhoods ``N_p`` of a rectified set link a texel mostly to the same texel in
the set's other images and to look-alikes nearby. So a set is cut into spatial tiles, each
solved on its *outer window*: the tile's *core* plus a *halo* of at least the largest filter
support, clipped to the image, with every image of the set (the same texel across the set's
rectified images is in the same tile, and ``N_p`` is searched among the window's pixels of
all of them). Only the core is kept; the cores partition the image.

Halo: filter centres keep ``s_i`` from the borders of the solved window
(:func:`~.operators.filter_centres`), so a window border leaves a band of ``s_i`` px that
the filters of band ``b_i`` do not constrain; a halo of ``s_max`` keeps that band out of the
core. Measured (:func:`default_halo`, Notes): no halo costs 23 % in median nRMSE, a halo of
``s_max`` about 4 % on the same small tiles, and more halo little more. What remains is not at
the borders (no seam) but in what a tile learns from its own pixels: the neighbourhoods,
searched among its window's pixels only (fewer look-alikes to pool band data over, fewer
distant metamers linked), and the default method's endmember dictionary. The dictionary is
therefore learnt once per set (:func:`shared_endmembers`, on a strided sample of the whole
set) and shared by all its tiles. Measured with the default method (``benchmarks/
paper_scale.py``, 20 x 256^2 glossy-mosaic set, 128 px tiles): median 1.004x and p95 1.001x
the untiled solve's nRMSE (eq. 1 before: 1.020x and 1.015x); 8-image 128^2 sets in 64 px
tiles, every hard scene: 1.001-1.017x and 0.999-1.012x. Tiles that learnt their own
dictionaries were 0.96-1.24x there (0.90x / 0.86x on the 256^2 set: a local dictionary can
fit better, but not reliably). The per-scene table in :func:`default_halo`'s Notes is of
eq. 1, before the shared dictionary.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1, "Filtering", "Filter
   Placement") and section 4 (sets of 20 images).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from spectralize.nodes.filter_size import filter_radius
from spectralize.schemas import ReconstructionError

__all__ = [
    "HALO_PER_FILTER_SIZE",
    "TileWindow",
    "tile_windows",
    "default_halo",
    "check_windows",
    "solve_set_tiled",
    "sample_grid",
    "shared_endmembers",
]

HALO_PER_FILTER_SIZE: float = 1.0
"""Default halo in units of the largest filter support ``s_max`` (the kernel radius of
:func:`~spectralize.nodes.filter_size.filter_radius`).

A halo of ``s_max`` removes the error of the truncated filters at window borders; a larger
one buys little for its cost (see :func:`default_halo`, Notes).
"""


@dataclass(frozen=True)
class TileWindow:
    """One tile of an image: its core and the outer window it is solved on.

    Attributes
    ----------
    outer
        ``(y, x)`` slices of the outer window in image pixels: the core plus the halo,
        clipped to the image.
    core
        ``(y, x)`` slices of the core in image pixels; the cores of
        :func:`tile_windows` partition the image.
    """

    outer: tuple[slice, slice]
    core: tuple[slice, slice]

    @property
    def inner(self) -> tuple[slice, slice]:
        """``(y, x)`` slices of the core inside the outer window (to crop a window's result)."""
        return tuple(
            slice(c.start - o.start, c.stop - o.start)
            for c, o in zip(self.core, self.outer, strict=True)
        )

    @property
    def label(self) -> str:
        """The core in image pixels, for people: ``"tile y 0:256, x 256:512"``."""
        (y, x) = self.core
        return f"tile y {y.start}:{y.stop}, x {x.start}:{x.stop}"

    @property
    def core_shape(self) -> tuple[int, int]:
        """``(height, width)`` of the core."""
        return tuple(s.stop - s.start for s in self.core)

    @property
    def outer_shape(self) -> tuple[int, int]:
        """``(height, width)`` of the outer window."""
        return tuple(s.stop - s.start for s in self.outer)


def _check_count(name: str, value: object, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < low:
        raise ReconstructionError(f"{name}: expected an integer >= {low}, found {value!r}")
    return int(value)


def _axis_windows(length: int, tile: int, halo: int) -> list[tuple[slice, slice]]:
    """``(outer, core)`` along one axis: cores of ``tile`` px from 0 (the last one shorter),
    each widened by ``halo`` on both sides and clipped to the axis. A window shorter than a
    full border window (``tile + halo``; a short last core) is widened into the image, so
    every window is as long as ``min(length, tile + halo)`` at least."""
    starts = list(range(0, length, tile))
    if len(starts) == 1:
        return [(slice(0, length), slice(0, length))]
    shortest = min(length, tile + halo)
    out = []
    for start in starts:
        stop = min(start + tile, length)
        low, high = max(0, start - halo), min(length, stop + halo)
        if high - low < shortest:
            low, high = (0, shortest) if low == 0 else (length - shortest, length)
        out.append((slice(low, high), slice(start, stop)))
    return out


def tile_windows(height: int, width: int, tile: int, halo: int) -> list[TileWindow]:
    """The tiles of an image of ``height x width`` px: cores and outer windows, row by row.

    The cores are the cells of a regular grid of ``tile x tile`` px anchored at pixel
    ``(0, 0)`` (the last row and column shorter where ``tile`` does not divide the image), so
    they partition the image and line up with chunks of ``tile`` px on disk. Each outer window
    is its core widened by ``halo`` px on every side and clipped to the image; where that
    leaves a window shorter than a full border window (``tile + halo``) along an axis (a short
    last core), it is widened further into the image. An image no larger than one tile is one
    tile whose core and window are the whole image.

    Parameters
    ----------
    height, width
        Image size [px], >= 1.
    tile
        Core size [px], >= 1.
    halo
        Halo [px], >= 0; for eq. 1 at least the largest filter support
        (:func:`default_halo`).

    Returns
    -------
    list of TileWindow
        Row-major: ``windows[i * n_columns + j]`` is the tile in grid row ``i``, column ``j``.

    Raises
    ------
    ReconstructionError
        For a size, tile or halo that is not an integer in range.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filter Placement".

    Examples
    --------
    >>> [w.core for w in tile_windows(4, 6, 3, 1)]  # doctest: +NORMALIZE_WHITESPACE
    [(slice(0, 3, None), slice(0, 3, None)), (slice(0, 3, None), slice(3, 6, None)),
     (slice(3, 4, None), slice(0, 3, None)), (slice(3, 4, None), slice(3, 6, None))]
    """
    height = _check_count("height", height, 1)
    width = _check_count("width", width, 1)
    tile = _check_count("tile", tile, 1)
    halo = _check_count("halo", halo, 0)
    rows, columns = _axis_windows(height, tile, halo), _axis_windows(width, tile, halo)
    return [TileWindow(outer=(oy, ox), core=(cy, cx)) for oy, cy in rows for ox, cx in columns]


def default_halo(
    filter_size: Sequence[float] | np.ndarray, *, factor: float = HALO_PER_FILTER_SIZE
) -> int:
    """The halo [px] of a set's tiles: ``factor`` times its largest filter support, rounded up.

    A Gaussian filter of size ``s_i`` has ``sigma_i = s_i / 5`` and is truncated at
    ``5 sigma_i = s_i`` (:func:`~spectralize.nodes.filter_size.filter_radius`); filter
    centres keep ``s_i`` from every border of the solved window
    (:func:`~.operators.filter_centres`). With a halo of ``s_max`` no core pixel lies in the
    band a window border leaves without its full set of filters, and every filter that
    reaches a core pixel fits in the window.

    Parameters
    ----------
    filter_size
        ``s_i`` [px] of the set's band shots (eq. 3), at least one.
    factor
        Halo per ``s_max``, >= 1.

    Returns
    -------
    int
        ``ceil(factor * s_max)``.

    Raises
    ------
    ReconstructionError
        Without any filter size, for a non-finite or negative one, or ``factor < 1``.

    Notes
    -----
    Measured with ``block-jacobi-pcg`` (the default then; tolerance 1e-3) on the hard
    scenes (:func:`~spectralize.nodes.simulation.scenes.get_scene`; ``s_i`` 6 to 25.6 px,
    ``s_max = 25.6``): the tiled solve's median and p95 per-pixel nRMSE against the truth,
    divided by the untiled solve's (1 = identical; < 1: tiles better)::

        scene            size  images  tile  halo            median  p95
        glossy-mosaic    128   4       64    0               1.231   1.277
        glossy-mosaic    128   4       64    26 (1 s_max)    1.038   1.160
        glossy-mosaic    128   4       64    40 (1.6 s_max)  1.026   1.060
        woven-fabric     160   8       64    26 (1 s_max)    1.058   1.096
        woven-fabric     160   8       64    52 (2 s_max)    1.044   1.061
        woven-fabric     256   8       128   26              1.096   1.091
        woven-fabric     384   8       256   26              1.024   1.001
        woven-fabric     384   8       256   52 (2 s_max)    1.019   0.994
        halftone-print   384   8       256   26              0.900   0.994
        glossy-mosaic    384   8       256   26              1.034   0.981
        dark-still-life  384   8       256   26              1.125   0.998

    A tighter solver tolerance (1e-5) or a shared initial guess leave the ratios as they are
    (glossy-mosaic, 96 px, 4 images, tile 64: median 1.056 and 1.055 against 1.055). The
    differences are spread over the cores, not at their borders: the error within 4 px of an
    internal border, relative to the untiled one there, is 0.93 to 1.04 times the same ratio
    in the cores' interiors at 384 px. So the halo is ``s_max``: below it the truncated
    filters show, above it each tile of 256 px costs ``((256 + 2 halo) / (256 + 2 s_max))^2``
    more (1.37 for ``2 s_max``) for a gain that the neighbourhoods' locality swamps.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3, "Filtering" and
       "Filter Placement".
    """
    sizes = np.asarray(filter_size, dtype=np.float64).ravel()
    if sizes.size == 0:
        raise ReconstructionError(
            "filter_size: expected the filter sizes of at least one band shot, found none"
        )
    if not np.all(np.isfinite(sizes)) or np.any(sizes < 0):
        bad = sizes[~(np.isfinite(sizes) & (sizes >= 0))]
        raise ReconstructionError(
            f"filter_size: expected finite sizes >= 0 px, found {bad[:5].tolist()}"
        )
    if not factor >= 1:
        raise ReconstructionError(
            "factor: expected a halo of at least the largest filter support (factor >= 1), "
            f"found {factor!r}"
        )
    return int(math.ceil(factor * max(filter_radius(s) for s in sizes) - 1e-9))


def _merged_attrs(attrs: list[dict]) -> dict:
    """One record of the tiles' solver attrs: the worst residual and convergence, the most
    iterations, summed time and filter count; other attrs kept where every tile agrees."""
    merged: dict[str, Any] = {}
    rules = {
        "iterations": max,
        "residual_history_length": max,
        "final_relative_residual": max,
        "converged": min,
        "wall_time_s": sum,
        "filter_constraints": sum,
    }
    for key in attrs[0]:
        values = [a.get(key) for a in attrs]
        if key in rules and all(v is not None for v in values):
            merged[key] = rules[key](values)
        elif all(_same(v, values[0]) for v in values[1:]):
            merged[key] = values[0]
    return merged


def _same(a: object, b: object) -> bool:
    try:
        return bool(np.all(a == b))
    except (TypeError, ValueError):
        return False


def solve_set_tiled(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    *,
    tile: int = 256,
    halo: int | None = None,
    initial: xr.DataArray | None = None,
    **settings: Any,
) -> tuple[xr.DataArray, int, float]:
    """Reconstruct one image set tile by tile (eq. 1 on each outer window, cores kept).

    Each tile of :func:`tile_windows` is solved by
    :func:`~.set_reconstruction.solve_set` with all images and band shots of the set cut to
    its outer window (appearance neighbourhoods are searched among the window's pixels of
    every image), and its core is copied into the result. A set no larger than one tile is
    solved whole: the result is exactly :func:`~.set_reconstruction.solve_set`'s.

    Parameters
    ----------
    rgb, shots, camera_matrix
        As for :func:`~.set_reconstruction.solve_set`: HDR RGB ``(image, y, x, channel)``,
        band shots ``(shot, y, x)`` with ``filter_size`` per shot, ``C``. Lazy (dask) inputs
        are read one window at a time.
    tile
        Core size [px].
    halo
        Halo [px]; ``None``: :func:`default_halo` of the shots' filter sizes.
    initial
        Warm start ``(image, wavelength, y, x)`` of the whole image, cut per window.
    **settings
        ``method`` and the solver settings of :func:`~.set_reconstruction.solve_set`.

    Returns
    -------
    tuple
        ``(spectra, iterations, seconds)`` like :func:`~.set_reconstruction.solve_set`:
        ``spectra`` ``(image, wavelength, y, x)`` float32 (attrs: the tiles' most
        iterations, largest final residual, summed wall time, and ``tile``, ``halo``,
        ``tiles``), ``iterations`` the most over the tiles, ``seconds`` the wall time.

    Raises
    ------
    ReconstructionError
        For a tile too small for the set's filters (a window must hold ``2 s_max + 1`` px
        along each axis), and everything :func:`~.set_reconstruction.solve_set` raises.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1) and section 4.
    """
    # set_reconstruction builds its dask tasks from this module's windows, so its solver is
    # imported here, at call time, not at import time
    from .methods import DEFAULT_METHOD, get_method
    from .set_reconstruction import solve_set

    height, width = rgb.sizes["y"], rgb.sizes["x"]
    tile = _check_count("tile", tile, 1)
    if (height <= tile and width <= tile) or shots.sizes.get("shot", 0) == 0:
        return solve_set(rgb, shots, camera_matrix, initial=initial, **settings)
    sizes = shots["filter_size"].values
    halo = default_halo(sizes) if halo is None else _check_count("halo", halo, 0)
    windows = tile_windows(height, width, tile, halo)
    check_windows(windows, sizes)
    started = time.perf_counter()
    if "endmembers" in get_method(settings.get("method", DEFAULT_METHOD)).options:
        settings = {**settings, "endmembers": shared_endmembers(rgb, shots, camera_matrix)}
    cube: np.ndarray | None = None
    coords: dict = {}
    records, iterations = [], 0
    for window in windows:
        oy, ox = window.outer
        spectra, count, _ = solve_set(
            rgb.isel(y=oy, x=ox),
            shots.isel(y=oy, x=ox),
            camera_matrix,
            initial=None if initial is None else initial.isel(y=oy, x=ox),
            where=window.label,
            **settings,
        )
        spectra = spectra.transpose("image", "wavelength", "y", "x")
        if cube is None:
            cube = np.empty((*spectra.shape[:2], height, width), dtype=np.float32)
            coords = dict(spectra.coords)
        iy, ix = window.inner
        cube[:, :, window.core[0], window.core[1]] = spectra.values[:, :, iy, ix]
        records.append(dict(spectra.attrs))
        iterations = max(iterations, int(count))
    attrs = {**_merged_attrs(records), "tile": tile, "halo": halo, "tiles": len(windows)}
    result = xr.DataArray(cube, dims=("image", "wavelength", "y", "x"), coords=coords, attrs=attrs)
    return result, iterations, time.perf_counter() - started


def sample_grid(rgb: xr.DataArray) -> dict[str, slice]:
    """The strided ``isel`` grid of a set whose pixels a dictionary is learnt from: at most
    :data:`~.estimators.endmember_mixture.SAMPLE_PIXELS` over all images (every pixel of a
    smaller set)."""
    from .estimators.endmember_mixture import sample_stride

    n_image = rgb.sizes.get("image", 1)
    stride = sample_stride(n_image, rgb.sizes["y"], rgb.sizes["x"])
    return {"y": slice(None, None, stride), "x": slice(None, None, stride)}


def shared_endmembers(rgb: xr.DataArray, shots: xr.DataArray, camera_matrix: xr.DataArray):
    """The endmember dictionary of a whole set, learnt once for all its tiles.

    The mixture prior of the default method pools the band shots of all pixels of a
    material; a tile learning its own dictionary sees fewer pixels per material and other
    endmembers than its neighbours, so tiles would disagree at their seams and with the
    untiled solve. The dictionary is learnt from the set's pixels on :func:`sample_grid`
    (all of them up to 2 Mpx; lazy inputs are read at the grid's pixels only: pass them
    cut to the grid to keep the read small).

    Returns
    -------
    ~.estimators.endmember_mixture.Endmembers
    """
    from .estimators.endmember_mixture import set_endmembers
    from .inputs import inputs_from_xarray

    grid = sample_grid(rgb)
    inputs = inputs_from_xarray(rgb.isel(grid).load(), shots.isel(grid).load(), camera_matrix)
    return set_endmembers(inputs)


def check_windows(windows: list[TileWindow], filter_size: Sequence[float] | np.ndarray) -> None:
    """Raise :class:`ReconstructionError` when a window cannot hold a filter centre of the
    largest filter (``2 s_max + 1`` px along an axis that is cut into tiles)."""
    largest = float(np.max(filter_size))
    need = 2 * largest + 1
    full = tuple(max(w.outer[a].stop for w in windows) for a in (0, 1))
    for window in windows:
        for axis, name in enumerate(("height", "width")):
            length = window.outer_shape[axis]
            if length < need and length < full[axis]:
                raise ReconstructionError(
                    f"tile: expected tiles whose windows hold the largest filter "
                    f"(s_max = {largest:g} px: a window {name} of at least {need:g} px), found a "
                    f"window {name} of {length} px (core {window.core_shape[axis]} px plus halo); "
                    "choose a larger tile"
                )
