"""Colorimetry and sRGB display of spectral cubes (paper Figures 5, 6 and 8, left halves).

The paper shows every ground-truth spectral image "converted to RGB for display". This
module does that conversion with colour-science and the CIE 1931 2 degree standard observer:

1. spectra -> CIE XYZ with :func:`colour.msds_to_XYZ` (``method="Integration"``). The
   cube's values are weighted by an ``illuminant`` and normalised so that a perfect
   reflector (a spectrum equal to 1 everywhere) has ``Y = 1``; ``illuminant=None`` weights
   every wavelength equally (CIE illuminant E), i.e. a radiance cube is integrated as it is.
   Since XYZ is linear in the spectrum the conversion is a ``(wavelength, xyz)`` weight
   matrix that colour-science computes once (:func:`xyz_weights`), applied lazily with dask.
2. XYZ -> sRGB with :func:`colour.XYZ_to_sRGB`, adapting the white (the chromaticity of a
   perfect reflector under the illuminant, integrated on the cube's bands) to D65 with
   CAT02 (the sRGB encoding is applied), then clipped to [0, 1].

**Exposure normalisation.** Spectral radiance has no natural display brightness, so every
render states the factor its XYZ were multiplied by (``attrs["exposure_scale"]``). With
``exposure="auto"`` one factor is used for the whole cube (all images): the ``percentile``-th
percentile of the luminance ``Y`` over every pixel of every image is mapped to ``Y = 1``
(sRGB white); brighter pixels (highlights) clip. Pass the same number as ``exposure`` to
render a reconstruction exactly like its ground truth.

References
----------
Fast Capture of Spectral Image Series, Figures 5, 6 and 8 ("ground truth image (converted to
RGB for display)"). CIE 015:2018 Colorimetry; IEC 61966-2-1:1999 (sRGB).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Literal, Union

import numpy as np
import numpy.typing as npt
import xarray as xr

from spectralize.schemas import ParameterError, Problem, SchemaError

if TYPE_CHECKING:
    import colour

# colour-science is imported inside the functions that use it: importing it is slow (it
# imports matplotlib), which declaring the ``evaluate`` node (``spectralize nodes``) must not pay.

__all__ = [
    "OBSERVER",
    "Illuminant",
    "illuminant_sd",
    "white_point",
    "xyz_weights",
    "spectra_to_xyz",
    "xyz_to_srgb",
    "auto_exposure",
    "render_srgb",
]

#: The colour matching functions used throughout (CIE 1931 2 degree standard observer).
OBSERVER: str = "CIE 1931 2 Degree Standard Observer"

#: An illuminant: a key of ``colour.SDS_ILLUMINANTS``, a spectral distribution, or ``None``
#: (equal energy, CIE illuminant E: the spectra are integrated as they are).
Illuminant = Union[str, "colour.SpectralDistribution", None]  # noqa: UP007 (a forward reference)

_WAVELENGTH_TOLERANCE_NM = 1e-6


@contextmanager
def _quiet_colour() -> Iterator[None]:
    """Silence colour-science's notes about aligning spectral shapes (expected here)."""
    import colour

    with warnings.catch_warnings():
        for category in (
            colour.utilities.ColourWarning,
            colour.utilities.ColourRuntimeWarning,
            colour.utilities.ColourUsageWarning,
        ):
            warnings.simplefilter("ignore", category)
        yield


def illuminant_sd(illuminant: Illuminant) -> colour.SpectralDistribution | None:
    """The spectral distribution of ``illuminant`` (``None`` stays ``None``: illuminant E).

    Raises
    ------
    ParameterError
        If a name is not a key of ``colour.SDS_ILLUMINANTS`` (the message lists some) or
        ``illuminant`` is of another type.

    References
    ----------
    CIE 015:2018 Colorimetry (standard illuminants).
    """
    import colour

    if illuminant is None or isinstance(illuminant, colour.SpectralDistribution):
        return illuminant
    if isinstance(illuminant, str):
        if illuminant == "E":
            return None
        try:
            return colour.SDS_ILLUMINANTS[illuminant]
        except KeyError:
            known = ", ".join(list(colour.SDS_ILLUMINANTS)[:12])
            raise ParameterError(
                "unknown illuminant:",
                [
                    Problem(
                        "illuminant",
                        f"a key of colour.SDS_ILLUMINANTS (e.g. {known}, ...), 'E', a "
                        "SpectralDistribution or None",
                        f"{illuminant!r}, which is not a colour-science illuminant",
                    )
                ],
            ) from None
    raise ParameterError(
        "unknown illuminant:",
        [
            Problem(
                "illuminant",
                "a name, a colour.SpectralDistribution or None",
                f"a {type(illuminant).__name__}",
            )
        ],
    )


