"""The run's endmember library: material spectra learnt once per run, shared by every set.

A sample's materials recur in every image set of a run; only the light and view change from
set to set. The default method's mixture prior learns its endmembers (the materials'
spectra, :mod:`~.estimators.endmember_mixture`) from the band shots of the set it solves,
where each band is shot once per set and its per-pixel SNR is at or below 1 on hard
scenes. Pooling the band shots of several sets gives each material more shots under more
lights, so its spectrum is learnt with less noise and from more pixels that show it pure.

:func:`endmember_library` pools the images of up to ``sets`` image sets spread over the run
(:func:`library_sets`), on a strided grid that keeps at most
:data:`~.estimators.endmember_mixture.SAMPLE_PIXELS` pixels over all of them, and learns the
library with the same steps a set uses on its own
(:func:`~.estimators.endmember_mixture.set_endmembers`: chromaticity clusters, their pooled
band shapes, abundance and dictionary rounds). The set nodes (:mod:`~.set_reconstruction`)
hand it to every set and tile as the warm start's seed pixels are handed on
(:func:`~.set_reconstruction.library_endmembers` reads it back). How reproducible each
endmember is, is measured without ground truth: the library is learnt again from each half
of the sample (alternate columns of its grid), and each endmember's spectral angle to the
nearest one learnt from a half is kept as ``split_angle``.

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 3, 4 and 5 (eq. 1; the image sets of
   a run).
.. [2] Keshava, N., Mustard, J. F. (2002). Spectral unmixing. IEEE Signal Processing
   Magazine 19(1) (endmembers and the linear mixing model).
.. [3] Kruse, F. A. et al. (1993). The spectral image processing system (SIPS): interactive
   visualization and analysis of imaging spectrometer data. Remote Sensing of Environment
   44(2-3) (the spectral angle).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
import xarray as xr
from pydantic import Field

from spectralize.schemas.errors import ReconstructionError
from spectralize.schemas.run import ENDMEMBER_LIBRARY

from .estimators.endmember_mixture import (
    DEFAULT_ENDMEMBERS,
    Endmembers,
    chromaticity,
    sample_stride,
    set_endmembers,
)
from .image_sets import set_members
from .inputs import ReconstructionInputs, inputs_from_xarray
from .set_reconstruction import _prepared

__all__ = [
    "endmember_library",
    "library_sets",
    "library_from_sample",
    "spectral_angles",
    "DEFAULT_LIBRARY_SETS",
]

DEFAULT_LIBRARY_SETS = 8
"""Image sets whose band shots the run's library pools (spread over the run)."""

LibrarySets = Annotated[
    int,
    Field(ge=1, description="image sets whose band shots are pooled, spread over the run"),
]
LibraryEndmembers = Annotated[
    int,
    Field(ge=1, description="endmembers learnt besides the highlight atom"),
]
LibrarySeed = Annotated[
    int, Field(ge=0, description="seed of the clustering (deterministic result for a seed)")
]


def library_sets(n_sets: int, count: int) -> np.ndarray:
    """Indices of at most ``count`` of a run's ``n_sets`` image sets, evenly spread over it
    (first and last included), increasing."""
    if n_sets < 1:
        raise ReconstructionError.single("image_sets", "at least one image set", "none")
    picked = np.linspace(0, n_sets - 1, min(int(count), n_sets))
    return np.unique(np.round(picked).astype(np.int64))


def spectral_angles(atoms: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per row of ``atoms`` ``(n, w)``, the spectral angle [degree] to the nearest row of
    ``reference`` ``(k, w)``: ``arccos`` of their normalised inner product."""
    a = atoms / np.maximum(np.linalg.norm(atoms, axis=1, keepdims=True), 1e-300)
    r = reference / np.maximum(np.linalg.norm(reference, axis=1, keepdims=True), 1e-300)
    return np.degrees(np.arccos(np.clip(a @ r.T, -1.0, 1.0))).min(axis=1)


def _pooled_sample(
    hdr: xr.Dataset, bands: xr.Dataset, labels: np.ndarray
) -> tuple[xr.DataArray, xr.DataArray, int]:
    """The images ``labels`` and their band shots on the strided grid that keeps at most
    :data:`~.estimators.endmember_mixture.SAMPLE_PIXELS` pixels over all of them, in memory,
    and the stride."""
    stride = sample_stride(len(labels), hdr.sizes["y"], hdr.sizes["x"])
    grid = {"y": slice(None, None, stride), "x": slice(None, None, stride)}
    rgb = hdr["radiance"].sel(image=labels).isel(grid).load()
    shot_image = np.asarray(bands["image"].values)
    shots = bands["radiance"].isel(shot=np.flatnonzero(np.isin(shot_image, labels))).isel(grid)
    return rgb, shots.load(), stride


def _sample_inputs(
    rgb: xr.DataArray, shots: xr.DataArray, camera_matrix: xr.DataArray, stride: int
) -> ReconstructionInputs:
    """The checked inputs of a sample on a grid of ``stride``: the shots' filter sizes
    scaled to the grid and kept within the sample's size (the learning does not use them;
    the input check bounds them by the image size)."""
    largest = (min(rgb.sizes["y"], rgb.sizes["x"]) - 1) / 2
    size = np.minimum(np.asarray(shots["filter_size"].values, dtype=np.float64) / stride, largest)
    shots = shots.assign_coords(filter_size=("shot", np.maximum(size, 1e-3)))
    return inputs_from_xarray(rgb, shots, camera_matrix)


def library_from_sample(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    *,
    stride: int = 1,
    n_endmembers: int = DEFAULT_ENDMEMBERS,
    seed: int = 0,
) -> tuple[Endmembers, ReconstructionInputs]:
    """The library learnt from a pooled sample of a run's images, and the sample's inputs.

    Parameters
    ----------
    rgb, shots
        The pooled images' RGB ``(image, y, x, channel)`` and their band shots ``(shot, y,
        x)`` (coords ``wavelength``, ``image``, ``filter_size``), e.g. several sets of a run
        concatenated along ``image``, on a grid of ``stride``.
    camera_matrix
        ``C`` on the shots' wavelengths, as the set nodes take it.
    stride
        The sample's grid stride (the shots' filter sizes are scaled by it).
    n_endmembers, seed
        As for :func:`endmember_library`.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 to 5.
    """
    inputs = _sample_inputs(rgb, shots, camera_matrix, stride)
    return set_endmembers(inputs, n_endmembers=int(n_endmembers), seed=int(seed)), inputs


def _split_angle(
    rgb: xr.DataArray,
    shots: xr.DataArray,
    camera_matrix: xr.DataArray,
    stride: int,
    atoms: np.ndarray,
    n_endmembers: int,
    seed: int,
) -> np.ndarray:
    """Per endmember of ``atoms``, the mean over the two halves of the sample (even and odd
    columns) of the spectral angle to the nearest endmember learnt from that half; the
    highlight atom against the halves' highlight atoms."""
    angles = []
    for half in (slice(0, None, 2), slice(1, None, 2)):
        inputs = _sample_inputs(rgb.isel(x=half), shots.isel(x=half), camera_matrix, stride)
        other = set_endmembers(inputs, n_endmembers=n_endmembers, seed=seed).atoms
        materials = spectral_angles(atoms[:-1], other[:-1])
        light = spectral_angles(atoms[-1:], other[-1:])
        angles.append(np.concatenate([materials, light]))
    return np.mean(angles, axis=0)


