"""Reconstruction inputs: the numpy bundle the numerics use, and its checked construction
from xarray (the thin xarray layer).

Bad input raises :class:`~spectralize.schemas.errors.ReconstructionError` (a ``ValueError``)
listing every problem found, each naming the array, what was expected and what was found.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3 (eq. 1: ``R``, ``D``, ``C``, ``s_i``).
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass

import dask.array as da
import numpy as np
import xarray as xr

from spectralize.schemas.errors import ReconstructionError

__all__ = [
    "ReconstructionInputs",
    "camera_blocks",
    "inputs_from_xarray",
    "in_paired_camera",
    "checked_illuminant",
    "illuminant_on_bands",
    "WAVELENGTH_TOLERANCE_NM",
]

WAVELENGTH_TOLERANCE_NM = 0.01
"""Band and camera-matrix wavelengths closer than this are the same wavelength."""


@dataclass(frozen=True)
class ReconstructionInputs:
    """Everything eq. 1 needs, as plain arrays.

    Attributes
    ----------
    rgb
        ``R``: HDR RGB radiance, ``(n_image, height, width, 3)``.
    band_data
        ``D``: calibrated noisy band radiance, ``(n_shot, height, width)``.
    band
        Per shot, the index of its wavelength in :attr:`wavelength`.
    image
        Per shot, the position of its RGB image (0 .. n_image - 1).
    filter_size
        Per shot ``s_i`` in pixels (eq. 3).
    camera_matrix
        ``C``, ``(3, n_wavelength)``: maps a spectrum to RGB; or ``(n_image, 3,
        n_wavelength)``, one ``C_m`` per image (images of several RGB cameras, each through
        its own camera's matrix; :func:`camera_blocks`).
    wavelength
        The spectral grid in nm, increasing: the wavelengths of the band shots.
    illuminant
        ``L``, ``(n_wavelength,)`` float64 on :attr:`wavelength`, or None: the relative
        spectral radiance of the light (any scale; finite, ``>= 0``, not all zero), the
        spectrum of highlights (dichromatic model). Only the set model ``"shared-texel"``
        (:func:`~.estimators.shared_texel.shared_texel_refine`) uses it. Checked on
        construction (:class:`~spectralize.schemas.errors.ReconstructionError` naming
        ``illuminant``, the expected and the found).
    """

    rgb: np.ndarray
    band_data: np.ndarray
    band: np.ndarray
    image: np.ndarray
    filter_size: np.ndarray
    camera_matrix: np.ndarray
    wavelength: np.ndarray
    illuminant: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.illuminant is not None:
            object.__setattr__(
                self, "illuminant", checked_illuminant(self.illuminant, self.wavelength.size)
            )

    @property
    def n_image(self) -> int:
        """Images in the set."""
        return self.rgb.shape[0]

    @property
    def height(self) -> int:
        """Pixels along ``y``."""
        return self.rgb.shape[1]

    @property
    def width(self) -> int:
        """Pixels along ``x``."""
        return self.rgb.shape[2]

    @property
    def n_wavelength(self) -> int:
        """Wavelengths of the spectra (the bands')."""
        return self.wavelength.size

    @property
    def cube_shape(self) -> tuple[int, int, int, int]:
        """``(n_wavelength, n_image, height, width)``: the solvers' layout of ``S``."""
        return (self.n_wavelength, self.n_image, self.height, self.width)

    @property
    def per_image_camera(self) -> bool:
        """Whether every image has its own ``C_m`` (a 3-D :attr:`camera_matrix`)."""
        return self.camera_matrix.ndim == 3

    def camera_of(self, image: int) -> np.ndarray:
        """``C`` of image ``image``, ``(3, n_wavelength)``."""
        return self.camera_matrix[image] if self.per_image_camera else self.camera_matrix

    def cached(self, name: str, compute: Callable[[ReconstructionInputs], np.ndarray]) -> np.ndarray:
        """``compute(self)``, computed on the first call for ``name`` and kept on this object;
        each call returns its own copy.

        For quantities of the inputs alone that several steps of one solve need (the band
        noise, :func:`~.estimators.endmember_mixture.band_noise_sigma`: the spectral prior,
        its band evidence and the set model). The arrays are not changed after
        construction (a changed input is a new object, e.g. ``dataclasses.replace``), so a
        kept value stays the inputs' own.
        """
        kept = self.__dict__.setdefault("_cached", {})
        if name not in kept:
            kept[name] = np.asarray(compute(self))
        return kept[name].copy()

    def check_cubes(self, **cubes: np.ndarray) -> None:
        """Raise :class:`~spectralize.schemas.errors.ReconstructionError` naming the first of
        ``cubes`` (name -> array) whose shape is not :attr:`cube_shape`."""
        for name, cube in cubes.items():
            if np.shape(cube) != self.cube_shape:
                raise ReconstructionError.single(
                    name, f"shape {self.cube_shape} (wavelength, image, y, x)", np.shape(cube)
                )

    def shot_log_ratio_terms(self, shot: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``(D_i - a)^2 - (D_i - b)^2`` over the plane of band shot ``i``, as
        ``(b - a)(2 D_i - a - b)`` (float64), ``a`` and ``b`` two cubes of :attr:`cube_shape`
        read at the shot's wavelength and image: twice the shot's log-likelihood ratio of
        ``b`` over ``a`` times its noise variance (Gaussian noise)."""
        band, image = int(self.band[shot]), int(self.image[shot])
        data = self.band_data[shot].astype(np.float64)
        a_plane = np.asarray(a[band, image], dtype=np.float64)
        b_plane = np.asarray(b[band, image], dtype=np.float64)
        return (b_plane - a_plane) * (2.0 * data - a_plane - b_plane)

    def rgb_pixels(self) -> np.ndarray:
        """``R`` as ``(3, n_pixels)`` over all pixels of all images (solver pixel order)."""
        return np.moveaxis(self.rgb, -1, 0).reshape(3, -1)


def checked_illuminant(illuminant: object, n_wavelength: int) -> np.ndarray:
    """``L`` as a checked ``(n_wavelength,)`` float64 array.

    Raises
    ------
    ReconstructionError
        Naming ``illuminant``, what was expected and what was found: not a real 1-D array
        of ``n_wavelength`` values, a NaN or inf, a negative value, or all zero.
    """
    try:
        values = np.asarray(illuminant, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise ReconstructionError(
            f"illuminant: expected ({n_wavelength},) real values (relative spectral radiance "
            f"of the light on the bands' wavelengths), found {type(illuminant).__name__} ({error})"
        ) from None
    if values.shape != (n_wavelength,):
        raise ReconstructionError(
            f"illuminant: expected shape ({n_wavelength},) (one value per band wavelength), "
            f"found shape {values.shape}"
        )
    problems: list[str] = []
    _check_finite("illuminant", values, problems)
    if problems:
        raise ReconstructionError(problems[0])
    if np.any(values < 0):
        raise ReconstructionError(
            f"illuminant: expected values >= 0 (relative spectral radiance), found "
            f"{int((values < 0).sum())} negative (smallest {float(values.min()):g})"
        )
    if not np.any(values > 0):
        raise ReconstructionError("illuminant: expected a positive value, found all zero")
    return values


def illuminant_on_bands(
    illuminant: xr.DataArray | np.ndarray | None, wavelength: np.ndarray
) -> np.ndarray | None:
    """``L`` on the bands' ``wavelength`` ``(n_wavelength,)``, checked: a DataArray
    ``(wavelength,)`` with a ``wavelength`` coordinate [nm] at them (within
    :data:`WAVELENGTH_TOLERANCE_NM`) or, on another grid that covers them, linearly
    interpolated; an array as given (then it must be on the bands' wavelengths already);
    None stays None.

    Raises
    ------
    ReconstructionError
        Naming ``illuminant``: other dims, no wavelength coordinate, a grid that does not
        cover the bands' wavelengths, or values :func:`checked_illuminant` refuses.
    """
    if illuminant is None or not isinstance(illuminant, xr.DataArray):
        return None if illuminant is None else checked_illuminant(illuminant, wavelength.size)
    if illuminant.dims != ("wavelength",) or "wavelength" not in illuminant.coords:
        raise ReconstructionError(
            f"illuminant: expected dims ('wavelength',) with a 'wavelength' coordinate [nm], "
            f"found {_describe(illuminant)} with coords {_names(illuminant.coords)}"
        )
    grid = np.asarray(illuminant["wavelength"].values, dtype=np.float64)
    values = np.asarray(illuminant.values, dtype=np.float64)
    order = np.argsort(grid, kind="stable")
    grid, values = grid[order], values[order]
    if wavelength.min() < grid.min() - WAVELENGTH_TOLERANCE_NM or (
        wavelength.max() > grid.max() + WAVELENGTH_TOLERANCE_NM
    ):
        raise ReconstructionError(
            f"illuminant: expected a wavelength grid covering the bands' "
            f"{wavelength.min():g}-{wavelength.max():g} nm, found {grid.min():g}-{grid.max():g} nm"
        )
    problems: list[str] = []
    _check_finite("illuminant", values, problems)
    if problems:
        raise ReconstructionError(problems[0])
    nearest = np.abs(grid[:, None] - wavelength[None]).argmin(axis=0)
    if np.all(np.abs(grid[nearest] - wavelength) <= WAVELENGTH_TOLERANCE_NM):
        return checked_illuminant(values[nearest], wavelength.size)
    return checked_illuminant(np.interp(wavelength, grid, values), wavelength.size)


def camera_blocks(camera_matrix: np.ndarray, n_image: int) -> tuple[np.ndarray, np.ndarray]:
    """The distinct camera matrices of a set and which one each image is seen through.

    Parameters
    ----------
    camera_matrix
        ``C``, ``(3, n_wavelength)`` (every image), or ``(n_image, 3, n_wavelength)``.
    n_image
        Images of the set.

    Returns
    -------
    blocks, index
        ``blocks`` ``(n_camera, 3, n_wavelength)`` C-contiguous (one for a 2-D ``C``, the
        distinct ``C_m`` otherwise, in order of first use) and ``index`` ``(n_image,)``
        int64: image ``m`` is seen through ``blocks[index[m]]``.

    Raises
    ------
    ReconstructionError
        For a ``C`` of another shape.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 1 (second term, ``C S(p)``).
    """
    c = np.asarray(camera_matrix)
    if c.ndim == 2 and c.shape[0] == 3:
        return np.ascontiguousarray(c[None]), np.zeros(n_image, dtype=np.int64)
    if c.ndim != 3 or c.shape[:2] != (n_image, 3):
        raise ReconstructionError(
            f"camera_matrix: expected (3, n_wavelength) or (n_image={n_image}, 3, "
            f"n_wavelength), found shape {c.shape}"
        )
    flat = c.reshape(n_image, -1)
    first: dict[bytes, int] = {}
    index = np.empty(n_image, dtype=np.int64)
    kept: list[int] = []
    for m in range(n_image):
        key = np.ascontiguousarray(flat[m]).tobytes()
        if key not in first:
            first[key] = len(kept)
            kept.append(m)
        index[m] = first[key]
    return np.ascontiguousarray(c[kept]), index


def _names(coords: Iterable[Hashable]) -> list[str]:
    """Coordinate names, sorted, for messages."""
    return sorted(str(name) for name in coords)


def _describe(array: xr.DataArray) -> str:
    sizes = ", ".join(f"{d}: {n}" for d, n in array.sizes.items())
    return f"dims ({sizes}) dtype {array.dtype}"


def _check_dims(name: str, array: object, wanted: tuple[str, ...], problems: list[str]) -> bool:
    if not isinstance(array, xr.DataArray):
        problems.append(
            f"{name}: expected an xarray.DataArray with dims {wanted}, found {type(array).__name__}"
        )
        return False
    if set(array.dims) != set(wanted) or len(array.dims) != len(wanted):
        problems.append(f"{name}: expected dims {wanted} (any order), found {_describe(array)}")
        return False
    if not (np.issubdtype(array.dtype, np.floating) or np.issubdtype(array.dtype, np.integer)):
        problems.append(f"{name}: expected a real numeric dtype, found {array.dtype}")
        return False
    if 0 in array.shape:
        problems.append(
            f"{name}: is empty ({_describe(array)}); an empty set has nothing to reconstruct"
        )
        return False
    return True


def _check_finite(name: str, values: np.ndarray, problems: list[str]) -> None:
    bad = ~np.isfinite(values)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        problems.append(
            f"{name}: expected finite values, found {int(np.isnan(values).sum())} "
            f"NaN and {int(np.isinf(values).sum())} inf (first at index {first})"
        )


def inputs_from_xarray(
    rgb: xr.DataArray,
    bands: xr.DataArray,
    camera_matrix: xr.DataArray,
    illuminant: xr.DataArray | np.ndarray | None = None,
) -> ReconstructionInputs:
    """Check the three input arrays against each other and convert them to plain arrays.

    Parameters
    ----------
    rgb
        Dims ``(image, y, x, channel)`` in any order, 3 channels, finite.
    bands
        Dims ``(shot, y, x)``; coords along ``shot``: ``wavelength`` [nm], ``image`` (the
        value of ``rgb``'s ``image`` coordinate, or its position when ``rgb`` has none) and
        ``filter_size`` [px]; finite.
    camera_matrix
        Dims ``(channel, wavelength)`` with a ``wavelength`` coordinate [nm]; 3 channels.
        Every band wavelength must be one of its wavelengths (within
        :data:`WAVELENGTH_TOLERANCE_NM`); wavelengths without a band shot are left out, so
        the spectra live on the bands' wavelengths. One ``C`` per image (images of several
        RGB cameras): dims ``(image, channel, wavelength)``, matched to ``rgb``'s images by
        the ``image`` coordinate (by position where either has none), or ``(camera,
        channel, wavelength)`` with a ``camera`` coordinate, picked per image by ``rgb``'s
        ``camera`` coordinate along ``image``. The neighbour search, the chromaticities
        and the warm start compare the images' RGB as given, so give the images' RGB in
        one camera's space where their cameras differ much (e.g. each mapped by a 3 x 3
        ``T_m`` onto one camera, with ``T_m C_m`` as its ``C``).
    illuminant
        Optional ``L``, the light's relative spectral radiance (any scale, ``>= 0``): dims
        ``(wavelength,)`` with a ``wavelength`` coordinate [nm] (e.g. a calibration's
        ``illuminant``), taken at the bands' wavelengths or linearly interpolated onto them
        from a grid that covers them; or an array of one value per band wavelength
        (increasing). Used by the set model ``"shared-texel"`` only.

    Returns
    -------
    ReconstructionInputs

    Raises
    ------
    ReconstructionError
        Listing every problem found.
    """
    rgb, bands, camera_matrix = _checked_layout(rgb, bands, camera_matrix)
    problems: list[str] = []
    camera_matrix = _checked_channels(rgb, camera_matrix, problems)
    _check_shot_coordinates(rgb, bands, camera_matrix, problems)
    _raise_problems(problems)
    camera_matrix, wavelength, band = _band_grid(bands, camera_matrix, problems)
    labels, image = _shot_images(rgb, bands, problems)
    filter_size = _filter_sizes(rgb, bands, problems)
    rgb_values, band_values, c_values = _checked_values(rgb, bands, camera_matrix, labels, problems)
    _raise_problems(problems)
    if c_values.ndim == 3 and all(np.array_equal(c, c_values[0]) for c in c_values[1:]):
        c_values = c_values[0]  # one camera for every image: the 2-D C (the same solve)
    return ReconstructionInputs(
        rgb=rgb_values,
        band_data=band_values,
        band=band.astype(np.intp),
        image=image,
        filter_size=filter_size,
        camera_matrix=c_values,
        wavelength=wavelength,
        illuminant=illuminant_on_bands(illuminant, wavelength),
    )


def _raise_problems(problems: list[str]) -> None:
    """Raise every problem found so far at once (nothing where there is none)."""
    if problems:
        raise ReconstructionError("reconstruction inputs do not fit together:", problems)


def _checked_layout(
    rgb: xr.DataArray, bands: xr.DataArray, camera_matrix: xr.DataArray
) -> tuple[xr.DataArray, xr.DataArray, xr.DataArray]:
    """The three inputs as DataArrays of the expected dims, numeric and not empty, in the
    order ``(image, y, x, channel)``, ``(shot, y, x)`` and ``([image,] channel,
    wavelength)`` (a per-camera ``C`` picked per image, :func:`_per_image_camera`).

    Raises
    ------
    ReconstructionError
        Listing every array that is not.
    """
    problems: list[str] = []
    c_dims: tuple[str, ...] = ("channel", "wavelength")
    if isinstance(camera_matrix, xr.DataArray) and camera_matrix.ndim == 3:
        extra = [str(d) for d in camera_matrix.dims if d not in c_dims]
        c_dims = (extra[0] if extra and extra[0] in ("image", "camera") else "image", *c_dims)
    ok = [
        _check_dims("rgb", rgb, ("image", "y", "x", "channel"), problems),
        _check_dims("bands", bands, ("shot", "y", "x"), problems),
        _check_dims("camera_matrix", camera_matrix, c_dims, problems),
    ]
    if not all(ok):
        _raise_problems(problems)
    rgb = rgb.transpose("image", "y", "x", "channel")
    bands = bands.transpose("shot", "y", "x")
    camera_matrix = camera_matrix.transpose(*c_dims)
    if len(c_dims) == 3:
        camera_matrix = _per_image_camera(camera_matrix, rgb, problems)
        _raise_problems(problems)
    return rgb, bands, camera_matrix


def _checked_channels(
    rgb: xr.DataArray, camera_matrix: xr.DataArray, problems: list[str]
) -> xr.DataArray:
    """``camera_matrix`` with its channels in ``rgb``'s order (by the ``channel``
    coordinates, where both have them); problems appended: not 3 channels, other names."""
    if rgb.sizes["channel"] != 3:
        problems.append(f"rgb: expected 3 channels, found {rgb.sizes['channel']}")
    if camera_matrix.sizes["channel"] != 3:
        problems.append(
            f"camera_matrix: expected 3 channels (rows), found {camera_matrix.sizes['channel']}"
        )
    if (
        "channel" in rgb.coords
        and "channel" in camera_matrix.coords
        and rgb.sizes["channel"] == camera_matrix.sizes["channel"] == 3
    ):
        rgb_channels = [str(c) for c in rgb["channel"].values]
        c_channels = [str(c) for c in camera_matrix["channel"].values]
        if sorted(rgb_channels) != sorted(c_channels):
            problems.append(f"camera_matrix: channels {c_channels} differ from rgb's {rgb_channels}")
        elif rgb_channels != c_channels:
            camera_matrix = camera_matrix.sel(channel=rgb["channel"].values)
    return camera_matrix


def _check_shot_coordinates(
    rgb: xr.DataArray, bands: xr.DataArray, camera_matrix: xr.DataArray, problems: list[str]
) -> None:
    """Problems appended: band shots of another image size than ``rgb``'s, a shot
    coordinate missing (``wavelength``, ``image``, ``filter_size``), ``camera_matrix``
    without wavelengths."""
    if (bands.sizes["y"], bands.sizes["x"]) != (rgb.sizes["y"], rgb.sizes["x"]):
        problems.append(
            f"bands: expected the rgb image size (y: {rgb.sizes['y']}, x: "
            f"{rgb.sizes['x']}), found (y: {bands.sizes['y']}, x: "
            f"{bands.sizes['x']})"
        )
    for coord in ("wavelength", "image", "filter_size"):
        if coord not in bands.coords or bands[coord].dims != ("shot",):
            problems.append(
                f"bands: expected a coordinate {coord!r} along 'shot', found "
                f"coords {_names(bands.coords)}"
            )
    if "wavelength" not in camera_matrix.coords:
        problems.append("camera_matrix: expected a 'wavelength' coordinate [nm], found none")


def _band_grid(
    bands: xr.DataArray, camera_matrix: xr.DataArray, problems: list[str]
) -> tuple[xr.DataArray, np.ndarray, np.ndarray]:
    """The spectral grid: ``camera_matrix`` in increasing wavelength, restricted to the
    bands' wavelengths, the grid in nm and per shot its wavelength's index (nearest, within
    :data:`WAVELENGTH_TOLERANCE_NM`); problems appended: duplicate wavelengths, band
    wavelengths off ``camera_matrix``'s grid."""
    wavelength = np.asarray(camera_matrix["wavelength"].values, dtype=np.float64)
    order = np.argsort(wavelength, kind="stable")
    if not np.array_equal(order, np.arange(wavelength.size)):
        camera_matrix = camera_matrix.isel(wavelength=order)
        wavelength = wavelength[order]
    if np.any(np.diff(wavelength) <= WAVELENGTH_TOLERANCE_NM):
        problems.append(
            f"camera_matrix: expected distinct wavelengths, found duplicates in {wavelength.tolist()}"
        )
    shot_wavelength = np.asarray(bands["wavelength"].values, dtype=np.float64)
    nearest = np.clip(np.searchsorted(wavelength, shot_wavelength), 0, wavelength.size - 1)
    below = np.clip(nearest - 1, 0, wavelength.size - 1)
    use_below = np.abs(wavelength[below] - shot_wavelength) < np.abs(
        wavelength[nearest] - shot_wavelength
    )
    band = np.where(use_below, below, nearest)
    off_grid = np.abs(wavelength[band] - shot_wavelength) > WAVELENGTH_TOLERANCE_NM
    if off_grid.any():
        problems.append(
            f"bands: wavelengths {np.unique(shot_wavelength[off_grid]).tolist()} nm "
            f"are not on camera_matrix's wavelength grid {wavelength.tolist()} "
            f"(within {WAVELENGTH_TOLERANCE_NM} nm); the bands' wavelengths are "
            f"{np.unique(shot_wavelength).tolist()}: give camera_matrix on a grid "
            "that contains them"
        )
    elif np.unique(band).size < wavelength.size:
        # a wider grid: restrict C to the bands' wavelengths (nearest, within the tolerance)
        used = np.unique(band)
        camera_matrix = camera_matrix.isel(wavelength=used)
        wavelength = wavelength[used]
        band = np.searchsorted(used, band)
    return camera_matrix, wavelength, band


def _shot_images(rgb: xr.DataArray, bands: xr.DataArray, problems: list[str]) -> tuple[list, np.ndarray]:
    """``rgb``'s image labels (its ``image`` coordinate, else positions) and per shot the
    position of its image; problems appended: shots of images ``rgb`` does not have."""
    if "image" in rgb.coords:
        labels = list(np.asarray(rgb["image"].values).tolist())
    else:
        labels = list(range(rgb.sizes["image"]))
    position = {label: i for i, label in enumerate(labels)}
    shot_image_labels = np.asarray(bands["image"].values).tolist()
    unknown = sorted({lab for lab in shot_image_labels if lab not in position}, key=str)
    if unknown:
        problems.append(
            f"bands: coordinate 'image' names images {unknown} that rgb does not "
            f"have (rgb images: {labels[:10]}{' ...' if len(labels) > 10 else ''})"
        )
    return labels, np.array([position.get(lab, -1) for lab in shot_image_labels], dtype=np.intp)


def _filter_sizes(rgb: xr.DataArray, bands: xr.DataArray, problems: list[str]) -> np.ndarray:
    """Per shot ``s_i`` in pixels (float64); problems appended: not finite or not > 0, or
    larger than the image allows (filter centres keep ``s_i`` from its borders)."""
    filter_size = np.asarray(bands["filter_size"].values, dtype=np.float64)
    largest = (min(rgb.sizes["y"], rgb.sizes["x"]) - 1) / 2
    bad = ~np.isfinite(filter_size) | (filter_size <= 0)
    if bad.any():
        problems.append(
            f"bands: filter_size must be finite and > 0, found "
            f"{filter_size[bad].tolist()} (shots {np.flatnonzero(bad).tolist()})"
        )
    too_big = np.isfinite(filter_size) & (filter_size > largest)
    if too_big.any():
        problems.append(
            f"bands: filter_size {filter_size[too_big].tolist()} px (shots "
            f"{np.flatnonzero(too_big).tolist()}) is larger than the image allows: filter "
            f"centres keep s_i from the borders of the {rgb.sizes['y']} x {rgb.sizes['x']} "
            f"image, so s_i <= {largest:g} px"
        )
    return filter_size


def _checked_values(
    rgb: xr.DataArray,
    bands: xr.DataArray,
    camera_matrix: xr.DataArray,
    labels: list,
    problems: list[str],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The three arrays' values in float64; problems appended: NaN or inf, a camera
    matrix (per image: of image ``labels[m]``) of rank below 3."""
    rgb_values = np.asarray(rgb.values, dtype=np.float64)
    band_values = np.asarray(bands.values, dtype=np.float64)
    c_values = np.asarray(camera_matrix.values, dtype=np.float64)
    _check_finite("rgb", rgb_values, problems)
    _check_finite("bands", band_values, problems)
    _check_finite("camera_matrix", c_values, problems)
    if np.all(np.isfinite(c_values)):
        for m, c in enumerate(c_values if c_values.ndim == 3 else [c_values]):
            if np.linalg.matrix_rank(c) < 3:
                which = f" of image {labels[m]!r}" if c_values.ndim == 3 else ""
                problems.append(
                    f"camera_matrix{which}: expected rank 3 (three independent channels), "
                    f"found rank {np.linalg.matrix_rank(c)}"
                )
    return rgb_values, band_values, c_values


def _per_image_camera(
    camera_matrix: xr.DataArray, rgb: xr.DataArray, problems: list[str]
) -> xr.DataArray:
    """A 3-D ``camera_matrix`` (image or camera, channel, wavelength) as ``(image, channel,
    wavelength)`` in ``rgb``'s image order; problems appended."""
    n_image = rgb.sizes["image"]
    if camera_matrix.dims[0] == "camera":
        if "camera" not in rgb.coords or rgb["camera"].dims != ("image",):
            problems.append(
                "camera_matrix: dims (camera, channel, wavelength) need rgb's per-image "
                f"coordinate 'camera' along 'image', found rgb coords {_names(rgb.coords)}"
            )
            return camera_matrix
        if "camera" not in camera_matrix.coords:
            problems.append("camera_matrix: expected a 'camera' coordinate, found none")
            return camera_matrix
        cameras = np.asarray(rgb["camera"].values).tolist()
        known = np.asarray(camera_matrix["camera"].values).tolist()
        missing = sorted({c for c in cameras if c not in known}, key=str)
        if missing:
            problems.append(
                f"camera_matrix: expected a matrix for every camera of rgb's images "
                f"{sorted(set(cameras), key=str)}, found none for camera(s) {missing} "
                f"(camera_matrix has {known})"
            )
            return camera_matrix
        picked = camera_matrix.sel(camera=xr.DataArray(cameras, dims="image"))
        return picked.drop_vars([c for c in picked.coords if "image" in picked[c].dims or c == "camera"])
    if camera_matrix.sizes["image"] != n_image:
        problems.append(
            f"camera_matrix: expected one matrix per rgb image ({n_image}), found "
            f"{camera_matrix.sizes['image']} along 'image'"
        )
        return camera_matrix
    if "image" in camera_matrix.coords and "image" in rgb.coords:
        labels = np.asarray(rgb["image"].values).tolist()
        known = np.asarray(camera_matrix["image"].values).tolist()
        missing = [lab for lab in labels if lab not in known]
        if missing:
            problems.append(
                f"camera_matrix: has no matrix for rgb images {missing[:10]} (its images: "
                f"{known[:10]}{' ...' if len(known) > 10 else ''})"
            )
            return camera_matrix
        camera_matrix = camera_matrix.sel(image=labels)
    return camera_matrix.drop_vars([c for c in camera_matrix.coords if "image" in camera_matrix[c].dims])


def _paired_rgb(maps: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    """Images ``rgb`` (image, ..., channel_in) through their own 3 x 3 ``maps`` (image,
    channel, channel_in), computed in float64, returned in ``rgb``'s dtype."""
    return np.einsum("icd,i...d->i...c", maps, rgb).astype(rgb.dtype)


def in_paired_camera(hdr: xr.Dataset, calibration: xr.Dataset) -> xr.Dataset:
    """``hdr`` with every image's RGB as the paired camera would have measured it (lazy).

    Eq. 1 has one camera matrix ``C``, the paired camera's (its images pair with the band
    shots). An image of RGB camera ``k`` measures ``C_k S``; the calibration's
    ``rgb_transform`` (camera, channel, channel_in), the least-squares 3 x 3 map of ``C_k``
    onto ``C`` over the calibration spectra
    (:func:`~spectralize.nodes.calibration.rgb_transform.rgb_transform`), puts it into the
    paired camera's RGB, where all images compare (neighbours, chromaticities, warm start).
    The run reconstructs the mapped image through ``T_k C_k``, which holds for it exactly
    (:func:`~.set_reconstruction._camera_matrix`); with the paired camera's ``C`` alone the
    map is taken as exact, which it is only on the calibration spectra.
    Unchanged when the calibration has no ``rgb_transform`` (one camera matrix given, e.g.
    the truth) or ``hdr`` no per-image ``camera``.

    Raises
    ------
    ReconstructionError
        An image of a camera the calibration has no map for.
    """
    if "rgb_transform" not in calibration or "camera" not in hdr["radiance"].coords:
        return hdr
    transform = calibration["rgb_transform"].load()
    transform = transform.drop_vars([c for c in transform.coords if c != "camera"])
    cameras = np.asarray(hdr["camera"].values)
    known = set(int(c) for c in transform["camera"].values)
    missing = sorted(set(int(c) for c in np.unique(cameras)) - known)
    if missing:
        raise ReconstructionError(
            f"calibration: rgb_transform has no map for RGB camera(s) {missing} of hdr "
            f"(it has {sorted(known)})"
        )
    if all(
        np.allclose(transform.sel(camera=int(c)).values, np.eye(3), atol=1e-9, rtol=0)
        for c in np.unique(cameras)
    ):
        return hdr
    picked = transform.sel(camera=xr.DataArray(cameras, dims="image"))
    per_image = picked.transpose("image", "channel", "channel_in").values  # (image, 3, 3)
    radiance = hdr["radiance"]
    order = ("image", *(d for d in radiance.dims if d not in ("image", "channel")), "channel")
    data = radiance.transpose(*order).data
    if isinstance(data, da.Array):  # one task per chunk of hdr, its images' maps beside it
        middle = "".join(chr(ord("p") + k) for k in range(data.ndim - 2))
        maps = da.from_array(per_image, chunks=(data.chunks[0], -1, -1))
        values = da.blockwise(
            _paired_rgb,
            f"i{middle}c",
            maps,
            "icd",
            data,
            f"i{middle}d",
            concatenate=True,
            dtype=radiance.dtype,
        )
    else:
        values = _paired_rgb(per_image, data)
    mapped = xr.DataArray(values, dims=order).transpose(*radiance.dims)
    mapped = mapped.assign_attrs(
        hdr["radiance"].attrs, rgb="in the paired camera's RGB (calibration/spectral rgb_transform)"
    )
    return hdr.assign(
        radiance=mapped.assign_coords({c: hdr["radiance"][c] for c in hdr["radiance"].coords})
    )
