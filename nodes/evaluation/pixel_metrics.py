"""Per-pixel accuracy of a reconstruction against spectral ground truth (paper sec. 5).

Per pixel ``p`` of image ``i`` with reconstructed spectrum ``S`` and ground truth ``T``
over the ``K`` wavelengths:

normalised RMSE (Figures 5, 6 and 7)
    ``nRMSE(p) = sqrt(mean_k (S_k(p) - T_k(p))**2) / mean_{k, q} T_k(q)``: the RMSE over
    the wavelengths divided by the mean intensity of the ground-truth *image* (the mean over
    wavelength, y and x of image ``i``), as in the captions of Figures 5 and 6.
spectral angle
    the angle between ``S(p)`` and ``T(p)`` in degrees (scale-invariant), computed as
    ``2 atan2(|s - t|, |s + t|)`` of the unit vectors, which is accurate near 0.
CIEDE2000 colour difference
    both spectra -> CIE XYZ (CIE 1931 2 degree observer, weighted by an illuminant, default
    D65; see :mod:`spectralize.nodes.evaluation.colorimetry`) -> CIELAB relative to the
    illuminant's white -> ``colour.delta_E(method="CIE 2000")``.

:func:`pixel_maps` computes any of the three maps in one pass over the blocks of the cubes
(each block of both cubes is read once for all of them); lazy when the cubes are.

References
----------
Fast Capture of Spectral Image Series, sec. 5 and Figures 5, 6 (normalised RMSE maps) and 7.
"""

from __future__ import annotations

import warnings

import numpy as np
import xarray as xr

from .colorimetry import Illuminant, _quiet_colour, xyz_weights
from .cubes import as_float64, check_pair

# colour-science is imported where it is used: importing it is slow (it imports
# matplotlib), which declaring the ``evaluate`` node (``spectralize nodes``) must not pay.

__all__ = ["METRICS", "normalised_rmse", "spectral_angle", "colour_difference", "pixel_maps"]

#: The per-pixel metrics by name: (units, long name).
METRICS = {
    "nrmse": ("1", "normalised RMSE over wavelength (RMSE / mean ground-truth intensity of the image)"),
    "spectral_angle": ("degree", "spectral angle between reconstruction and ground truth"),
    "delta_e": ("1", "CIEDE2000 colour difference"),
}


def _chunk_spectral(array: xr.DataArray) -> xr.DataArray:
    return array.chunk({"wavelength": -1}) if array.chunks is not None else array


def normalised_rmse(
    spectra: xr.DataArray | xr.Dataset, truth: xr.DataArray | xr.Dataset
) -> xr.DataArray:
    """Per-pixel RMSE over wavelength divided by the mean ground-truth intensity of the image.

    Parameters
    ----------
    spectra, truth
        ``radiance`` (image, wavelength, y, x) of the reconstruction and the ground truth,
        or Datasets holding it.

    Returns
    -------
    xarray.DataArray
        ``nrmse`` (image, y, x) float32 [1]. NaN where a spectrum holds NaN, and for every
        pixel of an image whose ground-truth mean is not positive (nRMSE is undefined there).

    Raises
    ------
    SchemaError
        If the cubes do not have dims (image, wavelength, y, x), equal shapes and wavelengths.

    References
    ----------
    Fast Capture of Spectral Image Series, Figures 5 and 6: "The pixel-wise RMSE is
    normalized by the mean over all pixel intensities of the ground truth spectral image."
    """
    return pixel_maps(*check_pair(spectra, truth), ("nrmse",))["nrmse"]


def spectral_angle(spectra: xr.DataArray | xr.Dataset, truth: xr.DataArray | xr.Dataset) -> xr.DataArray:
    """Per-pixel angle between the reconstructed and the true spectrum, in degrees.

    ``2 atan2(|s - t|, |s + t|)`` with ``s = S / |S|`` and ``t = T / |T|``: equal to
    ``arccos(s . t)`` but accurate for small angles. NaN where either spectrum is all zero
    or holds NaN.

    Parameters
    ----------
    spectra, truth
        ``radiance`` (image, wavelength, y, x) of the reconstruction and the ground truth,
        or Datasets holding it.

    Returns
    -------
    xarray.DataArray
        ``spectral_angle`` (image, y, x) float32 [degree], in [0, 180].

    Raises
    ------
    SchemaError
        If the cubes do not have dims (image, wavelength, y, x), equal shapes and wavelengths.

    References
    ----------
    Kruse, F. A. et al. (1993). The spectral image processing system (SIPS). Remote Sensing
    of Environment 44. (Spectral angle mapper.)
    """
    return pixel_maps(*check_pair(spectra, truth), ("spectral_angle",))["spectral_angle"]


