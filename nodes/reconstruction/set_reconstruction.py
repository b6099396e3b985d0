"""Reconstruction of a whole run, image set by image set (paper sec. 4, "Calibration" and 5).

A run is reconstructed in the sets chosen by :mod:`~spectralize.nodes.reconstruction.image_sets`.
One seed set is solved first from a cold start (:func:`reconstruct_seed_set`); every other set
starts from spectra transported from the seed through appearance neighbourhoods
(:mod:`~spectralize.nodes.reconstruction.warm_start`) and is solved independently, so the sets
run in parallel on dask (:func:`reconstruct_image_sets`). The cube is written set by set: each
set is one resumable region of the ``spectra`` group, so a crash loses at most the sets in
flight.

The node functions' keyword-only arguments are the nodes' parameters (the engine derives
the parameter models from them; :mod:`~spectralize.nodes.reconstruction.declarations`
declares the nodes); ``method`` takes exactly the names of
:data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 4 and 5.
"""

from __future__ import annotations

import time
from typing import Annotated, Any

import dask
import dask.array as da
import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.engine import Choices
from spectralize.schemas import ReconstructionError

from .api import reconstruct
from .confidence import neighbourhood_spread
from .image_sets import set_members
from .methods import DEFAULT_METHOD, RECONSTRUCTION_METHODS, get_method
from .warm_start import transport_spectra

__all__ = [
    "solve_set",
    "reconstruct_seed_set",
    "reconstruct_image_sets",
]

_PER_IMAGE = ("camera", "rotation", "led", "theta_i", "phi_i", "theta_o", "phi_o")


# The set nodes' parameters, shared by the seed set and the other sets.
Method = Annotated[
    str,
    Choices(RECONSTRUCTION_METHODS, "reconstruction method"),
    Field(description="reconstruction method: a solver of eq. 1 or a baseline"),
]
GammaHat = Annotated[
    float,
    Field(
        ge=0, description="neighbour-term weight (eq. 4; paper: 20 for multi-image sets); solvers only"
    ),
]
Tolerance = Annotated[
    float, Field(gt=0, description="relative normal-equation residual to stop at; solvers only")
]
MaxIterations = Annotated[int, Field(ge=1, description="iteration limit per set; solvers only")]
Neighbours = Annotated[
    int, Field(ge=1, description="appearance neighbours per pixel (paper: 3); solvers only")
]
Prior = Annotated[
    float | None,
    Field(
        ge=0,
        description="weight of the guided prior (None: the method's default, 0.1 for "
        "guided-prior-pcg, 0 for block-jacobi-pcg); only methods with a prior",
    ),
]
WarmStartPixels = Annotated[
    int, Field(ge=1000, description="seed pixels used to transport spectra to the other sets")
]


def _method_options(
    method: str, *, gamma_hat: float, tolerance: float, max_iterations: int, k: int, prior: float | None
) -> dict[str, Any]:
    """The settings ``method`` takes: all of them for a solver, none for a baseline.

    Raises
    ------
    ReconstructionError
        For an unknown method, or a ``prior`` for a method without one.
    """
    options = get_method(method).options
    if prior is not None and "prior" not in options:
        takers = [name for name, m in RECONSTRUCTION_METHODS.items() if "prior" in m.options]
        raise ReconstructionError(
            f"prior: method {method!r} has no prior; methods with one: {', '.join(takers)}"
        )
    settings = {
        "gamma_hat": gamma_hat,
        "tolerance": tolerance,
        "max_iterations": max_iterations,
        "k": k,
        "prior": prior,
    }
    return {name: value for name, value in settings.items() if name in options and value is not None}


def _set_inputs(
    hdr: xr.Dataset, bands: xr.Dataset, labels: np.ndarray
) -> tuple[xr.DataArray, xr.DataArray]:
    """The HDR RGB of the images ``labels`` and the band shots that pair with them."""
    rgb = hdr["radiance"].sel(image=labels)
    shots = bands["radiance"].isel(shot=np.flatnonzero(np.isin(bands["image"].values, labels)))
    return rgb, shots