def white_point(
    illuminant: Illuminant, wavelength: npt.ArrayLike | None = None
) -> npt.NDArray[np.float64]:
    """CIE 1931 xy chromaticity of the white of ``illuminant`` (``None``: E, (1/3, 1/3)).

    With ``wavelength``, the chromaticity of a perfect reflector integrated on those bands
    (:func:`xyz_weights`), which is the white that a cube on those bands can reach: a band
    range narrower than 360..830 nm shifts it slightly (D65 on 410..720 nm: x = 0.3129,
    y = 0.3298).

    Parameters
    ----------
    illuminant
        See :data:`Illuminant`.
    wavelength
        Band centres [nm], evenly spaced; ``None`` for the illuminant's own white.

    Returns
    -------
    numpy.ndarray
        float64 (2,): x, y.

    References
    ----------
    CIE 015:2018 Colorimetry (chromaticity coordinates, white points).
    """
    import colour

    if wavelength is not None:
        xyz = xyz_weights(wavelength, illuminant=illuminant).values.sum(axis=0)
        return np.asarray(colour.XYZ_to_xy(xyz), dtype=np.float64)
    sd = illuminant_sd(illuminant)
    if sd is None:
        return np.array([1.0 / 3.0, 1.0 / 3.0])
    if isinstance(illuminant, str) and illuminant in colour.CCS_ILLUMINANTS[OBSERVER]:
        return np.asarray(colour.CCS_ILLUMINANTS[OBSERVER][illuminant], dtype=np.float64)
    cmfs = colour.MSDS_CMFS[OBSERVER]
    with _quiet_colour():
        xyz = colour.sd_to_XYZ(sd, cmfs=cmfs, method="Integration")
    return np.asarray(colour.XYZ_to_xy(xyz), dtype=np.float64)


def _spectral_shape(wavelength: npt.ArrayLike) -> colour.SpectralShape:
    import colour

    wl = np.asarray(wavelength, dtype=np.float64).reshape(-1)
    if wl.size < 2:
        raise SchemaError(
            "cannot integrate the spectra:",
            [Problem("wavelength", "at least 2 wavelengths [nm]", f"{wl.size}")],
        )
    steps = np.diff(wl)
    if (
        not np.all(np.isfinite(wl))
        or np.any(steps <= 0)
        or not np.allclose(steps, steps[0], rtol=0, atol=_WAVELENGTH_TOLERANCE_NM)
    ):
        raise SchemaError(
            "cannot integrate the spectra:",
            [
                Problem(
                    "wavelength",
                    "finite, increasing, evenly spaced values [nm] (colour-science "
                    "integrates on a SpectralShape)",
                    np.array2string(wl, precision=2),
                )
            ],
        )
    return colour.SpectralShape(float(wl[0]), float(wl[-1]), float(steps[0]))


def xyz_weights(wavelength: npt.ArrayLike, *, illuminant: Illuminant = "D65") -> xr.DataArray:
    """Weights ``W`` (wavelength, xyz) with ``XYZ = sum_wavelength S W`` as colour-science does.

    ``W[j]`` is ``colour.msds_to_XYZ(e_j, cmfs, illuminant, method="Integration",
    shape=...) / 100`` for the unit spectrum ``e_j``: colour-science's integration, which is
    linear in the spectrum, evaluated once. A spectrum equal to 1 everywhere has ``Y = 1``.

    Parameters
    ----------
    wavelength
        Band centres [nm], evenly spaced (e.g. 410, 420, ..., 720).
    illuminant
        See :data:`Illuminant`.

    Returns
    -------
    xarray.DataArray
        float64 (wavelength, xyz) with ``xyz = ['X', 'Y', 'Z']``.

    Raises
    ------
    SchemaError
        If the wavelengths are not evenly spaced.
    ParameterError
        If the illuminant is unknown.

    References
    ----------
    CIE 015:2018 Colorimetry; colour-science's ``colour.msds_to_XYZ`` (integration).
    """
    import colour

    shape = _spectral_shape(wavelength)
    sd = illuminant_sd(illuminant)
    n = len(shape.wavelengths)
    cmfs = colour.MSDS_CMFS[OBSERVER]
    with _quiet_colour():
        weights = (
            colour.msds_to_XYZ(np.eye(n), cmfs=cmfs, illuminant=sd, method="Integration", shape=shape)
            / 100.0
        )
    return xr.DataArray(
        np.asarray(weights, dtype=np.float64),
        dims=("wavelength", "xyz"),
        coords={
            "wavelength": np.asarray(wavelength, dtype=np.float64).reshape(-1),
            "xyz": ["X", "Y", "Z"],
        },
        attrs={
            "long_name": "CIE XYZ weights per wavelength",
            "observer": OBSERVER,
            "illuminant": _illuminant_name(illuminant),
        },
    )