def _pixel_rmse(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """RMSE over the last (wavelength) axis; NaN where either spectrum holds NaN."""
    return np.sqrt(np.mean((s - t) ** 2, axis=-1))


def _pixel_angle(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spectral angle [degree] over the last axis: ``2 atan2(|s - t|, |s + t|)`` of the unit
    spectra; NaN where either is all zero or holds NaN."""
    norm_s = np.sqrt((s**2).sum(axis=-1))
    norm_t = np.sqrt((t**2).sum(axis=-1))
    valid = np.isfinite(norm_s) & (norm_s > 0) & (norm_t > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        unit_s = s / np.where(valid, norm_s, np.nan)[..., None]
        unit_t = t / np.where(valid, norm_t, np.nan)[..., None]
        difference = np.sqrt(((unit_s - unit_t) ** 2).sum(axis=-1))
        total = np.sqrt(((unit_s + unit_t) ** 2).sum(axis=-1))
        return np.where(valid, np.degrees(2.0 * np.arctan2(difference, total)), np.nan)


def _pixel_metrics_numpy(
    s: np.ndarray, t: np.ndarray, names: tuple[str, ...], weights: np.ndarray, white: np.ndarray
) -> np.ndarray:
    """(..., wavelength) spectra and truth -> (..., metric) float32: the metrics ``names`` of
    every pixel in one pass over the block (``nrmse`` as the RMSE, before the image mean)."""
    s = np.asarray(s, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    out = np.empty((*s.shape[:-1], len(names)), dtype=np.float32)
    for i, name in enumerate(names):
        if name == "nrmse":
            out[..., i] = _pixel_rmse(s, t)
        elif name == "spectral_angle":
            out[..., i] = _pixel_angle(s, t)
        else:  # delta_e
            out[..., i] = _ciede2000(s @ weights, t @ weights, white)
    return out


def pixel_maps(
    s: xr.DataArray, t: xr.DataArray, names: tuple[str, ...], *, illuminant: Illuminant = "D65"
) -> dict[str, xr.DataArray]:
    """The per-pixel maps ``names`` (of :data:`METRICS`) of aligned cubes, lazy if they are.

    Every block of the cubes is read once for all the maps: computed one map at a time, each
    block of both cubes (as float64) would stay in memory until the last map had used it,
    which holds whole cubes at once.
    """
    import colour

    s, t = _chunk_spectral(s), _chunk_spectral(t)
    weights = xyz_weights(t["wavelength"].values, illuminant=illuminant)
    white = colour.XYZ_to_xy(weights.values.sum(axis=0))
    stacked = xr.apply_ufunc(
        _pixel_metrics_numpy,
        s,
        t,
        kwargs={"names": names, "weights": weights.values, "white": white},
        input_core_dims=[["wavelength"], ["wavelength"]],
        output_core_dims=[["metric"]],
        dask="parallelized",
        output_dtypes=[np.float32],
        dask_gufunc_kwargs={"output_sizes": {"metric": len(names)}},
    )
    maps = {}
    for i, name in enumerate(names):
        values = stacked.isel(metric=i, drop=True).transpose(*(d for d in t.dims if d != "wavelength"))
        if name == "nrmse":
            mean = as_float64(t).mean(("wavelength", "y", "x"), skipna=False)
            values = (values / mean.where(mean > 0)).astype(np.float32)
        units, long_name = METRICS[name]
        values.name = name
        values.attrs = {"units": units, "long_name": long_name}
        if name == "delta_e":
            values.attrs.update(
                long_name=f"{long_name} under {weights.attrs['illuminant']}",
                illuminant=weights.attrs["illuminant"],
                observer=weights.attrs["observer"],
            )
        maps[name] = values
    return maps


def _ciede2000(xyz_spectra: np.ndarray, xyz_truth: np.ndarray, white: np.ndarray) -> np.ndarray:
    import colour

    with _quiet_colour(), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lab_s = colour.XYZ_to_Lab(xyz_spectra, white)
        lab_t = colour.XYZ_to_Lab(xyz_truth, white)
        return np.asarray(colour.delta_E(lab_s, lab_t, method="CIE 2000"), dtype=np.float32)


def colour_difference(
    spectra: xr.DataArray | xr.Dataset,
    truth: xr.DataArray | xr.Dataset,
    *,
    illuminant: Illuminant = "D65",
) -> xr.DataArray:
    """Per-pixel CIEDE2000 colour difference between reconstruction and ground truth.

    Both spectra are converted to CIE XYZ with the CIE 1931 2 degree observer, weighted by
    ``illuminant`` and normalised so that a spectrum equal to 1 has ``Y = 1``
    (:func:`~spectralize.nodes.evaluation.colorimetry.spectra_to_xyz`, colour-science's
    integration), then to CIELAB relative to the white of the illuminant on the cube's bands
    (a perfect reflector has L* = 100, a* = b* = 0), and compared with
    ``colour.delta_E(method="CIE 2000")``.

    Parameters
    ----------
    spectra, truth
        ``radiance`` (image, wavelength, y, x), or Datasets holding it.
    illuminant
        Name in ``colour.SDS_ILLUMINANTS``, a ``SpectralDistribution``, or ``None`` (equal
        energy: the cubes are integrated as they are, e.g. radiance that already contains
        the light, with white point E).

    Returns
    -------
    xarray.DataArray
        ``delta_e`` (image, y, x) float32 [1]; NaN where a spectrum holds NaN.

    Raises
    ------
    SchemaError
        If the cubes do not have dims (image, wavelength, y, x), equal shapes and wavelengths.
    ParameterError
        If ``illuminant`` is unknown.

    Notes
    -----
    The relative radiance of a run is treated like a reflectance factor under
    ``illuminant``: a value of 1 at every wavelength is the reference white (L* = 100).

    References
    ----------
    CIE 142-2001, Improvement to industrial colour-difference evaluation (CIEDE2000).
    """
    s, t = check_pair(spectra, truth)
    return pixel_maps(s, t, ("delta_e",), illuminant=illuminant)["delta_e"]
