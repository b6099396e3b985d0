"""The RGB camera matrix ``C`` as a non-negative sum of smooth lobes (paper eq. 1, section 4).

A colour checker's 18-24 smooth spectra, under an LED with a narrow peak, span far fewer
dimensions than the 32 bands: many ``C`` reproduce every patch, and the fit alone cannot tell
them apart. Where the chart is silent, the prior decides. A second-difference penalty
extrapolates linearly where the light is weak, so a red row keeps rising to 700 nm and a green
row rises again there; real sensors do not do that. Their sensitivities are a few smooth
lobes (one main lobe per channel, a small secondary one in the red) that fall to zero at
both ends of the visible. :func:`lobe_camera_matrix` therefore writes every row of ``C`` as a
non-negative combination of Gaussian lobes of several widths centred on a fine grid,

``C_c = G a_c``, ``a_c >= 0``,
``min ||W (S G a_c - R_c)||^2 + mu ||a_c||^2 + nu sum_lambda u_lambda (G a_c)_lambda^2``,

where ``S`` (patch, wavelength) holds the patches' known spectral radiance, ``R`` (patch,
channel) their measured RGB, ``W`` weights each patch by ``1 / |R_p|`` (relative errors, so
that a white reference does not outweigh the dark patches) and the ridge ``mu`` pulls every
lobe the data do not ask for to zero. Non-negativity and smoothness hold by construction;
non-negative least squares keeps few lobes. ``mu`` is chosen per channel by leaving each patch
out in turn (:func:`cross_validated_ridge`, with the one-standard-error rule).

The last term holds ``C`` to zero where the calibration had no light
(:func:`weak_light_weights`): ``u_lambda = (e / (L_lambda + e))^4`` with ``L_lambda`` the
patches' (weighted) light at ``lambda`` relative to the best-lit band, 1 where they had none
and vanishing where they had some; ``nu`` is relative to the data (``||W S G||_F^2 /
||G||_F^2``), so a bright chart or a dim one is held alike. Under a
phosphor LED the chart's 410 nm band gets under 1 % of the peak; nothing there tells a
sensitivity of 0.6 from one of 0.02, and the ridge on lobe amplitudes prefers the broadest
lobes (the most RGB per unit of amplitude), whose tails then reach into that band. Such a
``C`` reproduces every patch, but the reconstruction projects every pixel onto ``C S = R``
along the rows of ``C``: its RGB residuals land, as large relative errors, in the bands where
the light is weak (on a foreign gantry the weakest bands came out far too bright through a
``C`` whose only fault was its value there). No patch left out can see this
term, so its weight ``nu`` (relative, :data:`WEAK_LIGHT_WEIGHT`) and floor ``e``
(:data:`WEAK_LIGHT_FLOOR`) are fixed and stored with the fit.

The benchmark ``benchmarks/calibration.py --camera-matrix`` measures the shape error of ``C``
per channel against measured camera sensitivities.

References
----------
.. [1] Fast Capture of Spectral Image Series, eq. 1 (the camera matrix ``C``) and section 4
   ("Calibration").
.. [2] C. L. Lawson, R. J. Hanson, Solving Least Squares Problems, Prentice-Hall 1974
   (non-negative least squares).
.. [3] M. Stone, Cross-validatory choice and assessment of statistical predictions,
   J. R. Stat. Soc. B 36(2), 1974.
.. [4] T. Hastie, R. Tibshirani, J. Friedman, The Elements of Statistical Learning, 2nd ed.,
   Springer 2009, section 7.10 (the one-standard-error rule).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = [
    "LOBE_WIDTHS",
    "RIDGE_CANDIDATES",
    "WEAK_LIGHT_WEIGHT",
    "WEAK_LIGHT_FLOOR",
    "lobe_basis",
    "weak_light_weights",
    "lobe_camera_matrix",
    "cross_validated_ridge",
    "check_chart_pair",
    "chart_arrays",
    "fit_residual",
    "camera_matrix_dataset",
]

LOBE_WIDTHS: tuple[float, ...] = (15.0, 25.0, 40.0, 60.0)
"""Standard deviations [nm] of the lobes: the narrowest edge of a real sensor's sensitivity to
its broadest lobe."""

LOBE_STEP = 10.0
"""Spacing [nm] of the lobe centres."""

LOBE_MARGIN = 30.0
"""How far [nm] beyond the first and last band lobe centres reach (a lobe centred outside the
bands gives a tail inside them)."""

RIDGE_CANDIDATES: tuple[float, ...] = tuple(float(v) for v in np.logspace(-6, 0, 13))
"""Relative ridge weights :func:`cross_validated_ridge` chooses from (1e-6 .. 1, half decades)."""

WEAK_LIGHT_WEIGHT = 0.15
"""Relative weight ``nu`` of the penalty on ``C`` where the calibration had little light
(0: none). Chosen on the two tuned foreign gantries (``tests/support``: band bias of the
spectra, C per channel), the project's simulator and ``benchmarks/calibration.py
--camera-matrix``'s tuned cameras under three lights, never on a held-out one."""

