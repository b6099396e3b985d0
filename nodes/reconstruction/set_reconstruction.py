"""Reconstruction of a whole run, image set by image set (paper sec. 4, "Calibration" and 5).

A run is reconstructed in the sets chosen by :mod:`~spectralize.nodes.reconstruction.image_sets`.
One seed set is solved first from a cold start (:func:`reconstruct_seed_set`); every other set
starts from spectra transported from the seed through appearance neighbourhoods
(:mod:`~spectralize.nodes.reconstruction.warm_start`) and is solved independently, so the sets
run in parallel on dask (:func:`reconstruct_image_sets`). Every set is solved tile by tile
with the tasks of :func:`~spectralize.nodes.reconstruction.tiling.tile_tasks`: one dask task
per set and tile, so memory is bounded by tile x set, and for a method with an endmember
dictionary (the default) one more task per set that learns it from a strided sample of the
set, shared by the set's tiles; given the run's endmember library
(:mod:`~spectralize.nodes.reconstruction.endmember_library`, learnt once from the pooled band
shots of a sample of the run's sets), every set and tile mixes its endmembers instead, as every
set starts from the seed's spectra. The cube is written set by set: each set is one resumable
region of the ``spectra`` group, so a crash loses at most the sets in flight. A run of more
than :data:`BATCH_SETS_ABOVE` sets of tiny frames (every set in one tile) solves consecutive
sets in batches of about :data:`BATCH_BYTES` of spectra, one task and one resumable region
per batch, each set solved exactly as its own task would (a full run has thousands of sets).

The node functions' keyword-only arguments are the nodes' parameters (the engine derives
the parameter models from them; :mod:`~spectralize.nodes.reconstruction.declarations`
declares the nodes); ``method`` takes exactly the names of
:data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`. A node resolves its
method with its solver parameters once, at its top (:func:`node_method`), and passes the
resolved record down to every set, batch and tile task.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 4 and 5.
"""

from __future__ import annotations

import functools
import math
from typing import Annotated, Any, cast

import dask
import dask.array as da
import numpy as np
import xarray as xr
from dask.delayed import Delayed
from dask.highlevelgraph import HighLevelGraph
from pydantic import AfterValidator, Field

from spectralize.engine import Choices
from spectralize.schemas.errors import ParameterError, ReconstructionError
from spectralize.schemas.run import SPECTRA, SPECTRA_SEED

from .confidence import neighbourhood_spread
from .estimators.endmember_mixture import Endmembers
from .image_sets import set_members
from .inputs import illuminant_on_bands, in_paired_camera
from .methods import (
    DEFAULT_METHOD,
    RECONSTRUCTION_METHODS,
    SET_MODELS,
    ResolvedMethod,
    resolve_method,
)
from .tiling import (
    TileWindow,
    core_chunks,
    join_tiles,
    set_windows,
    solve_set,
    solve_tile,
    tile_tasks,
)

__all__ = [
    "node_method",
    "library_endmembers",
    "reconstruct_seed_set",
    "reconstruct_image_sets",
    "DISK_TILE",
]

_PER_IMAGE = ("camera", "rotation", "led", "theta_i", "phi_i", "theta_o", "phi_o")


# The set nodes' parameters, shared by the seed set and the other sets.
Method = Annotated[
    str,
    Choices(RECONSTRUCTION_METHODS, "reconstruction method"),
    Field(description="reconstruction method: a production preset (methods.RECONSTRUCTION_METHODS)"),
]
GammaHat = Annotated[
    float | None,
    Field(
        ge=0,
        description="neighbour-term weight (eq. 4; None: the method's, 20 for a set and 1 for "
        "one image as in the paper); solvers only",
    ),
]
Tolerance = Annotated[
    float | None,
    Field(
        gt=0,
        description="relative normal-equation residual to stop at (None: the method's); solvers only",
    ),
]
MaxIterations = Annotated[
    int | None,
    Field(ge=1, description="iteration limit per set (None: the method's); solvers only"),
]
Neighbours = Annotated[
    int | None,
    Field(
        ge=1,
        description="appearance neighbours per pixel (None: the method's, 3 for eq. 1 as in "
        "the paper, 6 for the prior PCG); solvers only",
    ),
]
Prior = Annotated[
    float | None,
    Field(
        ge=0,
        description="weight of the guided prior (None: the method's); only methods with a prior",
    ),
]
SetModel = Annotated[
    str | None,
    Choices(SET_MODELS, "set model"),
    Field(
        description="how a set's images share spectra after the solve: 'independent', "
        "'shared-texel' (per-texel shapes shared by the set's images), 'material-pooled' "
        "(one shape per material, fitted to its texels' pooled band shots) or "
        "'evidence-blend' ('material-pooled', then, with the run's library, each texel's "
        "material choice weighed in by its band evidence); all but 'independent' need the "
        "calibration's illuminant; None: the method's (the default's: 'evidence-blend' "
        "where the calibration has the illuminant, else 'independent'); solvers only",
    ),
]
RunLibrary = Annotated[
    bool,
    Field(
        description="mix the endmembers of the run's library (input endmember_library) in "
        "every set; False: each set learns its own from its own band shots",
    ),
]
WarmStartPixels = Annotated[
    int, Field(ge=1000, description="seed pixels used to transport spectra to the other sets")
]

DISK_TILE = 256
"""Tile size [px] of the spectra on disk (the nodes' declared ``y``/``x`` chunks) and the
default tile of a set's solve: a tile that divides it or is a multiple of it keeps every
chunk on disk inside one tile."""