def solve_set(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    *,
    initial: xr.DataArray | None = None,
    method: str = DEFAULT_METHOD,
    gamma_hat: float = 20.0,
    tolerance: float = 1e-3,
    max_iterations: int = 400,
    k: int = 3,
    prior: float | None = None,
) -> tuple[xr.DataArray, int, float]:
    """Reconstruct one image set (eq. 1 or a baseline).

    Parameters
    ----------
    rgb, shots, camera_matrix
        The set's HDR RGB ``(image, y, x, channel)``, its band shots ``(shot, y, x)`` and
        ``C`` (see :func:`~spectralize.nodes.reconstruction.reconstruct`).
    initial
        Warm start ``(image, wavelength, y, x)`` (solvers only; ignored by a baseline).
    method
        A name in :data:`~spectralize.nodes.reconstruction.methods.RECONSTRUCTION_METHODS`.
    gamma_hat, tolerance, max_iterations, k, prior
        Solver settings (a baseline takes none of them; ``prior=None``: the method's
        default).

    Returns
    -------
    tuple
        ``(spectra, iterations, seconds)``.

    Raises
    ------
    ReconstructionError
        For a set without band shots, and everything :func:`reconstruct` raises.
    """
    if shots.sizes["shot"] == 0:
        raise ReconstructionError(
            "an image set without any band shot cannot be solved on its "
            "own: it needs at least one image with bands"
        )
    options = _method_options(
        method, gamma_hat=gamma_hat, tolerance=tolerance, max_iterations=max_iterations, k=k, prior=prior
    )
    if initial is not None and "initial" in get_method(method).options:
        options["initial"] = initial
    start = time.perf_counter()
    result = reconstruct(
        rgb.load(), shots.load(), camera_matrix, method=method, full_output=True, **options
    )
    return result.spectra, int(result.iterations), time.perf_counter() - start


def _camera_matrix(calibration: xr.Dataset, wavelength: np.ndarray) -> xr.DataArray:
    """``C`` of a group of schema ``camera_matrix`` on the bands' wavelengths (within 0.5 nm)."""
    matrix = calibration["camera_matrix"].load()
    return matrix.sel(wavelength=wavelength, method="nearest", tolerance=0.5).assign_coords(
        wavelength=wavelength
    )


def _wavelengths(bands: xr.Dataset) -> np.ndarray:
    """The distinct band wavelengths [nm] of a ``bands`` group, increasing."""
    return np.unique(np.asarray(bands["wavelength"].values, dtype=float))


def reconstruct_seed_set(
    hdr: xr.Dataset,
    bands: xr.Dataset,
    calibration: xr.Dataset,
    image_sets: xr.Dataset,
    *,
    method: Method = DEFAULT_METHOD,
    gamma_hat: GammaHat = 20.0,
    tolerance: Tolerance = 1e-3,
    max_iterations: MaxIterations = 400,
    k: Neighbours = 3,
    prior: Prior = None,
) -> xr.Dataset:
    """Solve the seed set from a cold start (eq. 1 by any solver, or a baseline).

    Parameters
    ----------
    hdr
        Group ``hdr``: ``radiance`` (image, y, x, channel).
    bands
        Group ``bands``: ``radiance`` (shot, y, x) with per-shot ``wavelength``, ``image``,
        ``filter_size``.
    calibration
        A group with ``camera_matrix`` (channel, wavelength): ``calibration/spectral`` (the
        flows' default binding) or, to isolate the reconstruction, ``truth/camera``.
    image_sets
        Group ``image_sets``; its ``seed_set`` attr names the set solved here.
    method, gamma_hat, tolerance, max_iterations, k, prior
        Method and solver settings (see :func:`spectralize.nodes.reconstruction.reconstruct`);
        a baseline takes none of the solver settings.

    Returns
    -------
    xarray.Dataset
        Group ``spectra_seed``: ``radiance`` (image, wavelength, y, x) of every member of the
        seed set, attrs ``seed_set``, ``iterations``, ``seconds``.
    """
    seed = int(image_sets.attrs["seed_set"])
    members, _ = set_members(image_sets, seed)
    wavelength = _wavelengths(bands)
    rgb, shots = _set_inputs(hdr, bands, members)
    spectra, iterations, seconds = solve_set(
        rgb,
        shots,
        _camera_matrix(calibration, wavelength),
        method=method,
        gamma_hat=gamma_hat,
        tolerance=tolerance,
        max_iterations=max_iterations,
        k=k,
        prior=prior,
    )
    spectra = spectra.drop_vars(
        [c for c in spectra.coords if c not in ("image", "wavelength", *_PER_IMAGE)]
    )
    return xr.Dataset(
        {"radiance": spectra.assign_attrs(units="1", long_name="relative spectral radiance")},
        attrs={
            "seed_set": seed,
            "iterations": iterations,
            "seconds": round(seconds, 3),
            "method": method,
            **({} if prior is None else {"prior": prior}),
        },
    )