WEAK_LIGHT_FLOOR = 0.01
"""Floor ``e`` of :func:`weak_light_weights`: the relative light below which the penalty on
``C`` is at its strongest (1 % of the best-lit band)."""


def lobe_basis(
    wavelength: np.ndarray,
    *,
    widths: tuple[float, ...] = LOBE_WIDTHS,
    step: float = LOBE_STEP,
    margin: float = LOBE_MARGIN,
) -> np.ndarray:
    """Gaussian lobes ``exp(-(lambda - c)^2 / (2 w^2))`` on the bands, (wavelength, lobe).

    Centres every ``step`` nm from ``margin`` nm below the first band to ``margin`` nm above
    the last, one lobe per centre and width.
    """
    wl = np.asarray(wavelength, dtype=np.float64)
    centres = np.arange(wl.min() - margin, wl.max() + margin + 1e-9, step)
    lobes = [np.exp(-0.5 * ((wl[:, None] - centres[None]) / w) ** 2) for w in widths]
    return np.concatenate(lobes, axis=1)


def weak_light_weights(spectra: np.ndarray, floor: float = WEAK_LIGHT_FLOOR) -> np.ndarray:
    """(wavelength,) ``u = (e / (L + e))^4``: how strongly ``C`` is held to zero per band.

    ``L_lambda = sqrt(sum_p S_p,lambda^2)`` over the (weighted) patch spectra, relative to
    its best-lit band: the light the calibration saw at ``lambda``. ``u`` is 1 in a band
    without light, 1/16 in one lit at ``e`` and below ``(e / L)^4`` above: the fourth power
    keeps the penalty on the bands the patches barely see (a few ``e``) and off the moderately
    lit ones, such as the dip between an LED's blue peak and its phosphor, where the patches
    do tell ``C`` (a square pulled ``C`` down in that dip too, and the fit wiggled).

    Parameters
    ----------
    spectra
        (patch, wavelength) patch spectra as fitted (weighted rows).
    floor
        ``e`` > 0.

    References
    ----------
    .. [1] A. N. Tikhonov, V. Y. Arsenin, Solutions of Ill-Posed Problems, Winston 1977
       (weighted regularisation of an underdetermined fit).
    """
    if not floor > 0:
        raise CalibrationError(f"weak_light_weights: floor must be > 0, got {floor}")
    light = np.sqrt(np.sum(np.asarray(spectra, dtype=np.float64) ** 2, axis=0))
    light = light / max(float(light.max()), 1e-300)
    return (floor / (light + floor)) ** 4