def _illuminant_name(illuminant: Illuminant) -> str:
    if illuminant is None:
        return "E (equal energy)"
    if isinstance(illuminant, str):
        return illuminant
    return str(getattr(illuminant, "name", "custom"))


def spectra_to_xyz(radiance: xr.DataArray, *, illuminant: Illuminant = "D65") -> xr.DataArray:
    """CIE XYZ of every spectrum of ``radiance`` (lazy if ``radiance`` is dask-backed).

    Parameters
    ----------
    radiance
        Any dims including ``wavelength`` [nm] (with coordinate values).
    illuminant
        See :data:`Illuminant`.

    Returns
    -------
    xarray.DataArray
        float64 with ``wavelength`` replaced by a trailing ``xyz`` dim; ``Y = 1`` is the
        perfect reflector under ``illuminant``, whose chromaticity on these bands is in
        ``attrs["white_xy"]`` (the reference white of CIELAB and of the sRGB adaptation).

    Raises
    ------
    SchemaError
        If ``radiance`` has no ``wavelength`` dim with coordinates, or they are not evenly
        spaced.

    References
    ----------
    Fast Capture of Spectral Image Series, Figures 5, 6 and 8 (spectra "converted to RGB
    for display"); CIE 015:2018 Colorimetry.
    """
    import colour

    if "wavelength" not in radiance.dims or "wavelength" not in radiance.coords:
        raise SchemaError(
            "cannot integrate the spectra:",
            [
                Problem(
                    "radiance:wavelength",
                    "a 'wavelength' dim with coordinates [nm]",
                    f"dims {radiance.dims} and coords {list(radiance.coords)}",
                )
            ],
        )
    weights = xyz_weights(radiance["wavelength"].values, illuminant=illuminant)
    if radiance.chunks is not None:
        radiance = radiance.chunk({"wavelength": -1})
    weights = weights.assign_coords(wavelength=radiance["wavelength"])
    xyz = xr.dot(radiance.astype(np.float64), weights, dim="wavelength")
    dims = [d for d in radiance.dims if d != "wavelength"] + ["xyz"]
    xyz = xyz.transpose(*dims)
    white = colour.XYZ_to_xy(weights.values.sum(axis=0))
    xyz.attrs = {
        "units": "1",
        "long_name": "CIE 1931 XYZ tristimulus values",
        "observer": OBSERVER,
        "illuminant": _illuminant_name(illuminant),
        "white_xy": [float(white[0]), float(white[1])],
    }
    return xyz