def _solve_region(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    owned: np.ndarray,
    warm: tuple[np.ndarray, np.ndarray] | None,
    settings: dict,
) -> tuple[np.ndarray, np.ndarray]:
    """Solve one set: the owned images' cube (image, wavelength, y, x) float32, per owned
    image the set's iterations, and the owned images' confidence (image, y, x)
    (:func:`~.confidence.neighbourhood_spread` over the whole set)."""
    initial = None
    if warm is not None and "initial" in get_method(settings["method"]).options:
        source_rgb, source_spectra = warm
        target = rgb.transpose("image", "y", "x", "channel").values
        moved = transport_spectra(source_rgb, source_spectra, target.reshape(-1, 3), k=settings["k"])
        cube = moved.reshape(*target.shape[:3], -1)
        initial = xr.DataArray(
            np.moveaxis(cube, -1, 1),
            dims=("image", "wavelength", "y", "x"),
            coords={"wavelength": camera_matrix["wavelength"].values},
        )
    spectra, iterations, _ = solve_set(rgb, shots, camera_matrix, initial=initial, **settings)
    cube = spectra.transpose("image", "wavelength", "y", "x").values
    spread = neighbourhood_spread(
        np.moveaxis(cube, 1, 0), rgb.transpose("image", "y", "x", "channel").values
    )
    return (
        np.asarray(cube[owned], dtype=np.float32),
        np.full(int(owned.sum()), iterations, dtype=np.int32),
        spread[owned],
    )