def _weighted(rgb: np.ndarray, spectra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows scaled by ``1 / |R_p|`` (relative errors per patch)."""
    norm = np.linalg.norm(rgb, axis=1)
    if np.any(~(norm > 0)):
        bad = np.flatnonzero(~(norm > 0)).tolist()
        raise CalibrationError(f"lobe_camera_matrix: patch(es) {bad} have no RGB signal")
    w = 1.0 / norm
    return rgb * w[:, None], spectra * w[:, None]


def _weak_rows(
    design: np.ndarray, spectra: np.ndarray, basis: np.ndarray, weight: float, floor: float
) -> np.ndarray:
    """Rows ``sqrt(nu u) G`` of the weak-light penalty, ``nu = weight ||design||_F^2 / ||G||_F^2``
    and ``u`` from :func:`weak_light_weights` (none when ``weight`` is 0)."""
    if weight == 0:
        return np.zeros((0, basis.shape[1]))
    nu = weight * float(np.sum(design**2)) / max(float(np.sum(basis**2)), 1e-300)
    return np.sqrt(nu * weak_light_weights(spectra, floor))[:, None] * basis


def _ridge_nnls(
    design: np.ndarray, target: np.ndarray, ridge: float, extra: np.ndarray | None = None
) -> np.ndarray:
    """``argmin_{a >= 0} ||design a - target||^2 + mu ||a||^2 + ||extra a||^2``,
    ``mu = ridge * ||design||_F^2 / n``."""
    n = design.shape[1]
    mu = ridge * float(np.sum(design**2)) / n
    extra = np.zeros((0, n)) if extra is None else extra
    a = np.vstack([design, np.sqrt(mu) * np.eye(n), extra])
    b = np.concatenate([target, np.zeros(n + extra.shape[0])])
    from scipy import optimize  # not at import: `spectralize nodes` lists nodes without it

    return optimize.nnls(a, b, maxiter=50 * n)[0]


def cross_validated_ridge(
    rgb: np.ndarray,
    spectra: np.ndarray,
    basis: np.ndarray,
    *,
    candidates: tuple[float, ...] = RIDGE_CANDIDATES,
    one_se: float = 1.0,
    weak_light: float = WEAK_LIGHT_WEIGHT,
    weak_light_floor: float = WEAK_LIGHT_FLOOR,
) -> tuple[np.ndarray, np.ndarray]:
    """Per channel, the ridge weight whose fit best predicts a patch left out.

    For every candidate and patch ``p``, the lobes are fitted to all other patches and
    predict ``R_p``; the score is the mean of ``(C_c s_p - R_pc)^2 / |R_p|^2`` over patches.
    The chosen weight is the largest whose score is within ``one_se`` standard errors of the
    smallest (the one-standard-error rule): 19-25 patches give a noisy score, and its bare
    minimum often picks a ridge so weak that lobes where the light is weak grow to fit the
    noise (a row that rises again at 410 or 720 nm).

    Parameters
    ----------
    rgb
        (patch, channel) measured RGB.
    spectra
        (patch, wavelength) known spectral radiance.
    basis
        (wavelength, lobe), :func:`lobe_basis`.
    candidates
        Relative ridge weights to try, ascending.
    one_se
        How many standard errors of the smallest score a larger weight may lose (0: the
        minimum itself).
    weak_light, weak_light_floor
        The penalty on ``C`` where the light is weak (module docstring), in every fit.

    Returns
    -------
    tuple of numpy.ndarray
        The chosen weight per channel and the scores (candidate, channel).

    References
    ----------
    .. [1] M. Stone, Cross-validatory choice and assessment of statistical predictions,
       J. R. Stat. Soc. B 36(2), 1974.
    .. [2] Fast Capture of Spectral Image Series, section 4.
    """
    if not candidates:
        raise CalibrationError("cross_validated_ridge: no candidate ridge weight given")
    n = rgb.shape[0]
    if n < 3:
        raise CalibrationError(f"cross_validated_ridge: need at least 3 patches, got {n}")
    r, s = _weighted(rgb, spectra)
    design = s @ basis
    errors = np.zeros((len(candidates), n, r.shape[1]))
    folds = [np.arange(n) != p for p in range(n)]
    extras = [_weak_rows(design[k], s[k], basis, weak_light, weak_light_floor) for k in folds]
    for i, ridge in enumerate(candidates):
        for p, keep in enumerate(folds):
            for c in range(r.shape[1]):
                a = _ridge_nnls(design[keep], r[keep, c], ridge, extras[p])
                errors[i, p, c] = (design[p] @ a - r[p, c]) ** 2
    scores = errors.mean(axis=1)
    spread = errors.std(axis=1, ddof=1) / np.sqrt(n)
    chosen = np.empty(r.shape[1])
    for c in range(r.shape[1]):
        best = int(np.argmin(scores[:, c]))
        within = np.flatnonzero(scores[:, c] <= scores[best, c] + one_se * spread[best, c])
        chosen[c] = candidates[int(within[-1])]
    return chosen, scores


def lobe_camera_matrix(
    rgb: xr.DataArray,
    spectra: xr.DataArray,
    *,
    ridge: float | Sequence[float] | None = None,
    widths: tuple[float, ...] = LOBE_WIDTHS,
    weak_light: float = WEAK_LIGHT_WEIGHT,
    weak_light_floor: float = WEAK_LIGHT_FLOOR,
) -> xr.Dataset:
    """``C`` (channel, wavelength) as a non-negative sum of smooth lobes fitted to the patches.

    Parameters
    ----------
    rgb
        Measured RGB radiance of the patches (patch, channel), e.g. patch means of an HDR
        image; a white reference may be one of the patches.
    spectra
        Known spectral radiance of the same patches (patch, wavelength): reflectance times
        illuminant, in the units the spectral camera reports.
    ridge
        Relative weight of the ridge on the lobe amplitudes: one for every channel or one
        per channel; ``None``: chosen per channel by leaving each patch out in turn.
    widths
        Standard deviations [nm] of the lobes.
    weak_light
        Relative weight ``nu`` of the penalty on ``C`` where the patches had little light
        (module docstring); 0: none.
    weak_light_floor
        Its floor ``e`` (:func:`weak_light_weights`).

    Returns
    -------
    xarray.Dataset
        ``camera_matrix`` (channel, wavelength) float64 >= 0, units ``"1"``; ``residual``
        (patch, channel) ``C S - R``; ``ridge`` (channel), the weight used; ``ridge_cv``
        (ridge_candidate, channel), the leave-one-patch-out scores when chosen. Attrs
        ``method``, ``widths``, ``lobes``, ``relative_rms_residual``, ``weak_light``,
        ``weak_light_floor``.

    Raises
    ------
    SchemaError
        Wrong dims.
    CalibrationError
        Patches that do not match, fewer than 3 bands or patches, NaN or inf, a patch
        without RGB signal, a negative ridge or weak-light weight, a floor not positive.

    Notes
    -----
    ``C_c = G a_c`` with ``a_c >= 0`` and Gaussian lobes ``G`` (:func:`lobe_basis`); the
    objective is the module's equation. The scale of ``C`` is that of ``R`` per unit of
    ``S``, as in eq. 1.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1 and section 4.
    """
    where = "lobe_camera_matrix"
    check_chart_pair(rgb, spectra, where)
    if ridge is not None and np.any(~(np.asarray(ridge, dtype=float) >= 0)):
        raise CalibrationError(f"{where}: ridge must be >= 0, got {ridge}")
    if not weak_light >= 0:
        raise CalibrationError(f"{where}: weak_light must be >= 0, got {weak_light}")
    if not weak_light_floor > 0:
        raise CalibrationError(f"{where}: weak_light_floor must be > 0, got {weak_light_floor}")
    s, r = chart_arrays(rgb, spectra, where)
    wavelength = (
        np.asarray(spectra["wavelength"].values, dtype=np.float64)
        if "wavelength" in spectra.coords
        else np.arange(s.shape[1], dtype=np.float64)
    )
    basis = lobe_basis(wavelength, widths=widths)
    scores = None
    if ridge is None:
        ridges, scores = cross_validated_ridge(
            r, s, basis, weak_light=weak_light, weak_light_floor=weak_light_floor
        )
    else:
        ridges = np.broadcast_to(np.asarray(ridge, dtype=float), (r.shape[1],)).copy()
    rw, sw = _weighted(r, s)
    design = sw @ basis
    extra = _weak_rows(design, sw, basis, weak_light, weak_light_floor)
    c = np.stack([basis @ _ridge_nnls(design, rw[:, k], ridges[k], extra) for k in range(r.shape[1])])
    residual, rel = fit_residual(c, s, r)
    out = camera_matrix_dataset(
        c,
        residual,
        rgb,
        wavelength,
        variables={
            "ridge": (
                "channel",
                ridges,
                {"units": "1", "long_name": "relative ridge weight on the lobe amplitudes"},
            ),
        },
        attrs={
            "method": "non-negative sum of Gaussian lobes, ridge on amplitudes"
            + (", held to zero where the light is weak" if weak_light else ""),
            "widths": [float(w) for w in widths],
            "lobes": int(basis.shape[1]),
            "relative_rms_residual": rel,
            "weak_light": float(weak_light),
            "weak_light_floor": float(weak_light_floor),
        },
    )
    if scores is not None:
        out["ridge_cv"] = xr.DataArray(
            scores,
            dims=("ridge_candidate", "channel"),
            coords={"ridge_candidate": np.asarray(RIDGE_CANDIDATES)},
            attrs={"units": "1", "long_name": "leave-one-patch-out relative squared RGB error"},
        )
    return out


def check_chart_pair(rgb: xr.DataArray, spectra: xr.DataArray, where: str) -> None:
    """Refuse chart data a camera matrix cannot be fitted to: ``rgb`` must be
    ``(patch, channel)`` and ``spectra`` ``(patch, wavelength)`` of the same patches (in the same
    order, where both name them), on at least 3 wavelengths.

    Raises
    ------
    SchemaError
        For wrong dims, naming the array.
    CalibrationError
        For different patches, or fewer than 3 wavelengths, naming ``where``.
    """
    if set(rgb.dims) != {"patch", "channel"}:
        raise SchemaError(
            f"{where}: rgb must be (patch, channel)",
            [Problem("rgb", "dims (patch, channel)", f"dims {rgb.dims}")],
        )
    if set(spectra.dims) != {"patch", "wavelength"}:
        raise SchemaError(
            f"{where}: spectra must be (patch, wavelength)",
            [Problem("spectra", "dims (patch, wavelength)", f"dims {spectra.dims}")],
        )
    if rgb.sizes["patch"] != spectra.sizes["patch"]:
        raise CalibrationError(
            f"{where}: rgb has {rgb.sizes['patch']} patches, spectra {spectra.sizes['patch']}"
        )
    if "patch" in rgb.coords and "patch" in spectra.coords:
        if not np.array_equal(rgb["patch"].values, spectra["patch"].values):
            raise CalibrationError(f"{where}: rgb and spectra list different patches")
    if spectra.sizes["wavelength"] < 3:
        raise CalibrationError(f"{where}: need at least 3 bands, got {spectra.sizes['wavelength']}")


def chart_arrays(rgb: xr.DataArray, spectra: xr.DataArray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """``S`` (patch, wavelength) and ``R`` (patch, channel) of eq. 1 from a chart pair that
    :func:`check_chart_pair` passed, as float64.

    Raises
    ------
    CalibrationError
        For NaN or inf in either, naming ``where``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1 and section 4.
    """
    s = np.asarray(spectra.transpose("patch", "wavelength").values, dtype=np.float64)
    r = np.asarray(rgb.transpose("patch", "channel").values, dtype=np.float64)
    if not (np.all(np.isfinite(s)) and np.all(np.isfinite(r))):
        raise CalibrationError(f"{where}: rgb and spectra must be finite")
    return s, r


def fit_residual(c: np.ndarray, s: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, float]:
    """The residual ``C S - R`` (patch, channel) of a fitted ``C`` on the chart, and its RMS
    relative to that of ``R``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1.
    """
    residual = s @ c.T - r
    return residual, float(np.sqrt(np.mean(residual**2)) / max(np.sqrt(np.mean(r**2)), 1e-300))


def camera_matrix_dataset(
    c: np.ndarray,
    residual: np.ndarray,
    rgb: xr.DataArray,
    wavelength: np.ndarray,
    *,
    variables: dict[str, tuple[object, ...]],
    attrs: dict[str, object],
) -> xr.Dataset:
    """A fitted ``C`` as the camera-matrix fits return it: ``camera_matrix`` (channel,
    wavelength) and ``residual`` (patch, channel) ``C S - R``, then the fit's own
    ``variables``, on ``rgb``'s channels and patches (where it names them) and ``wavelength``,
    with the fit's ``attrs``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1 and section 4.
    """
    channel = rgb["channel"].values if "channel" in rgb.coords else np.arange(c.shape[0])
    coords = {"channel": channel, "wavelength": wavelength}
    patch = {"patch": rgb["patch"].values} if "patch" in rgb.coords else {}
    return xr.Dataset(
        {
            "camera_matrix": (
                ("channel", "wavelength"),
                c,
                {"units": "1", "long_name": "RGB camera matrix C (spectral sensitivity)"},
            ),
            "residual": (
                ("patch", "channel"),
                residual,
                {"units": "1", "long_name": "C S - R on the calibration patches"},
            ),
            **variables,
        },
        coords={**coords, **patch},
        attrs=attrs,
    )