def _aligned_tile(tile: int | None) -> int | None:
    if tile is not None and tile % DISK_TILE and DISK_TILE % tile:
        raise ParameterError(
            f"expected a divisor or a multiple of the {DISK_TILE} px chunks on disk "
            f"(e.g. 64, 128, 256, 512), or None for one tile; found {tile}"
        )
    return tile


Tile = Annotated[
    int | None,
    Field(
        ge=16,
        description=f"tile size [px]: each set is solved tile by tile, every tile with all of "
        f"the set's images and a halo of its largest filter (memory: tile x set); a divisor "
        f"or multiple of {DISK_TILE}; None: the whole image at once",
    ),
    AfterValidator(_aligned_tile),
]


def _set_inputs(
    hdr: xr.Dataset, bands: xr.Dataset, labels: np.ndarray, shot_image: np.ndarray | None = None
) -> tuple[xr.DataArray, xr.DataArray]:
    """The HDR RGB of the images ``labels`` and the band shots that pair with them
    (``shot_image``: the bands' per-shot image labels, if already read)."""
    shot_image = np.asarray(bands["image"].values) if shot_image is None else shot_image
    rgb = hdr["radiance"].sel(image=labels)
    shots = bands["radiance"].isel(shot=np.flatnonzero(np.isin(shot_image, labels)))
    return rgb, shots


def _camera_matrix(
    calibration: xr.Dataset, wavelength: np.ndarray, hdr: xr.Dataset | None = None
) -> xr.DataArray:
    """``C`` of a group of schema ``camera_matrix`` on the bands' wavelengths (within 0.5 nm).

    With ``hdr`` whose images carry a ``camera`` coordinate and a calibration with one
    ``camera_matrices`` (camera, channel, wavelength) per RGB camera: one matrix per camera,
    ``T_k C_k`` (dims ``camera, channel, wavelength``), with ``T_k`` the calibration's
    ``rgb_transform`` of camera ``k`` onto the paired camera. :func:`in_paired_camera` maps
    every image's RGB by that ``T_k``, so ``T_k C_k S`` is exactly what camera ``k``'s image
    holds after the map: each image is reconstructed through its own camera's ``C``, and
    the neighbour search, chromaticities and warm start still compare all images in the
    paired camera's RGB (the 3 x 3 map, exact only on the calibration spectra, decides
    only who is whose neighbour). Where every camera of ``hdr`` has the paired camera's
    ``C`` (one camera, or a ``camera_matrix`` given alone, e.g. the truth): the paired
    camera's ``C`` ``(channel, wavelength)``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1 (``C S(p) - R(p)``) and sec. 4.
    """

    def on_bands(matrix: xr.DataArray) -> xr.DataArray:
        matrix = matrix.sel(wavelength=wavelength, method="nearest", tolerance=0.5)
        return matrix.assign_coords(wavelength=wavelength)

    paired = on_bands(calibration["camera_matrix"].load())
    if hdr is None or "camera_matrices" not in calibration or "camera" not in hdr["radiance"].coords:
        return paired
    matrices = on_bands(calibration["camera_matrices"].load())
    matrices = matrices.drop_vars([c for c in matrices.coords if c not in matrices.dims])
    cameras = sorted({int(c) for c in np.asarray(hdr["camera"].values).ravel()})
    known = [int(c) for c in matrices["camera"].values]
    if any(c not in known for c in cameras):
        raise ReconstructionError(
            f"calibration: camera_matrices has no matrix for RGB camera(s) "
            f"{sorted(set(cameras) - set(known))} of hdr (it has {known})"
        )
    per_camera = []
    for k in cameras:
        c_k = np.asarray(matrices.sel(camera=k).transpose("channel", "wavelength").values, float)
        if "rgb_transform" in calibration:
            t_k = calibration["rgb_transform"].sel(camera=k).transpose("channel", "channel_in").values
            if not np.allclose(t_k, np.eye(3), atol=1e-9, rtol=0):  # as in_paired_camera
                c_k = np.asarray(t_k, float) @ c_k
        per_camera.append(c_k)
    if all(np.array_equal(c, paired.transpose("channel", "wavelength").values) for c in per_camera):
        return paired
    return xr.DataArray(
        np.stack(per_camera),
        dims=("camera", "channel", "wavelength"),
        coords={"camera": cameras, "channel": paired["channel"].values, "wavelength": wavelength},
        attrs={"long_name": "per RGB camera T_k C_k: its C in the paired camera's RGB"},
    )


# -- the nodes' method, resolved once at their top ------------------------------------------------
def node_method(
    method: str,
    *,
    gamma_hat: float | None = None,
    tolerance: float | None = None,
    max_iterations: int | None = None,
    k: int | None = None,
    prior: float | None = None,
    set_model: str | None = None,
) -> ResolvedMethod:
    """The set nodes' ``method`` resolved with their solver parameters, once, before any solve.

    A parameter left None is the method's setting. The solver parameters ``gamma_hat``,
    ``tolerance``, ``max_iterations`` and ``k`` apply to the methods that take them (the
    solvers; their descriptions say so); a ``prior`` or a ``set_model`` for a method without
    one is refused.

    Returns
    -------
    ~.methods.ResolvedMethod
        What the node's sets and tiles are solved with (:func:`~.methods.resolve_method`).

    Raises
    ------
    ReconstructionError
        For an unknown method, a ``prior`` or ``set_model`` the method does not take, or a
        value out of range.
    """
    record = resolve_method(method)
    for name, value in (("set_model", set_model), ("prior", prior)):
        if value is not None and name not in record.options:
            takers = [n for n, m in RECONSTRUCTION_METHODS.items() if name in m.options]
            what = "set model" if name == "set_model" else "prior"
            raise ReconstructionError(
                f"{name}: method {record.name!r} has no {what}; methods with one: {', '.join(takers)}"
            )
    parameters = {
        "gamma_hat": gamma_hat,
        "tolerance": tolerance,
        "max_iterations": max_iterations,
        "k": k,
        "prior": prior,
        "set_model": set_model,
    }
    given = {n: v for n, v in parameters.items() if v is not None and n in record.options}
    return resolve_method(record, **given)