def endmember_library(
    hdr: xr.Dataset,
    bands: xr.Dataset,
    calibration: xr.Dataset,
    image_sets: xr.Dataset,
    *,
    sets: LibrarySets = DEFAULT_LIBRARY_SETS,
    n_endmembers: LibraryEndmembers = DEFAULT_ENDMEMBERS,
    seed: LibrarySeed = 0,
) -> xr.Dataset:
    """Learn the run's endmember library from the pooled band shots of a sample of its sets.

    Parameters
    ----------
    hdr, bands, calibration, image_sets
        As for :func:`~.set_reconstruction.reconstruct_seed_set`: each image's RGB is taken
        in the paired camera's RGB and through its own camera's ``C``, as the sets are
        solved.
    sets
        Image sets pooled, spread over the run (:func:`library_sets`); their member images
        (each once) and band shots are pooled.
    n_endmembers
        ``J``, endmembers besides the highlight atom (fewer on a small sample: at least 256
        clustered pixels each).
    seed
        Seed of the k-means initialisation and sample.

    Returns
    -------
    xarray.Dataset
        Group ``endmember_library`` (schema :data:`~spectralize.schemas.run.ENDMEMBER_LIBRARY`):
        ``atoms`` (endmember, wavelength), relative spectral radiance per unit brightness,
        the highlight atom last (coord ``highlight``); ``centre`` (endmember, chromaticity)
        and ``channel_scale`` (channel,), the chromaticities the sets pick their candidate
        endmembers by; ``split_angle`` (endmember,) [degree]. Attrs: ``image_sets`` (the
        sets pooled), ``images``, ``stride`` (of the sample's grid), ``pixels`` (pooled),
        ``split_angle_median``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, sections 3 to 5.
    """
    hdr, _, camera_matrix = _prepared(hdr, bands, calibration)
    image_sets = image_sets.load()
    chosen = library_sets(image_sets.sizes["set"], sets)
    labels = np.unique(np.concatenate([set_members(image_sets, int(i))[0] for i in chosen]))
    rgb, shots, stride = _pooled_sample(hdr, bands, labels)
    learnt, inputs = library_from_sample(
        rgb, shots, camera_matrix, stride=stride, n_endmembers=int(n_endmembers), seed=int(seed)
    )
    split = _split_angle(rgb, shots, camera_matrix, stride, learnt.atoms, int(n_endmembers), int(seed))
    c = np.asarray(inputs.camera_matrix, dtype=np.float64)
    light_rgb = learnt.atoms[-1:] @ (c if c.ndim == 2 else c[0]).T
    _, light_centre = chromaticity(light_rgb, learnt.scale)
    n_atoms = learnt.atoms.shape[0]
    spec = ENDMEMBER_LIBRARY.spec
    return xr.Dataset(
        {
            "atoms": (("endmember", "wavelength"), learnt.atoms, spec("atoms").attrs),
            "centre": (
                ("endmember", "chromaticity"),
                np.vstack([learnt.centres, light_centre]),
                spec("centre").attrs,
            ),
            "channel_scale": ("channel", learnt.scale, spec("channel_scale").attrs),
            "split_angle": ("endmember", split.astype(np.float32), spec("split_angle").attrs),
        },
        coords={
            "wavelength": ("wavelength", inputs.wavelength, spec("wavelength").attrs),
            "highlight": ("endmember", np.arange(n_atoms) == n_atoms - 1, spec("highlight").attrs),
            "channel": ["R", "G", "B"],
            "chromaticity": ["r", "g"],
        },
        attrs={
            "image_sets": chosen.tolist(),
            "images": len(labels),
            "stride": stride,
            "pixels": int(rgb.sizes["image"] * rgb.sizes["y"] * rgb.sizes["x"]),
            "n_endmembers": n_atoms - 1,
            "split_angle_median": float(np.median(split[:-1])),
        },
    )