def _xyz_to_srgb_numpy(xyz: np.ndarray, white: np.ndarray) -> np.ndarray:
    import colour

    with _quiet_colour():
        rgb = colour.XYZ_to_sRGB(
            xyz, illuminant=white, chromatic_adaptation_transform="CAT02", apply_cctf_encoding=True
        )
    rgb = np.nan_to_num(np.asarray(rgb, dtype=np.float64), nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(rgb, 0.0, 1.0)


def xyz_to_srgb(
    xyz: xr.DataArray, *, white: npt.ArrayLike | None = None, dtype: Literal["uint8", "float"] = "uint8"
) -> xr.DataArray:
    """Encoded sRGB (``..., channel``) of XYZ (``..., xyz``), clipped to [0, 1] (NaN -> 0).

    The scene white ``white`` (xy; default ``xyz.attrs["white_xy"]`` as written by
    :func:`spectra_to_xyz`, else D65) is adapted to D65 with CAT02, so a perfect reflector
    at ``Y = 1`` renders as sRGB white.

    Parameters
    ----------
    xyz
        CIE XYZ with a trailing ``xyz`` dim, e.g. from :func:`spectra_to_xyz`.
    white
        Chromaticity (x, y) of the scene white.
    dtype
        ``"uint8"`` rounds ``255 * v``; ``"float"`` returns float32 in [0, 1].

    Returns
    -------
    xarray.DataArray
        (..., channel) with ``channel = ['R', 'G', 'B']``.

    References
    ----------
    IEC 61966-2-1:1999 (sRGB); CIE 160:2004 (CAT02 chromatic adaptation).
    """
    if dtype not in ("uint8", "float"):
        raise ParameterError(
            "cannot encode sRGB:", [Problem("dtype", "'uint8' or 'float'", repr(dtype))]
        )
    if white is None:
        white = xyz.attrs.get("white_xy", white_point("D65"))
    white = np.asarray(white, dtype=np.float64)
    rgb = xr.apply_ufunc(
        _xyz_to_srgb_numpy,
        xyz,
        kwargs={"white": white},
        input_core_dims=[["xyz"]],
        output_core_dims=[["channel"]],
        dask="parallelized",
        output_dtypes=[np.float64],
        dask_gufunc_kwargs={"output_sizes": {"channel": 3}},
    ).assign_coords(channel=["R", "G", "B"])
    if dtype == "uint8":
        rgb = (rgb * 255.0).round().astype(np.uint8)
    else:
        rgb = rgb.astype(np.float32)
    rgb.attrs = {
        "units": "1",
        "long_name": "sRGB (IEC 61966-2-1, encoded) for display",
        "observer": xyz.attrs.get("observer", OBSERVER),
        "illuminant": xyz.attrs.get("illuminant", "?"),
        "white_xy": [float(white[0]), float(white[1])],
    }
    return rgb


def auto_exposure(xyz: xr.DataArray, *, percentile: float = 99.0) -> float:
    """The factor that maps the ``percentile``-th percentile of ``Y`` (all pixels) to 1.

    Non-finite values are ignored; when no positive luminance is found the factor is 1.
    This computes the luminance of the whole cube (one pass).

    Parameters
    ----------
    xyz
        CIE XYZ with an ``xyz`` dim, e.g. from :func:`spectra_to_xyz`.
    percentile
        Percentile of ``Y`` over all pixels that becomes sRGB white, in (0, 100].

    Returns
    -------
    float
        The factor XYZ is multiplied by.

    References
    ----------
    Fast Capture of Spectral Image Series, Figures 5, 6 and 8 (RGB renders for display).
    """
    if not 0.0 < percentile <= 100.0:
        raise ParameterError(
            "cannot choose the exposure:",
            [Problem("percentile", "a value in (0, 100]", repr(percentile))],
        )
    luminance = np.asarray(xyz.sel(xyz="Y").values, dtype=np.float64).reshape(-1)
    luminance = luminance[np.isfinite(luminance)]
    if luminance.size == 0:
        return 1.0
    level = float(np.percentile(luminance, percentile))
    return 1.0 / level if level > 0 else 1.0


def _bad_exposure(exposure: object) -> ParameterError:
    return ParameterError(
        "cannot render sRGB:", [Problem("exposure", "'auto' or a positive number", repr(exposure))]
    )


def render_srgb(
    spectra: xr.DataArray | xr.Dataset,
    *,
    illuminant: Illuminant = None,
    exposure: float | Literal["auto"] = "auto",
    percentile: float = 99.0,
    dtype: Literal["uint8", "float"] = "uint8",
) -> xr.DataArray:
    """sRGB display image of a spectral cube (CIE 1931 2 degree observer, colour-science).

    Parameters
    ----------
    spectra
        ``radiance`` (image, wavelength, y, x), or a Dataset holding it (groups ``spectra``
        and ``truth/spectra``). Any other dims are kept; ``wavelength`` needs coordinates.
    illuminant
        Weighting of the spectra (see :data:`Illuminant`). The default ``None`` integrates a
        radiance cube as it is (it already contains the light) and adapts equal-energy white
        to D65; pass e.g. ``"D65"`` for reflectance cubes.
    exposure
        ``"auto"``: one factor for the whole cube mapping the ``percentile``-th percentile
        of the luminance to sRGB white; or the factor itself (e.g. the ``exposure_scale`` of
        the ground truth's render, to show a reconstruction the same way).
    percentile
        Percentile used by ``exposure="auto"``.
    dtype
        ``"uint8"`` (0..255) or ``"float"`` (float32 in [0, 1]).

    Returns
    -------
    xarray.DataArray
        (image, y, x, channel) with ``channel = ['R', 'G', 'B']``; attrs state
        ``exposure_scale``, ``exposure_normalisation``, ``illuminant`` and ``observer``.
        Lazy when the input is dask-backed (``exposure="auto"`` computes the luminance once).

    References
    ----------
    Fast Capture of Spectral Image Series, Figures 5, 6 and 8 (RGB renders of the truth).
    """
    radiance = spectra["radiance"] if isinstance(spectra, xr.Dataset) else spectra
    xyz = spectra_to_xyz(radiance, illuminant=illuminant)
    if isinstance(exposure, str):
        if exposure != "auto":
            raise _bad_exposure(exposure)
        scale = auto_exposure(xyz, percentile=percentile)
        statement = (
            f"XYZ scaled by {scale:.6g} so that the {percentile:g}th percentile of the "
            "luminance Y over all pixels of all images is sRGB white (Y = 1)"
        )
    else:
        scale = float(exposure)
        if not np.isfinite(scale) or scale <= 0:
            raise _bad_exposure(exposure)
        statement = f"XYZ scaled by the given exposure factor {scale:.6g}"
    scaled = xyz * scale
    scaled.attrs = xyz.attrs
    rgb = xyz_to_srgb(scaled, dtype=dtype)
    rgb.attrs.update({"exposure_scale": scale, "exposure_normalisation": statement})
    rgb.name = "srgb"
    return rgb
