"""The two spectral cubes an evaluation compares: their checks and their alignment.

The ``evaluate`` node's groups are checked against their schemas by the engine before it
runs, so it checks only what a schema of one group cannot say, that the two cubes fit
together (:func:`align`). The other public functions of the evaluation also take bare
DataArrays (e.g. baseline cubes), so they check those first (:func:`check_pair`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import Problem, SchemaError
from spectralize.schemas.run import SPECTRA

__all__ = ["CUBE_DIMS", "cube", "cube_problems", "align", "check_pair", "string_labels", "as_float64"]


#: Dims of a spectral cube (groups ``spectra`` and ``truth/spectra``), from their schema.
CUBE_DIMS: tuple[str, ...] = next(s.dims for s in SPECTRA.variables if s.name == "radiance")


def cube(data: xr.Dataset | xr.DataArray) -> xr.DataArray:
    """The ``radiance`` of a cube group, or the DataArray itself."""
    return data if isinstance(data, xr.DataArray) else data["radiance"]


def cube_problems(data: xr.Dataset | xr.DataArray, name: str) -> list[Problem]:
    """What keeps ``data`` (called ``name`` in messages) from being a spectral cube."""
    array = data if isinstance(data, xr.DataArray) else data.get("radiance")
    if array is None:
        variables = list(data.data_vars) if isinstance(data, xr.Dataset) else []
        return [
            Problem(f"{name}:radiance", f"a variable 'radiance' {CUBE_DIMS}", f"variables {variables}")
        ]
    if tuple(array.dims) != CUBE_DIMS:
        return [
            Problem(
                f"{name}:radiance",
                f"dims {CUBE_DIMS}",
                f"dims {tuple(array.dims)} shape {tuple(array.shape)}",
            )
        ]
    if "wavelength" not in array.coords:
        return [Problem(f"{name}:wavelength", "coordinate values [nm]", "none")]
    return []


def align(s: xr.DataArray, t: xr.DataArray) -> tuple[xr.DataArray, xr.DataArray]:
    """The reconstruction and its truth on the same images, or every mismatch at once."""
    if (
        "image" in s.indexes
        and "image" in t.indexes
        and not s.indexes["image"].equals(t.indexes["image"])
        and set(s.indexes["image"]) <= set(t.indexes["image"])
    ):
        # a reconstruction written set by set orders its images by set: follow its order
        t = t.sel(image=s.indexes["image"])
    problems = []
    if s.shape != t.shape:
        problems.append(
            Problem(
                "spectra:radiance", f"the shape of truth:radiance {dict(t.sizes)}", f"{dict(s.sizes)}"
            )
        )
    elif not np.allclose(s["wavelength"].values, t["wavelength"].values, rtol=0, atol=1e-6):
        problems.append(
            Problem(
                "spectra:wavelength",
                f"the wavelengths of the truth {t['wavelength'].values.tolist()} nm",
                f"{s['wavelength'].values.tolist()} nm",
            )
        )
    elif (
        "image" in s.indexes
        and "image" in t.indexes
        and not s.indexes["image"].equals(t.indexes["image"])
    ):
        problems.append(
            Problem(
                "spectra:image",
                f"the image labels of the truth {t.indexes['image'].tolist()}",
                f"{s.indexes['image'].tolist()}",
            )
        )
    if problems:
        raise SchemaError("cannot compare the reconstruction with the ground truth:", problems)
    # The truth's coordinates for both, so that arithmetic never realigns (drops) images.
    s = s.reset_coords(drop=True).drop_indexes(list(s.indexes)).drop_vars(list(s.indexes))
    s = s.assign_coords({name: t[name] for name in t.indexes})
    return s, t


def check_pair(
    spectra: xr.Dataset | xr.DataArray, truth: xr.Dataset | xr.DataArray
) -> tuple[xr.DataArray, xr.DataArray]:
    """Both cubes checked, then aligned (:func:`align`); every problem at once."""
    problems = cube_problems(spectra, "spectra") + cube_problems(truth, "truth")
    if problems:
        raise SchemaError("cannot compare the reconstruction with the ground truth:", problems)
    return align(cube(spectra), cube(truth))


def string_labels(values: Sequence[str]) -> np.ndarray:
    """String labels as fixed-width unicode, like the ``channel`` coords of the contract.

    (Object strings would be stored by zarr v3 as variable-length strings, which read back
    as numpy ``StringDType``, a dtype kind the contract's ``kind:UO`` does not accept.)
    """
    return np.array([str(v) for v in values], dtype=str)


def as_float64(array: xr.DataArray) -> xr.DataArray:
    """``array`` as float64 (sums and means over whole images)."""
    return array.astype(np.float64) if array.dtype != np.float64 else array
