"""Exposure planning for the spectral camera (paper eq. 2 and 3).

Per spectral band ``i``, with the camera system's quantum efficiency ``Q_i`` and the
illumination's spectral radiance ``L_i``:

- eq. 2, exposure time: ``t_i = (t0 / (Q_i L_i)) ** omega``;
- eq. 3, filter size: ``s_i = s0 / (Q_i L_i t_i)``, Gaussian ``sigma_i = s_i / 5``.

Bands with bad support from light source and sensor get longer exposures *and* larger
filters; ``omega`` trades noise against capture time (``omega = 1`` gives every band the
same signal, ``omega -> 0`` the same time).  The plan also states what it costs: the total
exposure time of the spectral shots and of the RGB exposure series.

References
----------
Fast Capture of Spectral Image Series, sec. 3 "Filtering" (eq. 2, 3), sec. 4 Figure 3,
sec. 5 "Real Data" (226 s reference vs 7.5 s noisy capture).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import numpy.typing as npt
import xarray as xr

from spectralize.nodes.filter_size import SIGMA_PER_FILTER_SIZE
from spectralize.nodes.simulation.camera_model import (
    ShapeMismatchError,
    SimulationParameterError,
    check_positive,
    check_wavelength,
)

__all__ = [
    "exposure_plan",
    "reference_exposure_plan",
    "t0_for_total_time",
]

#: The paper's exponent ``omega`` of eq. 2.
DEFAULT_OMEGA: float = 0.8


def _spectra(
    quantum_efficiency: xr.DataArray | npt.ArrayLike,
    illuminant: xr.DataArray | npt.ArrayLike,
    wavelength: npt.ArrayLike | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return (wavelength, Q, L) as checked float arrays on one wavelength axis."""
    wls = []
    vals = []
    for name, v in (("quantum_efficiency", quantum_efficiency), ("illuminant", illuminant)):
        if isinstance(v, xr.DataArray):
            if v.dims != ("wavelength",):
                raise ShapeMismatchError(
                    f"{name} must be 1-D over 'wavelength'; received dims {v.dims} and shape {v.shape}."
                )
            wls.append(check_wavelength(v["wavelength"].values, f"{name}.wavelength"))
            vals.append(np.asarray(v.values, dtype=np.float64))
        else:
            a = np.asarray(v, dtype=np.float64)
            if a.ndim != 1:
                raise ShapeMismatchError(f"{name} must be 1-D; received shape {a.shape}.")
            vals.append(a)
    if wavelength is not None:
        wls.append(check_wavelength(wavelength))
    if not wls:
        raise SimulationParameterError(
            "wavelength is required when quantum_efficiency and illuminant are plain "
            "arrays; pass DataArrays over 'wavelength' or `wavelength=`."
        )
    wl = wls[0]
    for other in wls[1:]:
        if other.shape != wl.shape or not np.allclose(other, wl):
            raise ShapeMismatchError(
                "quantum_efficiency, illuminant (and wavelength) must share one wavelength "
                f"axis; received {wl.size} values from {wl[0]:g} nm and {other.size} values "
                f"from {other[0]:g} nm. Interpolate one onto the other first."
            )
    for name, a in zip(("quantum_efficiency", "illuminant"), vals, strict=True):
        if a.shape != wl.shape:
            raise ShapeMismatchError(f"{name} has {a.size} values but there are {wl.size} wavelengths.")
    q = check_positive(vals[0], "quantum_efficiency")
    ell = check_positive(vals[1], "illuminant")
    return wl, q, ell