def _illuminant(
    method: ResolvedMethod, calibration: xr.Dataset, wavelength: np.ndarray
) -> xr.DataArray | None:
    """The calibration's illuminant ``L`` (wavelength,) on the bands' ``wavelength`` (linear)
    for the set model of :func:`~.tiling.solve_set`, where the calibration group has one
    (``truth/camera`` does). An unusable one is left out unless a given ``set_model`` needs
    it: a preset's own set model then keeps the solver's spectra. Checked before any solve.

    Raises
    ------
    ReconstructionError
        A given set model other than ``"independent"`` without a usable illuminant in the
        calibration.
    """
    set_model = method.given.get("set_model")
    needs_light = set_model not in (None, "independent")  # given: refused without L
    if "illuminant" not in calibration:
        if needs_light:
            raise ReconstructionError(
                f"set_model: {set_model!r} needs the illuminant L; the calibration group has no "
                f"'illuminant' (wavelength,) (found variables {sorted(map(str, calibration.data_vars))})"
            )
        return None
    light = calibration["illuminant"].load()
    light = light.drop_vars([c for c in light.coords if c != "wavelength"])
    try:
        on_bands = illuminant_on_bands(light, wavelength)
    except ReconstructionError as error:
        if needs_light:
            raise ReconstructionError(f"calibration: {error}") from None
        return None  # unused: not needed
    return xr.DataArray(on_bands, dims="wavelength", coords={"wavelength": wavelength})


def _wavelengths(bands: xr.Dataset) -> np.ndarray:
    """The distinct band wavelengths [nm] of a ``bands`` group, increasing."""
    return np.unique(np.asarray(bands["wavelength"].values, dtype=float))


def _prepared(
    hdr: xr.Dataset, bands: xr.Dataset, calibration: xr.Dataset
) -> tuple[xr.Dataset, np.ndarray, xr.DataArray]:
    """What both nodes solve from: ``hdr`` with each image's RGB in the paired camera's
    (its ``T_k``, :func:`~.inputs.in_paired_camera`), the bands' wavelengths and ``C`` on
    them (``T_k C_k`` per camera ``k``, :func:`_camera_matrix`)."""
    wavelength = _wavelengths(bands)
    camera_matrix = _camera_matrix(calibration, wavelength, hdr)
    return in_paired_camera(hdr, calibration), wavelength, camera_matrix


def _recorded_settings(method: ResolvedMethod) -> dict[str, Any]:
    """The method and its scalar settings (given or the preset's) as attrs."""
    attrs: dict[str, Any] = {"method": method.name}
    for name, value in method.used().items():
        if isinstance(value, bool | np.bool_):
            attrs[name] = int(value)
        elif isinstance(value, int | float | str):
            attrs[name] = value
    return attrs


def _image_coords(hdr: xr.Dataset, labels: Any, wavelength: np.ndarray) -> dict[str, Any]:
    """The ``spectra`` coords of images ``labels`` (in that order): their per-image coords
    of ``hdr`` and ``wavelength``, with the schema's attrs."""
    per_image = hdr.drop_vars(list(hdr.data_vars)).sel(image=labels).load()
    coords: dict[str, Any] = {
        name: per_image[name] for name in ("image", *_PER_IMAGE) if name in per_image.coords
    }
    coords["wavelength"] = ("wavelength", wavelength, SPECTRA.spec("wavelength").attrs)
    return coords


_RADIANCE_ATTRS = SPECTRA.spec("radiance").attrs
_CONFIDENCE_ATTRS = SPECTRA.spec("confidence").attrs
_SEED_ITERATIONS_ATTRS = SPECTRA_SEED.spec("iterations").attrs


def library_endmembers(library: xr.Dataset, wavelength: np.ndarray) -> Endmembers:
    """The :class:`~.estimators.endmember_mixture.Endmembers` of a group
    ``endmember_library`` on the bands' ``wavelength`` (within 0.5 nm), the highlight atom
    last, as the sets' solves take it.

    Raises
    ------
    ReconstructionError
        For a library without one atom on each of the bands' wavelengths, or without exactly
        one highlight atom.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 and 5.
    """
    wavelength = np.asarray(wavelength, dtype=np.float64)
    have = np.asarray(library["wavelength"].values, dtype=np.float64)
    nearest = np.abs(have[None, :] - wavelength[:, None]).argmin(axis=1)
    if have.size == 0 or np.any(np.abs(have[nearest] - wavelength) > 0.5):
        raise ReconstructionError.single(
            "endmember_library: wavelength",
            f"every band wavelength {wavelength.tolist()} nm (within 0.5 nm)",
            f"{have.tolist()} nm",
        )
    highlight = np.asarray(library["highlight"].values, dtype=bool)
    if highlight.sum() != 1:
        raise ReconstructionError.single(
            "endmember_library: highlight", "exactly one highlight atom", f"{int(highlight.sum())}"
        )
    atoms = np.asarray(library["atoms"].transpose("endmember", "wavelength").values, np.float64)
    centre = np.asarray(library["centre"].transpose("endmember", "chromaticity").values, np.float64)
    order = np.concatenate([np.flatnonzero(~highlight), np.flatnonzero(highlight)])
    return Endmembers(
        np.ascontiguousarray(atoms[order][:, nearest]),
        np.ascontiguousarray(centre[~highlight]),
        np.asarray(library["channel_scale"].values, dtype=np.float64),
    )