def _seed_confidence(cube: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Confidence (image, y, x) of the seed set's owned images from their spectra and RGB."""
    return neighbourhood_spread(np.moveaxis(np.asarray(cube, dtype=np.float64), 1, 0), np.asarray(rgb))


def reconstruct_image_sets(
    hdr: xr.Dataset,
    bands: xr.Dataset,
    calibration: xr.Dataset,
    image_sets: xr.Dataset,
    spectra_seed: xr.Dataset,
    *,
    method: Method = DEFAULT_METHOD,
    gamma_hat: GammaHat = 20.0,
    tolerance: Tolerance = 1e-3,
    max_iterations: MaxIterations = 400,
    k: Neighbours = 3,
    prior: Prior = None,
    warm_start_pixels: WarmStartPixels = 200_000,
) -> xr.Dataset:
    """The spectral cube of the whole run, one lazy dask chunk per image set.

    The seed set's owned images are copied from ``spectra_seed``; every other set is solved
    warm-started from the seed through appearance neighbourhoods in RGB (paper sec. 4). The
    ``image`` dim is ordered by set (the ``image`` coordinate keeps the run's labels, so
    ``spectra.sel(image=...)`` works), one dask chunk per set: the runner writes it set by set.

    Parameters
    ----------
    hdr, bands, calibration, image_sets
        As for :func:`reconstruct_seed_set`.
    spectra_seed
        Group ``spectra_seed`` (:func:`reconstruct_seed_set`): the seed set's spectra.
    method, gamma_hat, tolerance, max_iterations, k, prior
        As for :func:`reconstruct_seed_set`.
    warm_start_pixels
        At most this many seed pixels transport spectra to the other sets' initial guesses.

    Returns
    -------
    xarray.Dataset
        Group ``spectra``: ``radiance`` (image, wavelength, y, x) float32 units ``"1"``,
        ``confidence`` (image, y, x) float32 (:func:`~.confidence.neighbourhood_spread`: an
        estimated per-pixel nRMSE, higher where the result deserves less trust), plus
        ``image_set`` and ``iterations`` (image), lazy.
    """
    seed = int(spectra_seed.attrs["seed_set"])
    wavelength = _wavelengths(bands)
    camera_matrix = _camera_matrix(calibration, wavelength)
    ny, nx = hdr.sizes["y"], hdr.sizes["x"]
    seed_members, seed_owned = set_members(image_sets, seed)
    seed_rgb = hdr["radiance"].sel(image=seed_members).transpose("image", "y", "x", "channel")
    seed_cube = (
        spectra_seed["radiance"].sel(image=seed_members).transpose("image", "y", "x", "wavelength")
    )
    pick = np.random.default_rng(0).permutation(seed_rgb.size // 3)[:warm_start_pixels]
    warm = (seed_rgb.values.reshape(-1, 3)[pick], seed_cube.values.reshape(-1, wavelength.size)[pick])
    settings = {
        "method": method,
        "gamma_hat": gamma_hat,
        "tolerance": tolerance,
        "max_iterations": max_iterations,
        "k": k,
        "prior": prior,
    }
    _method_options(
        method, gamma_hat=gamma_hat, tolerance=tolerance, max_iterations=max_iterations, k=k, prior=prior
    )  # fail before any solve

    pieces, counts, labels, set_of, confidences = [], [], [], [], []
    seed_iterations = int(spectra_seed.attrs.get("iterations", -1))
    for index in range(image_sets.sizes["set"]):
        members, owned = set_members(image_sets, index)
        if not owned.any():
            continue
        shape = (int(owned.sum()), wavelength.size, ny, nx)
        if index == seed:
            block = (
                spectra_seed["radiance"]
                .sel(image=members[owned])
                .transpose("image", "wavelength", "y", "x")
                .data
            )
            block = da.asarray(block).astype(np.float32).rechunk((shape[0], -1, -1, -1))
            count = da.full(shape[0], seed_iterations, dtype=np.int32, chunks=shape[0])
            owned_rgb = hdr["radiance"].sel(image=members[owned]).transpose("image", "y", "x", "channel")
            confidence = da.from_delayed(
                dask.delayed(_seed_confidence, pure=True)(block, owned_rgb.data),
                shape=(shape[0], ny, nx),
                dtype=np.float32,
            )
        else:
            rgb, shots = _set_inputs(hdr, bands, members)
            task = dask.delayed(_solve_region, pure=True)(
                rgb,
                shots,
                camera_matrix,
                owned,
                warm,
                settings,
                dask_key_name=f"solve-set-{index}-{dask.base.tokenize(rgb.data, settings)}",
            )
            block = da.from_delayed(task[0], shape=shape, dtype=np.float32)
            count = da.from_delayed(task[1], shape=shape[:1], dtype=np.int32)
            confidence = da.from_delayed(task[2], shape=(shape[0], ny, nx), dtype=np.float32)
        pieces.append(block)
        counts.append(count)
        confidences.append(confidence)
        labels.extend(members[owned].tolist())
        set_of.extend([index] * shape[0])
    cube = da.concatenate(pieces, axis=0)
    per_image = hdr.drop_vars([v for v in hdr.data_vars]).sel(image=labels).load()
    coords = {name: per_image[name] for name in (*_PER_IMAGE, "image") if name in per_image.coords}
    coords["wavelength"] = ("wavelength", wavelength, {"units": "nm", "long_name": "wavelength"})
    return xr.Dataset(
        {
            "radiance": (
                ("image", "wavelength", "y", "x"),
                cube,
                {"units": "1", "long_name": "relative spectral radiance"},
            ),
            "confidence": (
                ("image", "y", "x"),
                da.concatenate(confidences, axis=0),
                {
                    "units": "1",
                    "long_name": "estimated per-pixel nRMSE of the spectra (higher: trust less)",
                },
            ),
            "image_set": ("image", np.asarray(set_of), {"long_name": "set the image was solved in"}),
            "iterations": (
                "image",
                da.concatenate(counts),
                {
                    "long_name": "solver iterations of the image's set (seed: cold start, others: "
                    "warm-started from the seed)"
                },
            ),
        },
        coords=coords,
        attrs={
            "seed_set": seed,
            "method": method,
            "gamma_hat": gamma_hat,
            **({} if prior is None else {"prior": prior}),
            "seed_iterations": seed_iterations,
            "ordering": "images ordered by image set; use .sel(image=label)",
        },
    )