def exposure_plan(
    quantum_efficiency: xr.DataArray | npt.ArrayLike,
    illuminant: xr.DataArray | npt.ArrayLike,
    *,
    t0: float,
    s0: float,
    omega: float = DEFAULT_OMEGA,
    wavelength: npt.ArrayLike | None = None,
    rgb_exposure_times: Sequence[float] = (),
    rgb_images: int = 0,
    spectral_sets: int = 1,
) -> xr.Dataset:
    """Exposure times and filter sizes per band (paper eq. 2 and 3) and what they cost.

    Parameters
    ----------
    quantum_efficiency
        ``Q_i`` (wavelength), > 0: combined quantum efficiency of optics, filter and sensor
        of the spectral camera [s-1 per unit radiance].
    illuminant
        ``L_i`` (wavelength), > 0: spectral radiance of the illumination [relative, "1"].
    t0
        Hardware constant of eq. 2, > 0 [in units of ``Q L`` times ``s ** (1 / omega)``].
    s0
        Hardware constant of eq. 3, >= 0 [px, times ``Q L t``]; 0 means "no filtering".
    omega
        Exponent of eq. 2 in (0, 1]; the paper uses 0.8.
    wavelength
        Band centres [nm] when the spectra are plain arrays.
    rgb_exposure_times
        Exposure times [s] of one RGB HDR exposure series (e.g. 4), for the cost summary.
    rgb_images
        Number of RGB images (exposure series) captured, for the cost summary.
    spectral_sets
        How many times the full set of bands is captured (sparse mode: once per set of
        LED positions), for the cost summary.

    Returns
    -------
    xarray.Dataset
        Over ``wavelength`` [nm]: ``exposure_time`` [s] (eq. 2), ``filter_size`` [px]
        (eq. 3), ``filter_sigma`` [px] (``s_i / 5``), ``relative_exposure`` (``Q L t``,
        the normalised exposure a white target receives), ``quantum_efficiency`` and
        ``illuminant``; scalars ``spectral_capture_time``, ``rgb_capture_time`` and
        ``total_capture_time`` [s]; ``rgb_exposure_time`` over ``rgb_exposure``.
        Attrs hold ``t0``, ``s0``, ``omega`` and a one-line ``cost`` summary.

    Notes
    -----
    With ``omega = 0.8``: ``Q L t = t0**0.8 (Q L)**0.2``, so a band ten times weaker gets
    ``10**0.8 = 6.3`` times the exposure but still 37 % less signal, and a filter
    ``10**0.2 = 1.6`` times larger.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 3, eq. 2 and 3.

    Examples
    --------
    >>> plan = exposure_plan([0.5, 1.0], [1.0, 1.0], wavelength=[500, 510], t0=0.1, s0=2)
    >>> plan.exposure_time.values.round(4)
    array([0.2759, 0.1585])
    """
    wl, q, ell = _spectra(quantum_efficiency, illuminant, wavelength)
    check_positive(t0, "t0")
    check_positive(s0, "s0", allow_zero=True)
    omega = float(check_positive(omega, "omega"))
    if omega > 1.0:
        raise SimulationParameterError(
            f"omega must be in (0, 1] (1: equal signal in all bands); received {omega:g}."
        )
    rgb_times = np.asarray(rgb_exposure_times, dtype=np.float64).reshape(-1)
    if rgb_times.size:
        check_positive(rgb_times, "rgb_exposure_times")
    for name, n in (("rgb_images", rgb_images), ("spectral_sets", spectral_sets)):
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 0:
            raise SimulationParameterError(f"{name} must be an int >= 0; received {n!r}.")

    ql = q * ell
    t = (t0 / ql) ** omega  # eq. 2
    s = s0 / (ql * t)  # eq. 3
    spectral_total = float(spectral_sets * t.sum())
    rgb_total = float(rgb_images * rgb_times.sum())

    wl_coord = xr.Variable(("wavelength",), wl, {"units": "nm", "long_name": "wavelength"})
    ds = xr.Dataset(
        {
            "exposure_time": (
                "wavelength",
                t,
                {"units": "s", "long_name": "exposure time of the band shot (eq. 2)"},
            ),
            "filter_size": (
                "wavelength",
                s,
                {"units": "px", "long_name": "Gaussian filter size s_i (eq. 3)"},
            ),
            "filter_sigma": (
                "wavelength",
                s * SIGMA_PER_FILTER_SIZE,
                {"units": "px", "long_name": "Gaussian filter standard deviation s_i / 5"},
            ),
            "relative_exposure": (
                "wavelength",
                ql * t,
                {"units": "1", "long_name": "normalised exposure Q L t of a white target"},
            ),
            "quantum_efficiency": (
                "wavelength",
                q,
                {"units": "s-1", "long_name": "quantum efficiency Q of the spectral camera"},
            ),
            "illuminant": (
                "wavelength",
                ell,
                {"units": "1", "long_name": "spectral radiance L of the illumination"},
            ),
            "rgb_exposure_time": (
                "rgb_exposure",
                rgb_times,
                {"units": "s", "long_name": "exposure times of one RGB exposure series"},
            ),
            "spectral_capture_time": (
                (),
                spectral_total,
                {"units": "s", "long_name": "total exposure time of the spectral shots"},
            ),
            "rgb_capture_time": (
                (),
                rgb_total,
                {"units": "s", "long_name": "total exposure time of the RGB images"},
            ),
            "total_capture_time": (
                (),
                spectral_total + rgb_total,
                {"units": "s", "long_name": "total exposure time of the capture"},
            ),
        },
        coords={"wavelength": wl_coord},
        attrs={
            "t0": float(t0),
            "s0": float(s0),
            "omega": omega,
            "spectral_sets": int(spectral_sets),
            "rgb_images": int(rgb_images),
            "kind": "noisy",
            "cost": (
                f"spectral {spectral_total:.3f} s ({len(wl)} bands x {spectral_sets} set(s), "
                f"{t.min():.4f}..{t.max():.4f} s per band) + RGB {rgb_total:.3f} s "
                f"({rgb_images} image(s) x {rgb_times.size} exposure(s)) = "
                f"{spectral_total + rgb_total:.3f} s"
            ),
            "references": "Fast Capture of Spectral Image Series, eq. 2 and 3",
        },
    )
    return ds


