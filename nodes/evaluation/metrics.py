"""Accuracy of a reconstruction against spectral ground truth (paper sec. 5, Figures 5-7).

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
    D65; see :mod:`spectralize.nodes.evaluation.colorimetry`) -> CIELAB relative to the illuminant's
    white -> ``colour.delta_E(method="CIE 2000")``.

:func:`evaluate` gives the three maps (image, y, x), per-image statistics (mean, median,
95th and 99th percentile; the fraction of pixels with nRMSE below 0.03, the level Figure 7
discusses), per-image nRMSE histograms (Figure 7 is their sum over the images with and
without band shots), statistics per subset of images (all / with band shots / without) and
representative spectra picked at low and high error (Figures 5 and 6, insets). Everything is
lazy over images when the inputs are dask-backed, as read from a run store.

References
----------
Fast Capture of Spectral Image Series, sec. 5 ("Full Correspondences", "Sparsely Measured
Spectral Bands"), Figures 5, 6 (normalised RMSE maps, representative spectra) and 7 (RMSE
histograms, images with and without band shots, logarithmic count axis).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Annotated

import numpy as np
import xarray as xr
from pydantic import AfterValidator, Field
from pydantic_core import PydanticCustomError

from spectralize.engine import Choices
from spectralize.nodes.evaluation.colorimetry import Illuminant, _quiet_colour, xyz_weights
from spectralize.schemas import ParameterError, Problem, SchemaError
from spectralize.schemas.run import SPECTRA

if TYPE_CHECKING:
    import colour

# colour-science is imported where it is used: importing it costs 1-2 s (it imports
# matplotlib), which declaring the ``evaluate`` node (``spectralize nodes``) must not pay.

__all__ = [
    "CUBE_DIMS",
    "STATISTICS",
    "DEFAULT_THRESHOLD",
    "DEFAULT_SAMPLE_QUANTILES",
    "ILLUMINANTS",
    "normalised_rmse",
    "spectral_angle",
    "colour_difference",
    "map_statistics",
    "band_shot_images",
    "representative_spectra",
    "evaluate",
    "compare_methods",
    "METHOD_DIM",
]

#: Dims of a spectral cube (groups ``spectra`` and ``truth/spectra``), from their schema.
CUBE_DIMS: tuple[str, ...] = next(s.dims for s in SPECTRA.variables if s.name == "radiance")
#: The statistics of every map, in the order of the ``statistic`` dim.
STATISTICS: tuple[str, ...] = ("mean", "median", "p95", "p99")
#: nRMSE level below which a pixel counts as well reconstructed (Figure 7: "~0.03").
DEFAULT_THRESHOLD: float = 0.03
#: Quantiles of the nRMSE map at which representative pixels are picked (low .. highest).
DEFAULT_SAMPLE_QUANTILES: tuple[float, ...] = (0.05, 0.5, 0.9, 0.99, 1.0)
#: The keys of ``colour.SDS_ILLUMINANTS`` (colour-science 0.4.7) plus ``"E"``, written out so
#: that the ``evaluate`` node's choices are known without importing colour-science; a test
#: (tests/flows/test_cli_fast.py) checks them against the installed colour-science.
ILLUMINANT_NAMES: tuple[str, ...] = (
    "A", "B", "C", "D50", "D55", "D60", "D65", "D75", "E",
    "FL1", "FL2", "FL3", "FL4", "FL5", "FL6", "FL7", "FL8", "FL9", "FL10", "FL11", "FL12",
    "FL3.1", "FL3.2", "FL3.3", "FL3.4", "FL3.5", "FL3.6", "FL3.7", "FL3.8", "FL3.9", "FL3.10",
    "FL3.11", "FL3.12", "FL3.13", "FL3.14", "FL3.15",
    "HP1", "HP2", "HP3", "HP4", "HP5",
    "LED-B1", "LED-B2", "LED-B3", "LED-B4", "LED-B5", "LED-BH1", "LED-RGB1", "LED-V1", "LED-V2",
    "ID65", "ID50",
    "ISO 7589 Photographic Daylight", "ISO 7589 Sensitometric Daylight", "ISO 7589 Studio Tungsten",
    "ISO 7589 Sensitometric Studio Tungsten", "ISO 7589 Photoflood",
    "ISO 7589 Sensitometric Photoflood", "ISO 7589 Sensitometric Printer",
)  # fmt: skip


class _IlluminantTable(Mapping[str, "colour.SpectralDistribution | None"]):
    """:data:`ILLUMINANTS`: the names without colour-science, the distributions on first use."""

    def __init__(self, names: Sequence[str]) -> None:
        self._names = tuple(names)
        self._table: dict[str, colour.SpectralDistribution | None] | None = None

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def __iter__(self) -> Iterator[str]:
        return iter(self._names)

    def __len__(self) -> int:
        return len(self._names)

    def __getitem__(self, name: str) -> colour.SpectralDistribution | None:
        if name not in self._names:
            raise KeyError(name)
        if self._table is None:
            import colour

            self._table = {"E": None, **colour.SDS_ILLUMINANTS}
        return self._table[name]


#: Illuminants of the CIEDE2000 colour difference by name: colour-science's table plus
#: ``"E"`` (equal energy: the cubes are integrated as they are). The distributions are
#: loaded from colour-science on first access.
ILLUMINANTS: Mapping[str, colour.SpectralDistribution | None] = _IlluminantTable(ILLUMINANT_NAMES)

_METRICS = {
    "nrmse": ("1", "normalised RMSE over wavelength (RMSE / mean ground-truth intensity of the image)"),
    "spectral_angle": ("degree", "spectral angle between reconstruction and ground truth"),
    "delta_e": ("1", "CIEDE2000 colour difference"),
}


# -- inputs ---------------------------------------------------------------------------------
# :func:`evaluate` is the node function: the engine has checked its groups against their
# schemas (spectra, truth/spectra, raw/spectral) before it runs, so it checks only what a
# schema of one group cannot say, that the two cubes fit together (:func:`_align`). The
# other public functions also take bare DataArrays (e.g. baseline cubes), so they check
# those first (:func:`_check_pair`).
def _cube(data: xr.Dataset | xr.DataArray) -> xr.DataArray:
    return data if isinstance(data, xr.DataArray) else data["radiance"]


def _cube_problems(data: xr.Dataset | xr.DataArray, name: str) -> list[Problem]:
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


def _align(s: xr.DataArray, t: xr.DataArray) -> tuple[xr.DataArray, xr.DataArray]:
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


def _check_pair(
    spectra: xr.Dataset | xr.DataArray, truth: xr.Dataset | xr.DataArray
) -> tuple[xr.DataArray, xr.DataArray]:
    problems = _cube_problems(spectra, "spectra") + _cube_problems(truth, "truth")
    if problems:
        raise SchemaError("cannot compare the reconstruction with the ground truth:", problems)
    return _align(_cube(spectra), _cube(truth))


def _labels(values: Sequence[str]) -> np.ndarray:
    """String labels as fixed-width unicode, like the ``channel`` coords of the contract.

    (Object strings would be stored by zarr v3 as variable-length strings, which read back
    as numpy ``StringDType``, a dtype kind the contract's ``kind:UO`` does not accept.)
    """
    return np.array([str(v) for v in values], dtype=str)


def _as_float(array: xr.DataArray) -> xr.DataArray:
    return array.astype(np.float64) if array.dtype != np.float64 else array


def _chunk_spectral(array: xr.DataArray) -> xr.DataArray:
    return array.chunk({"wavelength": -1}) if array.chunks is not None else array


# -- per-pixel metrics ---------------------------------------------------------------------
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
    return _nrmse(*_check_pair(spectra, truth))


def _nrmse(s: xr.DataArray, t: xr.DataArray) -> xr.DataArray:
    return _pixel_maps(s, t, ("nrmse",))["nrmse"]


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
    return _angle(*_check_pair(spectra, truth))


def _angle(s: xr.DataArray, t: xr.DataArray) -> xr.DataArray:
    return _pixel_maps(s, t, ("spectral_angle",))["spectral_angle"]


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


def _pixel_maps(
    s: xr.DataArray, t: xr.DataArray, names: tuple[str, ...], *, illuminant: Illuminant = "D65"
) -> dict[str, xr.DataArray]:
    """The per-pixel maps ``names`` (of :data:`_METRICS`) of aligned cubes, lazy if they are.

    Every block of the cubes is read once for all the maps: computed one map at a time, each
    block of both cubes (as float64) stayed in memory until the last map had used it, which
    held whole cubes at once (24 GB at 22 x 2048^2 x 32).
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
            mean = _as_float(t).mean(("wavelength", "y", "x"), skipna=False)
            values = (values / mean.where(mean > 0)).astype(np.float32)
        units, long_name = _METRICS[name]
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
    return _delta_e(*_check_pair(spectra, truth), illuminant=illuminant)


def _delta_e(s: xr.DataArray, t: xr.DataArray, *, illuminant: Illuminant) -> xr.DataArray:
    return _pixel_maps(s, t, ("delta_e",), illuminant=illuminant)["delta_e"]


# -- statistics ----------------------------------------------------------------------------
def _statistics_numpy(values: np.ndarray, n_core: int) -> np.ndarray:
    """(..., core...) -> (..., 4): nanmean, nanmedian, nan p95, nan p99 over the core axes."""
    lead = values.shape[: values.ndim - n_core]
    flat = np.asarray(values, dtype=np.float64).reshape(*lead, -1)
    out = np.full((*lead, len(STATISTICS)), np.nan)
    if flat.shape[-1] == 0:
        return out
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN images give NaN
        out[..., 0] = np.nanmean(flat, axis=-1)
        out[..., 1:] = np.moveaxis(np.nanquantile(flat, [0.5, 0.95, 0.99], axis=-1), 0, -1)
    return out


def map_statistics(error_map: xr.DataArray, *, dims: Sequence[str] = ("y", "x")) -> xr.DataArray:
    """Mean, median, 95th and 99th percentile of a map over ``dims``, NaN ignored.

    Parameters
    ----------
    error_map
        A metric map, e.g. ``nrmse`` (image, y, x).
    dims
        Dims reduced (default: per image). The map is rechunked to one chunk along them.

    Returns
    -------
    xarray.DataArray
        float64 (remaining dims..., statistic) with ``statistic`` = :data:`STATISTICS`, in
        the units of the map; NaN where no finite value is found.

    Raises
    ------
    SchemaError
        If ``error_map`` lacks one of ``dims``.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 (per-image accuracy of Figures 5 and 6).
    """
    dims = list(dims)
    missing = [d for d in dims if d not in error_map.dims]
    if missing:
        raise SchemaError(
            "cannot summarise the map:",
            [Problem(str(error_map.name), f"dims including {missing}", f"dims {error_map.dims}")],
        )
    if error_map.chunks is not None:
        error_map = error_map.chunk({d: -1 for d in dims})
    stats = xr.apply_ufunc(
        _statistics_numpy,
        error_map,
        kwargs={"n_core": len(dims)},
        input_core_dims=[dims],
        output_core_dims=[["statistic"]],
        dask="parallelized",
        output_dtypes=[np.float64],
        dask_gufunc_kwargs={"output_sizes": {"statistic": len(STATISTICS)}},
    ).assign_coords(statistic=_labels(STATISTICS))
    stats.attrs = {
        "units": error_map.attrs.get("units", "1"),
        "long_name": f"statistics of {error_map.attrs.get('long_name', error_map.name)}",
    }
    return stats


def _histogram_numpy(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    lead = values.shape[:-2]
    flat = values.reshape(-1, values.shape[-2] * values.shape[-1])
    counts = np.stack([np.histogram(row[np.isfinite(row)], bins=edges)[0] for row in flat])
    return counts.reshape(*lead, len(edges) - 1).astype(np.int64)


# -- band shots ----------------------------------------------------------------------------
def band_shot_images(shots: xr.Dataset, images: xr.DataArray | Sequence[int] | int) -> xr.DataArray:
    """Which images have at least one band shot (Figure 7 separates the two kinds).

    Parameters
    ----------
    shots
        Group ``raw/spectral`` or ``bands``: a per-shot ``image`` (shot) index of the RGB
        image each band-filtered frame pairs with.
    images
        The images to classify: a number of images (indices ``0..n-1``), their index values,
        or the ``image`` coordinate of a cube.

    Returns
    -------
    xarray.DataArray
        ``has_band_shots`` (image) bool.

    Raises
    ------
    SchemaError
        If ``shots`` has no integer ``image`` over a ``shot`` dim.

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 "Sparsely Measured Spectral Bands" and
    Figure 7.
    """
    found = shots.get("image") if isinstance(shots, xr.Dataset) else None
    if found is None or found.dims != ("shot",) or found.dtype.kind not in "iu":
        what = "nothing" if found is None else f"dims {found.dims} dtype {found.dtype}"
        raise SchemaError(
            "cannot tell which images have band shots:",
            [
                Problem(
                    "shots:image",
                    "an integer coordinate 'image' (shot) naming the RGB image "
                    "each shot pairs with (groups raw/spectral, bands)",
                    what,
                )
            ],
        )
    if isinstance(images, int | np.integer):
        index = np.arange(int(images))
    else:
        index = np.asarray(images.values if isinstance(images, xr.DataArray) else images)
    return _has_band_shots(shots, index)


def _has_band_shots(shots: xr.Dataset, images: np.ndarray) -> xr.DataArray:
    has = np.isin(images, np.unique(np.asarray(shots["image"].values)))
    return xr.DataArray(
        has,
        dims=("image",),
        name="has_band_shots",
        attrs={"long_name": "image has at least one band shot", "units": "1"},
    )


def _image_index(cube: xr.DataArray) -> np.ndarray:
    if "image" in cube.coords and cube["image"].dims == ("image",):
        return np.asarray(cube["image"].values)
    return np.arange(cube.sizes["image"])


# -- representative spectra ----------------------------------------------------------------
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
        (image, y, x) map from :func:`normalised_rmse`.
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
        If the cubes do not fit together (see :func:`normalised_rmse`) or ``nrmse`` is not
        an (image, y, x) map of their size.
    ParameterError
        If ``quantiles`` are not ascending values in [0, 1].

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5: "We selected representative spectra by
    picking both points with low and high RMSE in the color mapped error maps."
    """
    s, t = _check_pair(spectra, truth)
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
    return _representative(nrmse, s, t, q)


def _quantiles(quantiles: Sequence[float]) -> np.ndarray:
    q = np.asarray(list(quantiles), dtype=np.float64)
    if q.size == 0 or np.any(~np.isfinite(q)) or np.any((q < 0) | (q > 1)) or np.any(np.diff(q) < 0):
        raise ParameterError(
            "cannot pick representative spectra:",
            [Problem("sample_quantiles", "ascending values in [0, 1]", str(q.tolist()))],
        )
    return q


def _representative(nrmse: xr.DataArray, s: xr.DataArray, t: xr.DataArray, q: np.ndarray) -> xr.Dataset:
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


# -- the whole evaluation ------------------------------------------------------------------
def _subset_statistics(
    maps: dict[str, xr.DataArray], masks: dict[str, np.ndarray], threshold: float
) -> xr.Dataset:
    per_metric: dict[str, list[xr.DataArray]] = {name: [] for name in maps}
    fractions, counts = [], []
    for mask in masks.values():
        index = np.flatnonzero(mask)
        for name, error_map in maps.items():
            if index.size == 0:
                stats = xr.DataArray(np.full(len(STATISTICS), np.nan), dims=("statistic",))
            else:
                stats = map_statistics(error_map.isel(image=index), dims=("image", "y", "x"))
            per_metric[name].append(stats.drop_vars("statistic", errors="ignore"))
        if index.size == 0:
            fractions.append(xr.DataArray(np.nan))
            counts.append(xr.DataArray(np.int64(0)))
        else:
            nrmse = maps["nrmse"].isel(image=index)
            finite = nrmse.notnull().sum().astype(np.int64)
            below = (nrmse < threshold).sum()
            fractions.append(below / finite.where(finite > 0))
            counts.append(finite)
    subset = list(masks)
    out = xr.Dataset()
    for name, items in per_metric.items():
        units, long_name = _METRICS[name]
        out[f"{name}_subset_statistics"] = xr.concat(items, dim="subset").assign_attrs(
            units=maps[name].attrs.get("units", units),
            long_name=f"statistics of the {long_name} over all pixels of the subset",
        )
    out["nrmse_subset_fraction_below"] = (
        xr.concat(fractions, dim="subset")
        .astype(np.float64)
        .assign_attrs(
            units="1",
            threshold=threshold,
            long_name=f"fraction of finite pixels with nRMSE < {threshold:g}",
        )
    )
    out["subset_pixel_count"] = xr.concat(counts, dim="subset").assign_attrs(
        units="1", long_name="number of pixels with a finite nRMSE"
    )
    return out.assign_coords(subset=_labels(subset), statistic=_labels(STATISTICS))


def _ascending(value: tuple[float, ...]) -> tuple[float, ...]:
    if list(value) != sorted(value):
        raise PydanticCustomError("ascending", "ascending quantiles")
    return value


def evaluate(
    spectra: xr.Dataset,
    truth: xr.Dataset,
    *,
    shots: xr.Dataset | None = None,
    illuminant: Annotated[str, Choices(ILLUMINANTS, "illuminant")] = "D65",
    threshold: Annotated[float, Field(gt=0)] = DEFAULT_THRESHOLD,
    histogram_bins: Annotated[int, Field(ge=1, le=10000)] = 60,
    histogram_max: Annotated[float, Field(gt=0)] = 0.12,
    sample_quantiles: Annotated[
        tuple[Annotated[float, Field(ge=0, le=1)], ...], Field(min_length=1), AfterValidator(_ascending)
    ] = DEFAULT_SAMPLE_QUANTILES,
) -> xr.Dataset:
    """Compare a reconstructed spectral cube with its ground truth (paper sec. 5, Fig. 5-7).

    Parameters
    ----------
    spectra
        Group ``spectra``: ``radiance`` (image, wavelength, y, x) [1].
    truth
        Group ``truth/spectra``, the same layout, same shape and wavelengths (the images
        may be in another order: they are matched by their ``image`` labels).
    shots
        Group ``raw/spectral`` (or ``bands``): its per-shot ``image`` tells which images have
        band shots. Without it only the subset ``all`` is summarised.
    illuminant
        Illuminant of the CIEDE2000 colour difference (colour-science name, or 'E').
        A key of :data:`ILLUMINANTS`: of ``colour.SDS_ILLUMINANTS``, or ``"E"`` to integrate
        the cubes as they are.
    threshold
        nRMSE level of the fraction-below statistics (Figure 7: ~0.03).
    histogram_bins
        Number of bins of the per-image nRMSE histograms.
        Equal bins over ``[0, histogram_max]``.
    histogram_max
        Upper end of the nRMSE histograms.
        Larger values are counted in ``nrmse_above_range``.
    sample_quantiles
        Quantiles of the nRMSE map where representative spectra are picked.
        Ascending, in [0, 1]: per image, the pixel closest to each quantile.

    Returns
    -------
    xarray.Dataset
        The ``evaluation`` group (schema :data:`spectralize.schemas.run.EVALUATION`): maps
        ``nrmse``,
        ``spectral_angle``, ``delta_e`` (image, y, x) float32; per image ``truth_mean``,
        ``{metric}_statistics`` (image, statistic), ``nrmse_fraction_below``,
        ``invalid_count``, ``nrmse_histogram`` (image, nrmse_bin), ``nrmse_above_range`` and,
        with ``shots``, ``has_band_shots``; per subset ``{metric}_subset_statistics``
        (subset, statistic), ``nrmse_subset_fraction_below``, ``subset_pixel_count``;
        representative pixels ``sample_*`` (image, sample[, wavelength]). Per-image coords of
        the truth are kept. Lazy (dask) when the inputs are; the subset statistics hold the
        maps of a subset in one chunk when computed.

    Raises
    ------
    SchemaError
        If the two cubes do not fit together (shapes, wavelengths, image labels).

    Notes
    -----
    This is the function of the ``evaluate`` node
    (:data:`spectralize.nodes.evaluation.declarations.EVALUATE`). The engine checks its
    groups against their schemas (``spectra``, ``truth/spectra``, ``raw/spectral``) and its
    options against the constraints annotated in this signature before it runs, so only
    what those cannot say, that the two cubes fit together, is checked here. A direct call
    should pass groups that follow the schemas (``spectralize.schemas.check_dataset``) and
    valid options (``EVALUATE.parse_parameters``).

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5 and Figures 5, 6 and 7.
    """
    quantiles = np.asarray(sample_quantiles, dtype=np.float64)
    s, t = _align(_cube(spectra), _cube(truth))

    maps = _pixel_maps(s, t, tuple(_METRICS), illuminant=illuminant)
    nrmse, delta_e = maps["nrmse"], maps["delta_e"]

    truth_mean = _as_float(t).mean(("wavelength", "y", "x"), skipna=False)
    out = xr.Dataset(
        {
            **maps,
            "truth_mean": truth_mean.assign_attrs(
                units=t.attrs.get("units", "1"),
                long_name="mean ground-truth intensity of the image (nRMSE normaliser)",
            ),
        }
    )
    for name, error_map in maps.items():
        units, long_name = _METRICS[name]
        out[f"{name}_statistics"] = map_statistics(error_map).assign_attrs(
            units=error_map.attrs.get("units", units),
            long_name=f"per-image statistics of the {long_name}",
        )
    finite = nrmse.notnull().sum(("y", "x")).astype(np.int64)
    out["nrmse_fraction_below"] = (
        ((nrmse < threshold).sum(("y", "x")) / finite.where(finite > 0))
        .astype(np.float64)
        .assign_attrs(
            units="1",
            threshold=threshold,
            long_name=f"fraction of finite pixels with nRMSE < {threshold:g}",
        )
    )
    out["invalid_count"] = (
        (nrmse.sizes["y"] * nrmse.sizes["x"] - finite)
        .astype(np.int64)
        .assign_attrs(units="1", long_name="pixels with an undefined (NaN) nRMSE")
    )

    edges = np.linspace(0.0, float(histogram_max), int(histogram_bins) + 1)
    source = nrmse.chunk({"y": -1, "x": -1}) if nrmse.chunks is not None else nrmse
    histogram = xr.apply_ufunc(
        _histogram_numpy,
        source,
        kwargs={"edges": edges},
        input_core_dims=[["y", "x"]],
        output_core_dims=[["nrmse_bin"]],
        dask="parallelized",
        output_dtypes=[np.int64],
        dask_gufunc_kwargs={"output_sizes": {"nrmse_bin": edges.size - 1}},
    )
    out["nrmse_histogram"] = histogram.assign_attrs(
        units="1", long_name="per-image histogram of the nRMSE (pixel counts)"
    )
    out["nrmse_above_range"] = (
        (nrmse > histogram_max)
        .sum(("y", "x"))
        .astype(np.int64)
        .assign_attrs(units="1", long_name=f"pixels with nRMSE above {histogram_max:g}")
    )
    out = out.assign_coords(
        nrmse_bin_lower=(
            "nrmse_bin",
            edges[:-1],
            {"units": "1", "long_name": "lower edge of the nRMSE bin"},
        ),
        nrmse_bin_upper=(
            "nrmse_bin",
            edges[1:],
            {"units": "1", "long_name": "upper edge of the nRMSE bin"},
        ),
    )

    images = _image_index(t)
    masks: dict[str, np.ndarray] = {"all": np.ones(images.size, dtype=bool)}
    if shots is not None:
        has = _has_band_shots(shots, images)
        out["has_band_shots"] = has
        masks["with_band_shots"] = has.values
        masks["without_band_shots"] = ~has.values
    out = out.merge(_subset_statistics(maps, masks, threshold), compat="override", join="exact")

    samples = _representative(nrmse, s, t, quantiles)
    out = out.merge(samples, compat="override", join="exact")

    per_image = {name: coord.variable for name, coord in t.coords.items() if coord.dims == ("image",)}
    out = out.assign_coords(per_image)
    out = out.assign_coords(statistic=_labels(STATISTICS))
    out["wavelength"].attrs.update({"units": "nm", "long_name": "wavelength"})
    out.attrs = {
        "illuminant": delta_e.attrs["illuminant"],
        "observer": delta_e.attrs["observer"],
        "threshold": float(threshold),
        "band_shots_known": int(shots is not None),
        "references": "Fast Capture of Spectral Image Series, sec. 5, Figures 5, 6 and 7",
    }
    for role, ds in (("spectra", spectra), ("truth", truth)):
        fingerprint = ds.attrs.get("spectralize_fingerprint") if isinstance(ds, xr.Dataset) else None
        if fingerprint:
            out.attrs[f"{role}_fingerprint"] = str(fingerprint)
    return out


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
        As for :func:`evaluate`.

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
        If there is no method, or a cube does not fit the truth (see :func:`normalised_rmse`).

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
    problems = _cube_problems(truth, "truth")
    if problems:
        raise SchemaError("cannot compare methods:", problems)
    t = _cube(truth)
    masks: dict[str, np.ndarray] = {"all": np.ones(t.sizes["image"], dtype=bool)}
    if shots is not None:
        has = band_shot_images(shots, _image_index(t)).values
        masks.update(with_band_shots=has, without_band_shots=~has)
    rows = []
    for cube in cubes.values():
        s, t = _check_pair(cube, truth)
        maps = _pixel_maps(s, t, tuple(_METRICS), illuminant=illuminant)
        rows.append(_subset_statistics(maps, masks, threshold))
    out = xr.concat(
        rows, dim=METHOD_DIM, coords="minimal", compat="override", join="override"
    ).assign_coords({METHOD_DIM: _labels(list(cubes))})
    out.attrs = {"illuminant": illuminant, "threshold": float(threshold)}
    return out
