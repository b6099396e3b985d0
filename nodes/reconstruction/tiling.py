"""Tiled set reconstruction: eq. 1 solved tile by tile over all images of a set.

Eq. 1 couples every pixel of every image of a set, so a whole set at the paper's resolution
(20 images of 2048 x 2048 px) does not fit in memory. Its terms are local or nearly so: a
filter constraint ``F_i`` reaches ``s_i`` pixels (a Gaussian of ``sigma_i = s_i / 5``
truncated at ``5 sigma_i``, paper section 3, "Filtering"), the RGB term is per pixel, and the
appearance neighbourhoods ``N_p`` of a rectified set link a texel mostly to the same texel in
the set's other images and to look-alikes nearby. So a set is cut into spatial tiles, each
solved on its *outer window*: the tile's *core* plus a *halo* of the largest filter support
(:func:`default_halo`), clipped to the image, with every image of the set (the same texel
across the set's rectified images is in the same tile, and ``N_p`` is searched among the
window's pixels of all of them). Only the core is kept; the cores partition the image.

What a tile cannot see is the rest of the set: its neighbourhoods find fewer look-alikes,
and a method that learns an endmember dictionary from the pixels it solves would learn a
different one per tile (tiles disagreeing at their seams and with the whole solve). So the
dictionary is learnt once per set from a strided sample of all its pixels
(:func:`shared_endmembers`) and shared by the set's tiles.

This module is the one tiled path. :func:`tile_tasks` builds the dask graph of a set: one
task per tile (:func:`solve_tile`, which solves the window with :func:`solve_set`) and one
that learns the shared dictionary; the flow's nodes
(:mod:`~spectralize.nodes.reconstruction.set_reconstruction`) write those tasks' results
tile by tile, and :func:`solve_tiled` computes the same tasks at once (on the synchronous
scheduler by default) for tests and benchmarks. Dependencies go one way:
``set_reconstruction`` imports this module, never the reverse. How close the tiled solve
comes to the whole one: ``benchmarks/paper_scale.py``, case ``untiled``.

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
from typing import Any, NamedTuple

import dask
import dask.array as da
import numpy as np
import xarray as xr

from spectralize.engine import progress
from spectralize.nodes.filter_size import filter_radius
from spectralize.schemas import ReconstructionError
from spectralize.schemas.run import SPECTRA

from .api import reconstruct
from .estimators.endmember_mixture import Endmembers, sample_stride, set_endmembers
from .heap import keep_freed_memory
from .inputs import inputs_from_xarray
from .methods import MethodLike, resolve_method
from .solvers.common import counting_iterations
from .warm_start import warm_start

__all__ = [
    "HALO_PER_FILTER_SIZE",
    "TileWindow",
    "tile_windows",
    "default_halo",
    "check_windows",
    "set_windows",
    "sample_grid",
    "shared_endmembers",
    "solve_set",
    "solve_tile",
    "TileTasks",
    "tile_tasks",
    "core_chunks",
    "join_tiles",
    "solve_tiled",
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
        (core_y, core_x), (outer_y, outer_x) = self.core, self.outer
        return (
            slice(core_y.start - outer_y.start, core_y.stop - outer_y.start),
            slice(core_x.start - outer_x.start, core_x.stop - outer_x.start),
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
    Why ``s_max`` and no more: below it the truncated filters show at the window borders;
    above it every tile of ``t`` px costs ``((t + 2 halo) / (t + 2 s_max))^2`` more work for
    little gain, because what a tiled solve still loses against the whole one lies in the
    cores (neighbourhoods searched among the window's pixels only), not at their borders.
    The figures: ``benchmarks/paper_scale.py``, case ``untiled``.

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


def set_windows(
    shots: xr.DataArray, height: int, width: int, tile: int | None, halo: int | None = None
) -> tuple[list[TileWindow], int]:
    """The tiles a set is solved in, and their halo: ``(windows, halo)``.

    One window, the whole image (halo 0), when ``tile`` is None or covers the image;
    otherwise :func:`tile_windows` with ``halo`` (None: :func:`default_halo` of the set's
    band shots), checked by :func:`check_windows`. A set without band shots gets windows
    without a halo: :func:`solve_set` says why it cannot be solved when its tasks run.

    Parameters
    ----------
    shots
        The set's band shots ``(shot, y, x)`` with ``filter_size`` per shot.
    height, width
        Image size [px].
    tile
        Core size [px], or None for the whole image.
    halo
        Halo [px]; None: :func:`default_halo`.

    Raises
    ------
    ReconstructionError
        For a tile too small for the set's filters, or a size, tile or halo out of range.
    """
    if tile is None or (height <= tile and width <= tile):
        return tile_windows(height, width, max(height, width), 0), 0
    if shots.sizes["shot"] == 0:
        return tile_windows(height, width, tile, 0), 0
    sizes = np.asarray(shots["filter_size"].values, dtype=np.float64)
    halo = default_halo(sizes) if halo is None else _check_count("halo", halo, 0)
    windows = tile_windows(height, width, tile, halo)
    check_windows(windows, sizes)
    return windows, halo


# -- the set's shared dictionary -----------------------------------------------------------------
def sample_grid(rgb: xr.DataArray) -> dict[str, slice]:
    """The strided ``isel`` grid of a set whose pixels a dictionary is learnt from: at most
    :data:`~.estimators.endmember_mixture.SAMPLE_PIXELS` over all images (every pixel of a
    smaller set, so cutting a sample to its own grid leaves it as it is)."""
    n_image = rgb.sizes.get("image", 1)
    stride = sample_stride(n_image, rgb.sizes["y"], rgb.sizes["x"])
    return {"y": slice(None, None, stride), "x": slice(None, None, stride)}


def shared_endmembers(rgb: xr.DataArray, shots: xr.DataArray, camera_matrix: xr.DataArray) -> Endmembers:
    """The endmember dictionary of a whole set, learnt once for all its tiles.

    The mixture prior of the default method pools the band shots of all pixels of a
    material; a tile learning its own dictionary sees fewer pixels per material and other
    endmembers than its neighbours, so tiles would disagree at their seams and with the
    untiled solve. The dictionary is learnt from the set's pixels on :func:`sample_grid`
    (all of them up to its limit). Lazy inputs are read at the grid's pixels only; pass them
    cut to the grid (as :func:`tile_tasks` does) to hand a task only the sample.

    Parameters
    ----------
    rgb, shots, camera_matrix
        The set's HDR RGB ``(image, y, x, channel)``, band shots ``(shot, y, x)`` and ``C``.

    Returns
    -------
    ~.estimators.endmember_mixture.Endmembers
    """
    grid = sample_grid(rgb)
    inputs = inputs_from_xarray(rgb.isel(grid).load(), shots.isel(grid).load(), camera_matrix)
    return set_endmembers(inputs)


# -- one window ----------------------------------------------------------------------------------
def solve_set(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    *,
    method: MethodLike | None = None,
    initial: xr.DataArray | None = None,
    where: str | None = None,
    endmembers: Endmembers | None = None,
    confidence: bool | tuple[slice, slice] = False,
    illuminant: xr.DataArray | None = None,
    images: float | None = None,
    **options: Any,
) -> tuple[xr.DataArray, int, float]:
    """Reconstruct one image set on one window (eq. 1 or a baseline), in memory.

    The window is the whole image for an untiled solve, or a tile's outer window
    (:func:`solve_tile`). The solve reports its iterations to the progress display
    (:func:`spectralize.engine.progress.task`), labelled by the set's images and ``where``.

    Parameters
    ----------
    rgb, shots, camera_matrix
        The set's HDR RGB ``(image, y, x, channel)``, its band shots ``(shot, y, x)`` and
        ``C`` (see :func:`~spectralize.nodes.reconstruction.reconstruct`), cut to the window.
    method
        A method name, record or resolved record (:func:`~.methods.resolve_method`; None:
        the default).
    initial
        Warm start ``(image, wavelength, y, x)`` (a method that takes one; ignored by the
        others).
    where
        Which part of the images this is (a tile's :attr:`TileWindow.label`), for the
        progress display's label.
    endmembers
        The set's endmember dictionary (:func:`shared_endmembers`), for a method that takes
        one (ignored by the others): the tiles of a set share it.
    confidence
        Also compute the per-pixel confidence (:func:`~.confidence.neighbourhood_spread`,
        from the solver's own neighbourhoods where it has them), as the coordinate
        ``confidence`` ``(image, y, x)`` of ``spectra``; a ``(y, x)`` pair of slices: only
        inside them (a tile's core), NaN elsewhere.
    illuminant
        ``L`` ``(wavelength,)`` for a set model (:data:`~.methods.SET_MODELS`; None: none).
    images
        The run's images this solve completes, for the progress display to count images
        (:func:`spectralize.engine.progress.task`; None: not told).
    **options
        Settings that replace the method's (``gamma_hat``, ``tolerance``, ``set_model``...,
        :func:`~.methods.resolve_method`); one given as None is the method's.

    Returns
    -------
    tuple
        ``(spectra, iterations, seconds)``.

    Raises
    ------
    ReconstructionError
        For a set without band shots, and everything :func:`reconstruct` raises.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1) and section 4.
    """
    if shots.sizes["shot"] == 0:
        raise ReconstructionError(
            "an image set without any band shot cannot be solved on its "
            "own: it needs at least one image with bands"
        )
    resolved = resolve_method(method, **{n: v for n, v in options.items() if v is not None})
    run: dict[str, Any] = {}
    if initial is not None and "initial" in resolved.options:
        run["initial"] = initial
    if endmembers is not None and "endmembers" in resolved.options:
        run["endmembers"] = endmembers
    start = time.perf_counter()
    # named by its images without band shots (the anchors with shots are in every set)
    members = rgb["image"].values.tolist()
    anchors = set(shots["image"].values.tolist())
    named = [str(i) for i in sorted(i for i in members if i not in anchors) or members]
    more = f" and {len(named) - 3} more" if len(named) > 3 else ""
    label = f"images {', '.join(named[:3])}{more}" + (f", {where}" if where else "")
    solver = "callback" in resolved.options
    used = resolved.used()
    # a solver's CG iterations, then its S >= 0 refinement's (told when it is done)
    refinement = int(used.get("projected_iterations", 0))
    total = int(used["max_iterations"]) + refinement if solver else None
    stop = used["tolerance"] if solver else None
    # the display estimates the time left from the convergence rate (residual per iteration)
    with progress.task(
        label, total=total, tolerance=stop, fixed=refinement if solver else 0, images=images
    ) as solving:  # nothing is told when nobody listens
        if solving is not None and solver:
            run["callback"] = counting_iterations(solving.advance, residual=True)
        result = reconstruct(
            rgb.load(),
            shots.load(),
            camera_matrix,
            method=resolved,
            illuminant=illuminant,
            full_output=True,
            confidence=confidence,
            **run,
        )
        if solving is not None and solver:
            solving.advance(int(result.iterations))
    spectra = result.spectra
    if confidence:
        spectra = spectra.assign_coords(confidence=result.confidence)
    return spectra, int(result.iterations), time.perf_counter() - start


# -- one tile --------------------------------------------------------------------------------------
def solve_tile(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    inner: tuple[slice, slice],
    *,
    method: MethodLike | None = None,
    illuminant: xr.DataArray | None = None,
    keep: np.ndarray | None = None,
    warm: tuple[np.ndarray, np.ndarray] | None = None,
    confidence: bool = False,
    where: str | None = None,
    endmembers: Endmembers | None = None,
    images: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Solve one set on one tile's outer window (:func:`solve_set`) and keep the tile's core.

    The process keeps the memory a tile frees for its next one
    (:func:`~.heap.keep_freed_memory`, glibc only; the results do not depend on it).

    Parameters
    ----------
    rgb, shots, camera_matrix
        The set's inputs cut to the window, and ``C``.
    inner
        The core inside the window (:attr:`TileWindow.inner`).
    method
        The method resolved with its options (:func:`~.methods.resolve_method`, as a
        set's tile tasks get it; a name is resolved here; None: the default).
    illuminant
        ``L`` ``(wavelength,)`` for a set model (:func:`solve_set`), or None.
    keep
        Boolean mask over the set's images: those whose core is returned (None: all); the
        others help solve the window only (a set's images owned by another set).
    warm
        Seed pixels' ``(rgb (n, 3), spectra (n, wavelength))``, moved to the window's pixels
        as the initial guess (:func:`~.warm_start.warm_start`; solvers only; None: a cold
        start).
    confidence
        Also return the kept images' :func:`~.confidence.neighbourhood_spread` over the
        window, cut to the core.
    where
        The tile's label in the progress display.
    endmembers
        The set's shared dictionary (:func:`shared_endmembers`), or None.
    images
        The run's images the tile completes (the kept images times its core's share of the
        image), for the progress display (:func:`solve_set`; None: not told).

    Returns
    -------
    tuple
        ``(spectra, iterations, confidence)``: the kept images' spectra ``(image,
        wavelength, y, x)`` float32 on the core, the window's solver iterations per kept
        image (int32), and their confidence ``(image, y, x)`` float32 (None without
        ``confidence``).
    """
    keep_freed_memory()  # the process's next tile reuses this one's freed memory (glibc)
    keep = np.ones(rgb.sizes["image"], dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    method = resolve_method(method)
    initial = None
    if warm is not None and "initial" in method.options:
        source_rgb, source_spectra = warm
        wavelength = camera_matrix["wavelength"].values
        # transported through the caller's k where given, else through 3 RGB neighbours
        k = method.given.get("k") or 3
        initial = warm_start(source_rgb, source_spectra, rgb, wavelength, k=k)
    spectra, iterations, _ = solve_set(
        rgb,
        shots,
        camera_matrix,
        method=method,
        initial=initial,
        where=where,
        endmembers=endmembers,
        confidence=inner if confidence else False,  # the core's: the rest is cut off
        illuminant=illuminant,
        images=images,
    )
    cube = spectra.transpose("image", "wavelength", "y", "x").values
    iy, ix = inner
    spread = None
    if confidence:
        spread = spectra["confidence"].transpose("image", "y", "x").values[:, iy, ix][keep]
    return (  # the core cut before the kept images are: one copy of the core, not the window
        np.ascontiguousarray(cube[:, :, iy, ix][keep], dtype=np.float32),
        np.full(int(keep.sum()), iterations, dtype=np.int32),
        spread,
    )


# -- the tasks of a set --------------------------------------------------------------------------
class TileTasks(NamedTuple):
    """The lazy results of a set's tile tasks (:func:`tile_tasks`), chunked by tile."""

    spectra: da.Array
    """``(image, wavelength, y, x)`` float32 of the kept images; chunks (the kept images,
    all wavelengths, a tile's core)."""
    iterations: da.Array
    """``(image,)`` int32: per kept image the most solver iterations over the set's tiles."""
    confidence: da.Array | None
    """``(image, y, x)`` float32, chunked like ``spectra``; None when not asked for."""


def core_chunks(windows: list[TileWindow]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The cores' heights (along y) and widths (along x): the dask chunks of a tiled result."""
    ys = sorted({(w.core[0].start, w.core[0].stop) for w in windows})
    xs = sorted({(w.core[1].start, w.core[1].stop) for w in windows})
    return tuple(b - a for a, b in ys), tuple(b - a for a, b in xs)


def join_tiles(blocks: list[da.Array], windows: list[TileWindow]) -> da.Array:
    """Per-tile blocks (row-major, like ``windows``) joined along their last two dims."""
    columns = len(core_chunks(windows)[1])
    return da.block([blocks[i : i + columns] for i in range(0, len(blocks), columns)])


def tile_tasks(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    windows: list[TileWindow],
    *,
    method: MethodLike | None = None,
    illuminant: xr.DataArray | None = None,
    keep: np.ndarray | None = None,
    warm: Any = None,
    endmembers: Any = None,
    confidence: bool = False,
    name: str = "solve-set",
) -> TileTasks:
    """The dask graph of one set solved tile by tile: one task per tile, lazy results.

    Each task is :func:`solve_tile` on its window's inputs (cut lazily, so a task reads its
    window only). Every tile task takes the run's endmember dictionary where one is given;
    else, with more than one window and a method that takes an endmember dictionary, one
    more task learns it from the set's :func:`sample_grid` sample (:func:`shared_endmembers`)
    and every tile task takes it. Task keys are deterministic (``{name}-tile-{j}-{token}``,
    the token hashing inputs, method, windows, warm start and dictionary), so a graph built
    twice solves once.

    Parameters
    ----------
    rgb, shots, camera_matrix
        The whole set: HDR RGB ``(image, y, x, channel)``, band shots ``(shot, y, x)`` (lazy
        or in memory) and ``C`` on the shots' wavelengths.
    windows
        The set's tiles (:func:`set_windows`), row-major.
    method
        The method resolved with its options (:func:`~.methods.resolve_method`), passed to
        every tile task as it is (a name is resolved here once; None: the default).
    illuminant
        ``L`` ``(wavelength,)`` for a set model (:func:`solve_set`), or None.
    keep
        Boolean mask over the set's images whose results are returned (None: all).
    warm
        Seed pixels' ``(rgb, spectra)`` for a warm start (:func:`solve_tile`), or a
        :class:`dask.delayed.Delayed` of them (one task shared by a run's sets), or None.
    endmembers
        The run's endmember dictionary (:mod:`~.endmember_library`), or a
        :class:`dask.delayed.Delayed` of it (one task shared by a run's sets), for every
        tile; None: the set's own, learnt from its sample with more than one window.
    confidence
        Also return the per-pixel confidence.
    name
        Prefix of the task keys (the flow: ``solve-seed-{set}``, ``solve-set-{set}``).

    Returns
    -------
    TileTasks
    """
    keep = np.ones(rgb.sizes["image"], dtype=bool) if keep is None else np.asarray(keep, dtype=bool)
    method = resolve_method(method)
    token = dask.base.tokenize(
        rgb.data,
        shots.data,
        camera_matrix.values,
        method,
        illuminant,
        [w.core for w in windows],
        keep,
        warm,
        endmembers,
    )
    n_kept, n_wavelength = int(np.count_nonzero(keep)), camera_matrix.sizes["wavelength"]
    # one dictionary for all tiles of the set: the run's, or the set's own learnt once
    if endmembers is None and len(windows) > 1 and "endmembers" in method.options:
        grid = sample_grid(rgb)  # cut before the task: only the sample is read
        endmembers = dask.delayed(shared_endmembers, pure=True)(
            rgb.isel(grid),
            shots.isel(grid),
            camera_matrix,
            dask_key_name=f"{name}-endmembers-{token}",
        )
    blocks, counts, spreads = [], [], []
    for j, window in enumerate(windows):
        oy, ox = window.outer
        task = dask.delayed(solve_tile, pure=True, nout=3)(
            rgb.isel(y=oy, x=ox),
            shots.isel(y=oy, x=ox),
            camera_matrix,
            window.inner,
            method=method,
            illuminant=illuminant,
            keep=keep,
            warm=warm,
            confidence=confidence,
            where=window.label if len(windows) > 1 else None,
            endmembers=endmembers,
            # the kept images' share in this core, for the progress display's image count
            images=n_kept * float(np.prod(window.core_shape)) / (rgb.sizes["y"] * rgb.sizes["x"]),
            dask_key_name=f"{name}-tile-{j}-{token}",
        )
        shape = (n_kept, n_wavelength, *window.core_shape)
        blocks.append(da.from_delayed(task[0], shape=shape, dtype=np.float32))
        counts.append(da.from_delayed(task[1], shape=shape[:1], dtype=np.int32))
        if confidence:
            spreads.append(da.from_delayed(task[2], shape=(n_kept, *shape[2:]), dtype=np.float32))
    return TileTasks(
        spectra=join_tiles(blocks, windows),
        iterations=da.stack(counts).max(axis=0),
        confidence=join_tiles(spreads, windows) if confidence else None,
    )


def solve_tiled(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    *,
    tile: int | None,
    halo: int | None = None,
    warm: tuple[np.ndarray, np.ndarray] | None = None,
    confidence: bool = False,
    scheduler: str | Any = "synchronous",
    method: MethodLike | None = None,
    illuminant: xr.DataArray | None = None,
    **options: Any,
) -> tuple[xr.DataArray, int, float]:
    """Reconstruct one set tile by tile, now: the flow's tile tasks, computed at once.

    :func:`set_windows` and :func:`tile_tasks` as the flow's nodes use them, computed with
    ``scheduler`` (synchronous by default: one tile after the other in this thread, so a
    test sees every tile's progress in order and a benchmark measures one core). A set
    within one tile is one task on the whole image: the spectra of :func:`solve_set`.

    Parameters
    ----------
    rgb, shots, camera_matrix
        As for :func:`tile_tasks` (lazy inputs are read one window at a time).
    tile
        Core size [px]; None: the whole image at once.
    halo
        Halo [px]; None: :func:`default_halo` of the shots' filter sizes.
    warm
        Seed pixels' ``(rgb, spectra)`` for a warm start, or None.
    confidence
        Also compute the per-pixel confidence, as the coordinate ``confidence``.
    scheduler
        Any dask scheduler (``"synchronous"``, ``"threads"``, a distributed client).
    method, illuminant, **options
        As for :func:`solve_set`: the method is resolved with the options once, here.

    Returns
    -------
    tuple
        ``(spectra, iterations, seconds)``: ``spectra`` ``(image, wavelength, y, x)``
        float32 (attrs ``method``, ``tiles``, and ``tile`` and ``halo`` unless ``tile`` is
        None), ``iterations`` the most
        over the tiles, ``seconds`` the wall time.

    Raises
    ------
    ReconstructionError
        For a tile too small for the set's filters, and everything :func:`solve_set` raises.
    """
    started = time.perf_counter()
    resolved = resolve_method(method, **{n: v for n, v in options.items() if v is not None})
    windows, halo = set_windows(shots, rgb.sizes["y"], rgb.sizes["x"], tile, halo)
    tasks = tile_tasks(
        rgb,
        shots,
        camera_matrix,
        windows,
        method=resolved,
        illuminant=illuminant,
        warm=warm,
        confidence=confidence,
    )
    cube, iterations, spread = dask.compute(*tasks, scheduler=scheduler)
    coords: dict[str, Any] = {str(n): c for n, c in rgb.coords.items() if set(c.dims) <= {"image"}}
    wavelength = camera_matrix["wavelength"].values
    coords["wavelength"] = ("wavelength", wavelength, SPECTRA.spec("wavelength").attrs)
    if confidence:
        coords["confidence"] = (("image", "y", "x"), spread)
    spectra = xr.DataArray(
        cube,
        dims=("image", "wavelength", "y", "x"),
        coords=coords,
        attrs={
            "method": resolved.name,
            "tiles": len(windows),
            **({"tile": tile, "halo": halo} if tile else {}),
        },
    )
    return spectra, int(iterations.max(initial=0)), time.perf_counter() - started
