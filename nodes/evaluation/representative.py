"""Representative spectra: pixels picked at low and high error (paper sec. 5, Figures 5, 6).

Per image, for every quantile ``q`` the pixel whose nRMSE is closest to the ``q``-quantile of
the image's finite nRMSE map, with its true and reconstructed spectra (the insets of
Figures 5 and 6).

References
----------
Fast Capture of Spectral Image Series, sec. 5: "We selected representative spectra by
picking both points with low and high RMSE in the color mapped error maps."
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import ParameterError, Problem, SchemaError

from .cubes import check_pair

__all__ = ["DEFAULT_SAMPLE_QUANTILES", "representative_spectra", "representative"]

#: Quantiles of the nRMSE map at which representative pixels are picked (low .. highest).
DEFAULT_SAMPLE_QUANTILES: tuple[float, ...] = (0.05, 0.5, 0.9, 0.99, 1.0)


def _pick_numpy(
    nrmse: np.ndarray, spectra: np.ndarray, truth: np.ndarray, quantiles: np.ndarray
) -> tuple[np.ndarray, ...]:
    """Per leading index: the pixel whose nRMSE is closest to each quantile of the map."""
    lead = nrmse.shape[:-2]
    height, width = nrmse.shape[-2:]
    n_wl = spectra.shape[-3]
    flat_err = nrmse.reshape(-1, height * width)
    flat_s = spectra.reshape(-1, n_wl, height * width)
    flat_t = truth.reshape(-1, n_wl, height * width)
    n_q = len(quantiles)
    ys = np.full((flat_err.shape[0], n_q), -1, dtype=np.int64)
    xs = np.full_like(ys, -1)
    errs = np.full((flat_err.shape[0], n_q), np.nan, dtype=np.float32)
    picked_s = np.full((flat_err.shape[0], n_q, n_wl), np.nan, dtype=np.float32)
    picked_t = np.full_like(picked_s, np.nan)
    for i, row in enumerate(flat_err):
        finite = np.flatnonzero(np.isfinite(row))
        if finite.size == 0:
            continue
        levels = np.quantile(row[finite], quantiles)
        for j, level in enumerate(levels):
            k = finite[np.argmin(np.abs(row[finite] - level))]
            ys[i, j], xs[i, j] = divmod(int(k), width)
            errs[i, j] = row[k]
            picked_s[i, j] = flat_s[i, :, k]
            picked_t[i, j] = flat_t[i, :, k]
    shape = (*lead, n_q)
    return (
        ys.reshape(shape),
        xs.reshape(shape),
        errs.reshape(shape),
        picked_s.reshape(*shape, n_wl),
        picked_t.reshape(*shape, n_wl),
    )


def representative_spectra(
    nrmse: xr.DataArray,
    spectra: xr.DataArray | xr.Dataset,
    truth: xr.DataArray | xr.Dataset,
    *,
    quantiles: Sequence[float] = DEFAULT_SAMPLE_QUANTILES,
) -> xr.Dataset:
    """Pixels picked at low and high error, with their true and reconstructed spectra.

    Per image, for every ``q`` in ``quantiles`` the pixel whose nRMSE is closest to the
    ``q``-quantile of the image's (finite) nRMSE map: ``q = 1`` is the worst pixel.

    Parameters
    ----------
    nrmse
        (image, y, x) map from :func:`~.pixel_metrics.normalised_rmse`.
    spectra, truth
        ``radiance`` (image, wavelength, y, x) of reconstruction and ground truth.
    quantiles
        Quantiles in [0, 1], sorted ascending.

    Returns
    -------
    xarray.Dataset
        Over (image, sample): ``sample_y``, ``sample_x`` int64 [px] (-1 for an image without
        finite nRMSE), ``sample_nrmse`` float32 [1]; over (image, sample, wavelength):
        ``sample_truth`` and ``sample_reconstruction`` float32 [1]. Coord
        ``sample_quantile`` (sample). Lazy per image (one image per dask chunk).

    Raises
    ------
    SchemaError
        If the cubes do not fit together (see :func:`~.pixel_metrics.normalised_rmse`) or
        ``nrmse`` is not an (image, y, x) map of their size.
    ParameterError
        If ``quantiles`` are not ascending values in [0, 1].

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5: "We selected representative spectra by
    picking both points with low and high RMSE in the color mapped error maps."
    """
    s, t = check_pair(spectra, truth)
    q = _quantiles(quantiles)
    if tuple(nrmse.dims) != ("image", "y", "x") or nrmse.shape != (
        s.sizes["image"],
        s.sizes["y"],
        s.sizes["x"],
    ):
        raise SchemaError(
            "cannot pick representative spectra:",
            [
                Problem(
                    "nrmse",
                    f"dims ('image', 'y', 'x') with shape "
                    f"{(s.sizes['image'], s.sizes['y'], s.sizes['x'])}",
                    f"dims {nrmse.dims} shape {nrmse.shape}",
                )
            ],
        )
    return representative(nrmse, s, t, q)


def _quantiles(quantiles: Sequence[float]) -> np.ndarray:
    q = np.asarray(list(quantiles), dtype=np.float64)
    if q.size == 0 or np.any(~np.isfinite(q)) or np.any((q < 0) | (q > 1)) or np.any(np.diff(q) < 0):
        raise ParameterError(
            "cannot pick representative spectra:",
            [Problem("sample_quantiles", "ascending values in [0, 1]", str(q.tolist()))],
        )
    return q


def representative(nrmse: xr.DataArray, s: xr.DataArray, t: xr.DataArray, q: np.ndarray) -> xr.Dataset:
    """:func:`representative_spectra` of aligned cubes and checked quantiles ``q``."""
    if any(a.chunks is not None for a in (nrmse, s, t)):
        per_image = {"image": 1, "y": -1, "x": -1}
        nrmse = nrmse.chunk(per_image)
        s = s.chunk({**per_image, "wavelength": -1})
        t = t.chunk({**per_image, "wavelength": -1})
    core = ["wavelength", "y", "x"]
    outputs = xr.apply_ufunc(
        _pick_numpy,
        nrmse,
        s,
        t,
        kwargs={"quantiles": q},
        input_core_dims=[["y", "x"], core, core],
        output_core_dims=[
            ["sample"],
            ["sample"],
            ["sample"],
            ["sample", "wavelength"],
            ["sample", "wavelength"],
        ],
        dask="parallelized",
        output_dtypes=[np.int64, np.int64, np.float32, np.float32, np.float32],
        dask_gufunc_kwargs={"output_sizes": {"sample": q.size}},
    )
    sample_y, sample_x, sample_err, picked_s, picked_t = outputs
    out = xr.Dataset(
        {
            "sample_y": sample_y.assign_attrs(units="px", long_name="row of the picked pixel"),
            "sample_x": sample_x.assign_attrs(units="px", long_name="column of the picked pixel"),
            "sample_nrmse": sample_err.assign_attrs(units="1", long_name="nRMSE of the picked pixel"),
            "sample_truth": picked_t.assign_attrs(
                units="1", long_name="ground-truth spectrum of the picked pixel"
            ),
            "sample_reconstruction": picked_s.assign_attrs(
                units="1", long_name="reconstructed spectrum of the picked pixel"
            ),
        },
    )
    return out.assign_coords(
        sample_quantile=(
            "sample",
            q,
            {"units": "1", "long_name": "quantile of the image's nRMSE map the pixel was picked at"},
        )
    )