def reference_exposure_plan(
    quantum_efficiency: xr.DataArray | npt.ArrayLike,
    illuminant: xr.DataArray | npt.ArrayLike,
    *,
    target_exposure: float = 0.8,
    wavelength: npt.ArrayLike | None = None,
    rgb_exposure_times: Sequence[float] = (),
    rgb_images: int = 0,
    spectral_sets: int = 1,
) -> xr.Dataset:
    """Long-exposure reference plan: every band exposed to ``target_exposure`` of full scale.

    Eq. 2 with ``omega = 1`` and ``t0 = target_exposure``: ``t_i = target / (Q_i L_i)``, so a
    white target reaches the same high signal in every band and no filtering is needed
    (``filter_size = 0``). This is the paper's "long exposure" reference capture (226 s
    against 7.5 s for the noisy capture, sec. 5 "Real Data").
    """
    if not 0.0 < float(target_exposure) <= 1.0:
        raise SimulationParameterError(
            f"target_exposure must be in (0, 1] of full scale; received {target_exposure!r}."
        )
    ds = exposure_plan(
        quantum_efficiency,
        illuminant,
        t0=float(target_exposure),
        s0=0.0,
        omega=1.0,
        wavelength=wavelength,
        rgb_exposure_times=rgb_exposure_times,
        rgb_images=rgb_images,
        spectral_sets=spectral_sets,
    )
    ds.attrs["kind"] = "reference"
    ds.attrs["target_exposure"] = float(target_exposure)
    return ds


def t0_for_total_time(
    quantum_efficiency: xr.DataArray | npt.ArrayLike,
    illuminant: xr.DataArray | npt.ArrayLike,
    *,
    total_time: float,
    omega: float = DEFAULT_OMEGA,
    wavelength: npt.ArrayLike | None = None,
) -> float:
    """The ``t0`` of eq. 2 for which one set of bands takes ``total_time`` seconds.

    ``sum_i (t0 / (Q_i L_i)) ** omega = T``, so
    ``t0 = (T / sum_i (Q_i L_i) ** -omega) ** (1 / omega)``.
    """
    _, q, ell = _spectra(quantum_efficiency, illuminant, wavelength)
    check_positive(total_time, "total_time")
    omega = float(check_positive(omega, "omega"))
    return float((total_time / np.sum((q * ell) ** -omega)) ** (1.0 / omega))
