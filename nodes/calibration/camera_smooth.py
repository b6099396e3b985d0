"""The RGB camera matrix ``C`` by second-difference-penalised non-negative least squares.

:func:`camera_matrix` fits ``C`` (channel, wavelength) of eq. 1 to colour-checker patches of
known spectra; :func:`cross_validated_smoothness` chooses its smoothness by leaving each
patch out in turn. The alternative (and default) fit of ``C`` is
:func:`~spectralize.nodes.calibration.camera_lobes.lobe_camera_matrix`.

References
----------
Fast Capture of Spectral Image Series, eq. 1 (matrix ``C``) and section 4.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from spectralize.nodes.calibration.camera_lobes import (
    camera_matrix_dataset,
    chart_arrays,
    check_chart_pair,
    fit_residual,
)
from spectralize.schemas import CalibrationError

__all__ = ["camera_matrix", "SMOOTHNESS_CANDIDATES", "cross_validated_smoothness"]


def _second_difference(n: int) -> np.ndarray:
    d = np.zeros((n - 2, n))
    rows = np.arange(n - 2)
    d[rows, rows], d[rows, rows + 1], d[rows, rows + 2] = 1.0, -2.0, 1.0
    return d


def camera_matrix(
    rgb: xr.DataArray,
    spectra: xr.DataArray,
    *,
    smoothness: float = 1e-3,
    nonnegative: bool = True,
) -> xr.Dataset:
    """The RGB camera matrix ``C`` (channel, wavelength) from colour-checker shots.

    Solves, per channel ``c``, ``min_C ||S C_c - R_c||^2 + mu ||D2 C_c||^2`` subject to
    ``C_c >= 0`` (``scipy.optimize.nnls`` on the augmented system ``[S; sqrt(mu) D2]``),
    where ``S`` (patch, wavelength) holds the known spectral radiance of the patches, ``R``
    (patch, channel) the measured RGB radiance and ``D2`` the second difference along
    wavelength. ``mu = smoothness * ||S||_F^2 / ||D2||_F^2`` makes ``smoothness``
    independent of the units and of the number of patches and bands.

    Parameters
    ----------
    rgb
        Measured RGB radiance of the patches (patch, channel), e.g. :func:`~.patch_means` of
        an HDR image.
    spectra
        Known spectral radiance of the same patches (patch, wavelength): reflectance times
        illuminant, in the units the spectral camera reports.
    smoothness
        Relative weight of the smoothness penalty (0: none). With fewer patches than bands
        (24 colour-checker patches, 32 bands) some smoothness is needed for a unique answer.
    nonnegative
        Constrain ``C >= 0`` (sensitivities cannot be negative).

    Returns
    -------
    xarray.Dataset
        ``camera_matrix`` (channel, wavelength) float64 with units ``"1"``; ``residual``
        (patch, channel), ``S C - R``. Attrs ``smoothness``, ``mu``, ``nonnegative``,
        ``relative_rms_residual``.

    Raises
    ------
    SchemaError
        Wrong dims.
    CalibrationError
        Patches that do not match (count or labels), fewer than 3 bands, NaN or inf.

    Notes
    -----
    Domain: non-negative radiances. Range: ``C >= 0`` when ``nonnegative``. ``predict_rgb``
    gives ``C S`` for any spectra on the same wavelengths.

    References
    ----------
    Fast Capture of Spectral Image Series, eq. 1 (matrix ``C``) and section 4.
    """
    from scipy import optimize

    where = "camera_matrix"
    check_chart_pair(rgb, spectra, where)
    if smoothness < 0:
        raise CalibrationError(f"{where}: smoothness must be >= 0, got {smoothness}")
    s, r = chart_arrays(rgb, spectra, where)
    n_bands = s.shape[1]
    d2 = _second_difference(n_bands)
    mu = smoothness * float(np.sum(s**2)) / float(np.sum(d2**2))
    a = np.vstack([s, np.sqrt(mu) * d2])
    c = np.empty((r.shape[1], n_bands))
    for k in range(r.shape[1]):
        b = np.concatenate([r[:, k], np.zeros(n_bands - 2)])
        if nonnegative:
            c[k] = optimize.nnls(a, b, maxiter=50 * n_bands)[0]
        else:
            c[k] = np.linalg.lstsq(a, b, rcond=None)[0]
    residual, rel = fit_residual(c, s, r)
    wavelength = spectra["wavelength"].values if "wavelength" in spectra.coords else np.arange(n_bands)
    return camera_matrix_dataset(
        c,
        residual,
        rgb,
        wavelength,
        variables={},
        attrs={
            "method": "nnls + second-difference penalty"
            if nonnegative
            else "least squares + second-difference penalty",
            "smoothness": float(smoothness),
            "mu": mu,
            "nonnegative": bool(nonnegative),
            "relative_rms_residual": rel,
        },
    )


SMOOTHNESS_CANDIDATES: tuple[float, ...] = tuple(float(v) for v in np.logspace(-3, 2, 11))
"""Smoothness values :func:`cross_validated_smoothness` chooses from (1e-3 .. 1e2, half decades)."""


def cross_validated_smoothness(
    rgb: xr.DataArray,
    spectra: xr.DataArray,
    *,
    candidates: tuple[float, ...] = SMOOTHNESS_CANDIDATES,
    nonnegative: bool = True,
) -> tuple[float, xr.DataArray]:
    """The smoothness of :func:`camera_matrix` that best predicts a patch left out.

    For every candidate, ``C`` is fitted to all patches but one and predicts the RGB of the
    one left out; the score is the mean over patches of ``|C s_p - R_p|^2 / |R_p|^2``
    (leave-one-out cross-validation). A chart's smooth spectra, under an illuminant with a
    narrow peak, leave many ``C`` that reproduce every patch: the fit alone cannot tell a
    sensitivity that peaks at 600 nm from one that puts its weight where the light is weak,
    and a fixed smoothness that suits one chart and light gives a wrongly shaped ``C`` on
    another. A patch left out is the test the fit has to pass
    (``tests/flows/test_foreign_capture.py`` checks the shape of ``C`` on a foreign capture).

    Parameters
    ----------
    rgb, spectra, nonnegative
        As :func:`camera_matrix`.
    candidates
        Smoothness values to try.

    Returns
    -------
    tuple
        The chosen smoothness (the smallest score, ties to the smoother) and the scores,
        a DataArray over ``smoothness``.

    References
    ----------
    .. [1] Stone, M. (1974). Cross-validatory choice and assessment of statistical
       predictions. J. R. Stat. Soc. B 36(2).
    .. [2] Fast Capture of Spectral Image Series, section 4 (C from a colour checker).
    """
    if not candidates:
        raise CalibrationError("cross_validated_smoothness: no candidate smoothness given")
    n = rgb.sizes["patch"]
    if n < 3:
        raise CalibrationError(f"cross_validated_smoothness: need at least 3 patches, got {n}")
    r = np.asarray(rgb.transpose("patch", "channel").values, dtype=np.float64)
    energy = np.maximum(np.sum(r**2, axis=1), 1e-300)
    scores = []
    for value in candidates:
        error = 0.0
        for p in range(n):
            keep = np.arange(n) != p
            c = camera_matrix(
                rgb.isel(patch=keep), spectra.isel(patch=keep), smoothness=value, nonnegative=nonnegative
            )["camera_matrix"]
            s = np.asarray(spectra.isel(patch=p).transpose("wavelength").values, dtype=np.float64)
            predicted = np.asarray(c.transpose("channel", "wavelength").values) @ s
            error += float(np.sum((predicted - r[p]) ** 2) / energy[p])
        scores.append(error / n)
    scores_arr = np.asarray(scores)
    best = int(np.flatnonzero(scores_arr <= scores_arr.min() * (1 + 1e-9))[-1])
    curve = xr.DataArray(
        scores_arr,
        dims="smoothness",
        coords={"smoothness": np.asarray(candidates, dtype=float)},
        attrs={"units": "1", "long_name": "leave-one-patch-out relative squared RGB error"},
    )
    return float(candidates[best]), curve