def _run_endmembers(
    library: xr.Dataset | None, use: bool, method: ResolvedMethod, wavelength: np.ndarray
) -> Endmembers | None:
    """The run's endmember dictionary on the bands' ``wavelength`` for a method that mixes
    endmembers, or None (no library, not used, or a method without a dictionary: each set
    then learns its own where its method needs one)."""
    if library is None or not use or "endmembers" not in method.options:
        return None
    return library_endmembers(library, wavelength)


def _library_task(endmembers: Endmembers | None) -> Delayed | None:
    """The run's dictionary as one dask value every set's tasks share (keyed by its content)."""
    if endmembers is None:
        return None
    token = dask.base.tokenize(endmembers.atoms, endmembers.centres, endmembers.scale)
    return cast(Delayed, dask.delayed(endmembers, name=f"endmember-library-{token}"))


def reconstruct_seed_set(
    hdr: xr.Dataset,
    bands: xr.Dataset,
    calibration: xr.Dataset,
    image_sets: xr.Dataset,
    endmember_library: xr.Dataset | None = None,
    *,
    method: Method = DEFAULT_METHOD,
    gamma_hat: GammaHat = None,
    tolerance: Tolerance = None,
    max_iterations: MaxIterations = None,
    k: Neighbours = None,
    prior: Prior = None,
    set_model: SetModel = None,
    run_library: RunLibrary = True,
    tile: Tile = DISK_TILE,
) -> xr.Dataset:
    """Solve the seed set from a cold start (eq. 1 by any solver, or a baseline), tile by tile.

    Parameters
    ----------
    hdr
        Group ``hdr``: ``radiance`` (image, y, x, channel).
    bands
        Group ``bands``: ``radiance`` (shot, y, x) with per-shot ``wavelength``, ``image``,
        ``filter_size``.
    calibration
        A group with ``camera_matrix`` (channel, wavelength): ``calibration/spectral`` (the
        flows' default binding) or, to isolate the reconstruction, ``truth/camera``. With
        ``camera_matrices`` (camera, channel, wavelength) and ``rgb_transform`` too, each
        image is reconstructed through its own camera's ``C`` (:func:`_camera_matrix`).
        Its ``illuminant`` (wavelength,), where it has one (``truth/camera``), is passed to
        the solve as ``L`` (interpolated onto the bands' wavelengths) for ``set_model``.
    image_sets
        Group ``image_sets``; its ``seed_set`` attr names the set solved here.
    endmember_library
        Group ``endmember_library`` (:func:`~.endmember_library.endmember_library`): the
        run's endmembers, mixed by the set's solve for a method with an endmember dictionary
        (the default); None: the set learns its own.
    method, gamma_hat, tolerance, max_iterations, k, prior
        Method and solver settings (see :func:`spectralize.nodes.reconstruction.reconstruct`);
        a baseline takes none of the solver settings.
    set_model
        ``"independent"`` or ``"shared-texel"`` (a solver's set model, see
        :func:`~spectralize.nodes.reconstruction.reconstruct`; needs the calibration's
        ``illuminant``); None: the method's setting.
    run_library
        Mix the endmembers of ``endmember_library`` (False: the set learns its own, as
        without a library).
    tile
        Tile size [px] (:mod:`~.tiling`): every tile is solved with all images of the set on
        its core plus a halo of the set's largest filter, and its core kept. ``None``, or a
        tile that covers the image: the set is solved whole, in memory.

    Returns
    -------
    xarray.Dataset
        Group ``spectra_seed``: ``radiance`` (image, wavelength, y, x) of every member of the
        seed set, ``iterations`` (image) int32 (the set's solver iterations, the most
        over its tiles) and ``confidence`` (image, y, x) float32 (computed with the solve,
        from its neighbour graph; ``reconstruct_image_sets`` passes it on); attrs
        ``seed_set``, ``method``, ``endmembers`` (``"run"``: the run's library mixed,
        ``"set"``: the set's own, or none), ``tiles`` (and ``tile``, ``halo`` when tiled). Solved
        whole, the data are in memory; tiled, they are lazy: one dask task per tile, chunked
        (all images, all wavelengths, the tile's core), solved as the runner writes them, so
        memory is bounded by tile x set, not by the image size.
    """
    resolved = node_method(
        method,
        gamma_hat=gamma_hat,
        tolerance=tolerance,
        max_iterations=max_iterations,
        k=k,
        prior=prior,
        set_model=set_model,
    )
    seed = int(image_sets.attrs["seed_set"])
    members, _ = set_members(image_sets, seed)
    hdr, wavelength, camera_matrix = _prepared(hdr, bands, calibration)
    illuminant = _illuminant(resolved, calibration, wavelength)
    endmembers = _run_endmembers(endmember_library, run_library, resolved, wavelength)
    rgb, shots = _set_inputs(hdr, bands, members)
    windows, halo = set_windows(shots, hdr.sizes["y"], hdr.sizes["x"], tile)
    if len(windows) == 1:
        spectra, iterations, _ = solve_set(
            rgb,
            shots,
            camera_matrix,
            method=resolved,
            illuminant=illuminant,
            endmembers=endmembers,
            confidence=True,
        )
        spread: np.ndarray | da.Array | None = (
            spectra["confidence"].transpose("image", "y", "x").values.astype(np.float32)
        )
        spectra = spectra.drop_vars(
            [c for c in spectra.coords if c not in ("image", "wavelength", *_PER_IMAGE)]
        )
        count: np.ndarray | da.Array = np.full(len(members), iterations, dtype=np.int32)
    else:
        cube, count, spread = tile_tasks(
            rgb,
            shots,
            camera_matrix,
            windows,
            method=resolved,
            illuminant=illuminant,
            endmembers=_library_task(endmembers),
            confidence=True,
            name=f"solve-seed-{seed}",
        )
        spectra = xr.DataArray(
            cube,
            dims=("image", "wavelength", "y", "x"),
            coords=_image_coords(hdr, members, wavelength),
            attrs={**_recorded_settings(resolved), "tile": tile, "halo": halo},
        )
    return xr.Dataset(
        {
            "radiance": spectra.assign_attrs(_RADIANCE_ATTRS),
            "iterations": ("image", count, _SEED_ITERATIONS_ATTRS),
            # kept here so that ``reconstruct_image_sets`` need not search neighbours again
            "confidence": (("image", "y", "x"), spread, _CONFIDENCE_ATTRS),
        },
        attrs={
            "seed_set": seed,
            **_given_attrs(resolved, "prior", "set_model"),
            "endmembers": "run" if endmembers is not None else "set",
            "tiles": len(windows),
            **({"tile": tile, "halo": halo} if len(windows) > 1 else {}),
        },
    )


