"""Accuracy of several reconstructions of the same run, side by side (baselines).

:func:`compare_methods` evaluates each method's cube against the ground truth like
:func:`~.accuracy.evaluate` does and keeps the statistics per subset of images, over a
``reconstruction`` dim: the comparison table of the report's "Baselines" section.

References
----------
Fast Capture of Spectral Image Series, sec. 2 ("Hybrid Methods": pseudo-inverse and
Wiener-type estimates) and sec. 5.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import xarray as xr

from spectralize.schemas import Problem, SchemaError

from .band_shots import band_shot_images, image_index
from .cubes import check_pair, cube, cube_problems, string_labels
from .pixel_metrics import METRICS, pixel_maps
from .statistics import DEFAULT_THRESHOLD, subset_statistics

__all__ = ["METHOD_DIM", "compare_methods"]

#: Dim of :func:`compare_methods` (not ``method``, which ``Dataset.sel`` takes as an option).
METHOD_DIM: str = "reconstruction"


def _method_cubes(
    candidates: Mapping[str, xr.DataArray | xr.Dataset] | xr.Dataset,
) -> dict[str, xr.DataArray | xr.Dataset]:
    if isinstance(candidates, xr.Dataset):
        radiance = candidates.get("radiance")
        dim = next(
            (d for d in (METHOD_DIM, "method") if radiance is not None and d in radiance.dims), None
        )
        if radiance is None or dim is None:
            raise SchemaError(
                "cannot compare methods:",
                [
                    Problem(
                        "baselines:radiance",
                        f"radiance ({METHOD_DIM}, image, wavelength, y, x)",
                        "nothing" if radiance is None else f"dims {radiance.dims}",
                    )
                ],
            )
        names = [
            str(m)
            for m in (radiance[dim].values if dim in radiance.coords else range(radiance.sizes[dim]))
        ]
        return {name: radiance.isel({dim: i}, drop=True) for i, name in enumerate(names)}
    return dict(candidates)


def compare_methods(
    candidates: Mapping[str, xr.DataArray | xr.Dataset] | xr.Dataset,
    truth: xr.Dataset | xr.DataArray,
    *,
    shots: xr.Dataset | None = None,
    illuminant: str = "D65",
    threshold: float = DEFAULT_THRESHOLD,
) -> xr.Dataset:
    """Accuracy of several reconstructions of the same run, side by side (baseline table).

    Parameters
    ----------
    candidates
        Method name -> reconstructed ``radiance`` (image, wavelength, y, x) (a DataArray, or
        a Dataset holding it, e.g. the ``spectra`` of
        :func:`~spectralize.nodes.reconstruction.reconstruct` with a baseline ``method``);
        or one Dataset with ``radiance`` (reconstruction, image, wavelength,
        y, x) (a dim called ``method`` is accepted too).
    truth
        Group ``truth/spectra``.
    shots, illuminant, threshold
        As for :func:`~.accuracy.evaluate`.

    Returns
    -------
    xarray.Dataset
        Over ``reconstruction`` (:data:`METHOD_DIM`, the method names):
        ``{nrmse, spectral_angle, delta_e}_subset_statistics`` (reconstruction, subset,
        statistic), ``nrmse_subset_fraction_below`` and ``subset_pixel_count``
        (reconstruction, subset); lazy when the inputs are.

    Raises
    ------
    SchemaError
        If there is no method, or a cube does not fit the truth (see
        :func:`~.pixel_metrics.normalised_rmse`).

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 2 ("Hybrid Methods": pseudo-inverse and
    Wiener-type estimates) and sec. 5.
    """
    cubes = _method_cubes(candidates)
    if not cubes:
        raise SchemaError(
            "cannot compare methods:", [Problem("candidates", "at least one method", "none")]
        )
    problems = cube_problems(truth, "truth")
    if problems:
        raise SchemaError("cannot compare methods:", problems)
    t = cube(truth)
    masks: dict[str, np.ndarray] = {"all": np.ones(t.sizes["image"], dtype=bool)}
    if shots is not None:
        has = band_shot_images(shots, image_index(t)).values
        masks.update(with_band_shots=has, without_band_shots=~has)
    rows = []
    for candidate in cubes.values():
        s, t = check_pair(candidate, truth)
        maps = pixel_maps(s, t, tuple(METRICS), illuminant=illuminant)
        rows.append(subset_statistics(maps, masks, threshold))
    out = xr.concat(
        rows, dim=METHOD_DIM, coords="minimal", compat="override", join="override"
    ).assign_coords({METHOD_DIM: string_labels(list(cubes))})
    out.attrs = {"illuminant": illuminant, "threshold": float(threshold)}
    return out