def _given_attrs(method: ResolvedMethod, *names: str) -> dict[str, Any]:
    """The group attrs of a node's method: its name, and those of ``names`` the caller gave."""
    return {"method": method.name, **{n: method.given[n] for n in names if n in method.given}}


def _tile_confidence(cube: np.ndarray, rgb: np.ndarray, inner: tuple[slice, slice]) -> np.ndarray:
    """Confidence (image, y, x) on a tile's core from its window's spectra (image, wavelength,
    y, x) and RGB (image, y, x, channel)."""
    cube = np.moveaxis(np.asarray(cube, dtype=np.float64), 1, 0)
    iy, ix = inner
    return neighbourhood_spread(cube, np.asarray(rgb), region=inner)[:, iy, ix]


def _warm_sample(
    rgb: xr.DataArray, cube: xr.DataArray, count: int, *also: Any
) -> tuple[np.ndarray, np.ndarray, list]:
    """At most ``count`` seed pixels for the warm start, without reading the whole seed set.

    ``rgb`` (image, y, x, channel) and ``cube`` (image, y, x, wavelength) are read on a
    strided grid per image, its offset drawn per image (so a texture whose period divides
    the stride is still sampled at every phase), then cut to ``count`` at random. ``also``:
    more lazy values computed in the same pass (a lazy seed's tiles are solved once).

    Returns
    -------
    tuple
        ``(rgb (n, 3), spectra (n, wavelength), [computed also])``.
    """
    n_image, height, width = rgb.sizes["image"], rgb.sizes["y"], rgb.sizes["x"]
    stride = max(1, math.ceil(math.sqrt(n_image * height * width / count)))
    rng = np.random.default_rng(0)
    offsets = rng.integers(0, stride, size=(n_image, 2))
    pieces = []
    for m, (oy, ox) in enumerate(offsets):
        where = {"image": m, "y": slice(int(oy), None, stride), "x": slice(int(ox), None, stride)}
        pieces.append(rgb.isel(where).transpose("y", "x", "channel").data)
        pieces.append(cube.isel(where).transpose("y", "x", "wavelength").data)
    computed = dask.compute(*pieces, *also)
    source_rgb = np.concatenate([np.asarray(p).reshape(-1, 3) for p in computed[0 : len(pieces) : 2]])
    spectra = np.concatenate(
        [np.asarray(p).reshape(-1, cube.sizes["wavelength"]) for p in computed[1 : len(pieces) : 2]]
    )
    if len(source_rgb) > count:
        pick = np.sort(rng.permutation(len(source_rgb))[:count])
        source_rgb, spectra = source_rgb[pick], spectra[pick]
    return source_rgb, spectra, list(computed[len(pieces) :])


BATCH_SETS_ABOVE = 64
"""A run with more sets than this, each solved in one tile (tiny frames), solves consecutive
sets in batches (:func:`_solve_sets`): one task and one read of the inputs per batch, not
per set, so that the cost per set does not dominate a run of thousands of sets."""
BATCH_BYTES = 32 * 2**20
"""Spectra a batch of sets returns at most (at least one set)."""


def _solve_sets(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    shot_image: np.ndarray,
    camera_matrix: xr.DataArray,
    sets: list[tuple[np.ndarray, np.ndarray]],
    *,
    method: ResolvedMethod,
    illuminant: xr.DataArray | None,
    warm: Any,
    endmembers: Endmembers | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve a batch of sets, each whole in one tile, one after the other (one dask task).

    Each set is :func:`~.tiling.solve_tile` on its own images' RGB and band shots, cut
    from the batch's inputs, exactly as its own tile task would (:func:`~.tiling.tile_tasks`
    with one window): the results do not depend on the batching.

    Parameters
    ----------
    rgb
        HDR RGB ``(image, y, x, channel)`` of every image of the batch's sets.
    shots, shot_image
        Their band shots ``(shot, y, x)`` and each shot's image label.
    camera_matrix
        ``C`` (as :func:`~.tiling.tile_tasks` takes it).
    sets
        Per set ``(labels, owned)`` (:func:`~.image_sets.set_members`), in order.
    method, illuminant, warm, endmembers
        As for :func:`~.tiling.solve_tile` (``endmembers``: the run's dictionary, or None).

    Returns
    -------
    tuple of numpy.ndarray
        The owned images' spectra ``(image, wavelength, y, x)`` float32, iterations
        ``(image,)`` int32 and confidence ``(image, y, x)`` float32, set after set.
    """
    cubes: list[np.ndarray] = []
    counts: list[np.ndarray] = []
    spreads: list[np.ndarray] = []
    for members, owned in sets:
        set_rgb = rgb.sel(image=members)
        set_shots = shots.isel(shot=np.flatnonzero(np.isin(shot_image, members)))
        (window,), _ = set_windows(set_shots, rgb.sizes["y"], rgb.sizes["x"], None)
        oy, ox = window.outer
        cube, count, spread = solve_tile(
            set_rgb.isel(y=oy, x=ox),
            set_shots.isel(y=oy, x=ox),
            camera_matrix,
            window.inner,
            method=method,
            illuminant=illuminant,
            keep=owned,
            warm=warm,
            confidence=True,
            endmembers=endmembers,
            images=float(np.count_nonzero(owned)),  # the progress display counts images
        )
        cubes.append(cube)
        counts.append(count)
        spreads.append(cast(np.ndarray, spread))  # given with confidence=True
    return np.concatenate(cubes), np.concatenate(counts), np.concatenate(spreads)


def _row_blocks(data: da.Array, positions: np.ndarray) -> tuple[list[tuple], np.ndarray]:
    """The dask keys of the chunks of ``data`` (chunked along its first axis only) that hold
    rows ``positions``, and where each row is in those chunks joined in that order."""
    bounds = np.cumsum((0, *data.chunks[0]))
    block = np.searchsorted(bounds, positions, side="right") - 1
    needed, which = np.unique(block, return_inverse=True)
    start = np.cumsum(np.concatenate([[0], np.diff(bounds)[needed]]))[:-1]
    rest = (0,) * (data.ndim - 1)
    keys = [(data.name, int(b), *rest) for b in needed]
    return keys, start[which] + (positions - bounds[block])


def _by_rows(ds: xr.Dataset, dim: str) -> xr.Dataset:
    """``ds`` with ``radiance`` chunked along ``dim`` only, ``dim`` first, its coordinates in
    memory (small: one chunk each in a full run's store)."""
    var = ds["radiance"].transpose(dim, ...)
    var = var.chunk({d: -1 for d in var.dims if d != dim})
    coords = {n: c.load() for n, c in var.coords.items() if n not in var.indexes}
    return ds.assign(radiance=var.assign_coords(coords))


def _batch_from_rows(
    rgb_rows: list[np.ndarray],
    shot_rows: list[np.ndarray],
    warm: Any,
    endmembers: Endmembers | None,
    *,
    rgb_take: np.ndarray,
    shot_take: np.ndarray,
    rgb_dims: tuple[str, ...],
    rgb_coords: dict[str, Any],
    shot_dims: tuple[str, ...],
    shot_coords: dict[str, Any],
    shot_image: np.ndarray,
    camera_matrix: xr.DataArray,
    sets: list[tuple[np.ndarray, np.ndarray]],
    method: ResolvedMethod,
    illuminant: xr.DataArray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_solve_sets` on a batch's rows, picked from the chunks that hold them."""
    rgb = xr.DataArray(np.concatenate(rgb_rows)[rgb_take], dims=rgb_dims, coords=rgb_coords)
    shots = xr.DataArray(np.concatenate(shot_rows)[shot_take], dims=shot_dims, coords=shot_coords)
    return _solve_sets(
        rgb,
        shots,
        shot_image,
        camera_matrix,
        sets,
        method=method,
        illuminant=illuminant,
        warm=warm,
        endmembers=endmembers,
    )


def _batch_tasks(
    hdr: xr.Dataset,
    bands: xr.Dataset,
    shot_image: np.ndarray,
    camera_matrix: xr.DataArray,
    sets: list[tuple[np.ndarray, np.ndarray]],
    *,
    method: ResolvedMethod,
    illuminant: xr.DataArray | None,
    warm: Any,
    endmembers: Delayed | None,
    name: str,
) -> tuple[da.Array, da.Array, da.Array]:
    """The lazy results of :func:`_solve_sets` on a batch: spectra, iterations, confidence.

    The batch's task is written by hand on the chunks of ``hdr`` and ``bands`` that hold its
    images (:func:`_row_blocks`; both chunked along their first dim only, as
    :func:`reconstruct_image_sets` gives them): a dask selection of the images per batch
    would build and optimise a graph over every chunk of the run for every batch, a cost
    that grows with the run times its batches. ``endmembers``: the run's dictionary as one
    shared task (:func:`_library_task`), or None.
    """
    labels = np.unique(np.concatenate([members for members, _ in sets]))
    rgb = hdr["radiance"]
    rgb_at = rgb.indexes["image"].get_indexer(labels)
    picked = np.flatnonzero(np.isin(shot_image, labels))
    shots = bands["radiance"]
    rgb_keys, rgb_take = _row_blocks(rgb.data, rgb_at)
    shot_keys, shot_take = _row_blocks(shots.data, picked)
    token = dask.base.tokenize(
        rgb.data.name, shots.data.name, rgb_at, picked, camera_matrix.values, method,
        illuminant, [tuple(m) for m, _ in sets], warm, endmembers,
    )  # fmt: skip
    key = f"{name}-{token}"
    solve = functools.partial(
        _batch_from_rows,
        rgb_take=rgb_take,
        shot_take=shot_take,
        rgb_dims=tuple(map(str, rgb.dims)),
        rgb_coords={str(n): (c.dims, c.values) for n, c in rgb.isel(image=rgb_at).coords.items()},
        shot_dims=tuple(map(str, shots.dims)),
        shot_coords={str(n): (c.dims, c.values) for n, c in shots.isel(shot=picked).coords.items()},
        shot_image=shot_image[picked],
        camera_matrix=camera_matrix,
        sets=sets,
        method=method,
        illuminant=illuminant,
    )
    library = None if endmembers is None else endmembers.key
    layer: dict[Any, Any] = {key: (solve, list(rgb_keys), list(shot_keys), warm.key, library)}
    needed = [rgb.data, shots.data, warm, *([] if endmembers is None else [endmembers])]
    graph = HighLevelGraph.from_collections(key, layer, dependencies=needed)
    task: Any = Delayed(key, graph, length=3)  # indexable: a delayed tuple of three
    n_owned = sum(int(owned.sum()) for _, owned in sets)
    ny, nx = hdr.sizes["y"], hdr.sizes["x"]
    shape = (n_owned, camera_matrix.sizes["wavelength"], ny, nx)
    return (
        da.from_delayed(task[0], shape=shape, dtype=np.float32),
        da.from_delayed(task[1], shape=shape[:1], dtype=np.int32),
        da.from_delayed(task[2], shape=(n_owned, ny, nx), dtype=np.float32),
    )


def reconstruct_image_sets(
    hdr: xr.Dataset,
    bands: xr.Dataset,
    calibration: xr.Dataset,
    image_sets: xr.Dataset,
    spectra_seed: xr.Dataset,
    endmember_library: xr.Dataset | None = None,
    *,
    method: Method = DEFAULT_METHOD,
    gamma_hat: GammaHat = None,
    tolerance: Tolerance = None,
    max_iterations: MaxIterations = None,
    k: Neighbours = None,
    prior: Prior = None,
    set_model: SetModel = None,
    run_library: RunLibrary = True,
    warm_start_pixels: WarmStartPixels = 200_000,
    tile: Tile = DISK_TILE,
) -> xr.Dataset:
    """The spectral cube of the whole run, lazy: one dask task per image set and tile
    (per batch of sets, for many sets of tiny frames: :data:`BATCH_SETS_ABOVE`).

    The seed set's owned images are copied from ``spectra_seed``; every other set is solved
    warm-started from the seed through appearance neighbourhoods in RGB (paper sec. 4), tile
    by tile (:mod:`~.tiling`: each tile with all images of the set, on its core plus a halo of
    the set's largest filter; inputs are cut lazily from ``hdr`` and ``bands``, so a task
    reads its window only). The ``image`` dim is ordered by set (the ``image`` coordinate
    keeps the run's labels, so ``spectra.sel(image=...)`` works); the dask chunks are (the
    set's owned images, all wavelengths, the tile's core): the runner writes set by set, tile
    by tile, and memory is bounded by tile x set (times the tasks in flight), not by the
    image size. Pass ``spectra_seed`` as written to the store (the flows do): a lazy,
    unwritten seed is solved again wherever it is read.

    Parameters
    ----------
    hdr, bands, calibration, image_sets
        As for :func:`reconstruct_seed_set`.
    spectra_seed
        Group ``spectra_seed`` (:func:`reconstruct_seed_set`): the seed set's spectra.
    endmember_library
        Group ``endmember_library``: the run's endmembers, one shared task handed to every
        set and tile (as the warm start's seed pixels are); None: each set learns its own.
    method, gamma_hat, tolerance, max_iterations, k, prior, set_model, run_library, tile
        As for :func:`reconstruct_seed_set`.
    warm_start_pixels
        At most this many seed pixels (read on a strided grid, not the whole seed set)
        transport spectra to the other sets' initial guesses.

    Returns
    -------
    xarray.Dataset
        Group ``spectra``: ``radiance`` (image, wavelength, y, x) float32 units ``"1"``,
        ``confidence`` (image, y, x) float32 (:func:`~.confidence.neighbourhood_spread`: an
        estimated per-pixel nRMSE, higher where the result deserves less trust), plus
        ``image_set`` and ``iterations`` (image, the most over the set's tiles), lazy.
    """
    resolved = node_method(
        method,
        gamma_hat=gamma_hat,
        tolerance=tolerance,
        max_iterations=max_iterations,
        k=k,
        prior=prior,
        set_model=set_model,
    )
    seed = int(spectra_seed.attrs["seed_set"])
    hdr, wavelength, camera_matrix = _prepared(hdr, bands, calibration)
    warm, seed_iterations = _warm_start_source(hdr, image_sets, spectra_seed, warm_start_pixels)
    illuminant = _illuminant(resolved, calibration, wavelength)
    library = _library_task(_run_endmembers(endmember_library, run_library, resolved, wavelength))

    image_sets = image_sets.load()  # small: read once, not once per set
    shot_image = np.asarray(bands["image"].values)
    sets = [(i, *set_members(image_sets, i)) for i in range(image_sets.sizes["set"])]
    sets = [(index, members, owned) for index, members, owned in sets if owned.any()]
    ny, nx = hdr.sizes["y"], hdr.sizes["x"]
    whole = tile is None or (ny <= tile and nx <= tile)  # every set solved in one tile
    per_image = (camera_matrix.sizes["wavelength"] + 1) * ny * nx * np.dtype(np.float32).itemsize
    batch_images = BATCH_BYTES // per_image if whole and len(sets) > BATCH_SETS_ABOVE else 0
    if batch_images:  # batches read their rows chunk by chunk (_batch_tasks)
        hdr, bands = _by_rows(hdr, "image"), _by_rows(bands, "shot")
    pieces, counts, confidences, labels, set_of = [], [], [], [], []
    confidence: da.Array | None  # every set's task computes it (confidence=True)
    for batched, group in _task_groups(sets, seed, batch_images):
        if batched:
            block, count, confidence = _batch_tasks(
                hdr,
                bands,
                shot_image,
                camera_matrix,
                [(members, owned) for _, members, owned in group],
                method=resolved,
                illuminant=illuminant,
                warm=warm,
                endmembers=library,
                name=f"solve-sets-{group[0][0]}-{group[-1][0]}",
            )
        else:
            ((index, members, owned),) = group
            rgb, shots = _set_inputs(hdr, bands, members, shot_image)
            windows, _ = set_windows(shots, ny, nx, tile)
            if index == seed:
                block, count, confidence = _seed_copy(spectra_seed, hdr, members[owned], windows)
            else:
                block, count, confidence = tile_tasks(
                    rgb,
                    shots,
                    camera_matrix,
                    windows,
                    method=resolved,
                    illuminant=illuminant,
                    keep=owned,
                    warm=warm,
                    endmembers=library,
                    confidence=True,
                    name=f"solve-set-{index}",
                )
        pieces.append(block)
        counts.append(count)
        confidences.append(confidence)
        for index, members, owned in group:
            labels.extend(members[owned].tolist())
            set_of.extend([index] * int(owned.sum()))
    return xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                da.concatenate(pieces, axis=0),
                _RADIANCE_ATTRS,
            ),
            "confidence": (("image", "y", "x"), da.concatenate(confidences, axis=0), _CONFIDENCE_ATTRS),
            "image_set": ("image", np.asarray(set_of), {"long_name": "set the image was solved in"}),
            "iterations": ("image", da.concatenate(counts), _SET_ITERATIONS_ATTRS),
        },
        coords=_image_coords(hdr, labels, wavelength),
        attrs={
            "seed_set": seed,
            **_given_attrs(resolved, "gamma_hat", "prior", "set_model"),
            "seed_iterations": seed_iterations,
            "endmembers": "run" if library is not None else "set",
            **({} if tile is None else {"tile": tile}),
            "ordering": "images ordered by image set; use .sel(image=label)",
        },
    )


_SET_ITERATIONS_ATTRS = {
    "long_name": "solver iterations of the image's set (seed: cold start, others: "
    "warm-started from the seed)"
}


def _warm_start_source(
    hdr: xr.Dataset, image_sets: xr.Dataset, spectra_seed: xr.Dataset, pixels: int
) -> tuple[Delayed, int]:
    """The seed pixels every other set's warm start is transported from, as one dask task
    shared by the run's sets, and the seed set's iterations (read in the same pass).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4.
    """
    members, _ = set_members(image_sets, int(spectra_seed.attrs["seed_set"]))
    rgb = hdr["radiance"].sel(image=members).transpose("image", "y", "x", "channel")
    cube = spectra_seed["radiance"].sel(image=members).transpose("image", "y", "x", "wavelength")
    counts = spectra_seed["iterations"].sel(image=members)
    source_rgb, source_spectra, (seed_count,) = _warm_sample(rgb, cube, pixels, counts.max().data)
    warm = (source_rgb, source_spectra)
    return dask.delayed(warm, name=f"warm-start-{dask.base.tokenize(*warm)}"), int(seed_count)


def _task_groups(
    sets: list[tuple[int, np.ndarray, np.ndarray]], seed: int, batch_images: int
) -> list[tuple[bool, list[tuple[int, np.ndarray, np.ndarray]]]]:
    """The run's sets ``(index, members, owned)`` in order, grouped as the tasks that solve
    them: ``(True, sets)`` a batch of consecutive sets of at most ``batch_images`` owned
    images (at least one set), ``(False, [set])`` a set of its own (the seed set always;
    every set without batching, ``batch_images == 0``)."""
    groups: list[tuple[bool, list[tuple[int, np.ndarray, np.ndarray]]]] = []
    batch: list[tuple[int, np.ndarray, np.ndarray]] = []
    for index, members, owned in sets:
        if index != seed and batch_images:
            size = sum(int(o.sum()) for _, _, o in batch)
            if batch and size + int(owned.sum()) > batch_images:
                groups.append((True, batch))
                batch = []
            batch.append((index, members, owned))
            continue
        if batch:
            groups.append((True, batch))
            batch = []
        groups.append((False, [(index, members, owned)]))
    if batch:
        groups.append((True, batch))
    return groups


def _seed_copy(
    spectra_seed: xr.Dataset, hdr: xr.Dataset, owned: np.ndarray, windows: list[TileWindow]
) -> tuple[da.Array, da.Array, da.Array]:
    """The seed set's owned images ``owned`` (labels) as the ``spectra`` group holds them:
    spectra, iterations and confidence copied from ``spectra_seed``, chunked by the tiles'
    cores; a seed group written before it kept its confidence gets it computed again, tile
    by tile, from its spectra and ``hdr``'s RGB."""
    n_owned = len(owned)
    block = spectra_seed["radiance"].sel(image=owned).transpose("image", "wavelength", "y", "x")
    block = da.asarray(block.data).astype(np.float32).rechunk((n_owned, -1, *core_chunks(windows)))
    count = da.asarray(spectra_seed["iterations"].sel(image=owned).data).astype(np.int32)
    if "confidence" in spectra_seed:  # solved with the seed set
        kept = spectra_seed["confidence"].sel(image=owned).transpose("image", "y", "x")
        return block, count, da.asarray(kept.data).astype(np.float32)
    rgb = hdr["radiance"].sel(image=owned).transpose("image", "y", "x", "channel")
    tiles = [
        da.from_delayed(
            dask.delayed(_tile_confidence, pure=True)(
                block[:, :, w.outer[0], w.outer[1]], rgb.data[:, w.outer[0], w.outer[1]], w.inner
            ),
            shape=(n_owned, *w.core_shape),
            dtype=np.float32,
        )
        for w in windows
    ]
    return block, count, join_tiles(tiles, windows)
