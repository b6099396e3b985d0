"""Flat-field maps: a smooth fit of a white-reference frame and its division out of images.

- :func:`fit_flat_field`: one frame of the white reference -> a smooth map ``F`` (a
  low-order Legendre polynomial in the frame coordinates, 1 at the frame centre), its noise
  floor and the measures of an uneven target (local dip, gradient, corners).
- :class:`FlatField`: the fitted maps of one camera per row (RGB cameras, per channel) or
  of one spectral band per row, and :meth:`FlatField.divide`, which takes them out of
  images or band shots block by block (lazy stays lazy; the maps are never stored whole).
- :func:`smooth_across_bands`: the spectral camera's per-band maps, each a local linear fit
  over its neighbouring bands in wavelength weighted by their noise floors (a weak band
  borrows the falloff of its better-lit neighbours).
- :func:`from_calibration`: the maps stored in ``calibration/spectral``.

Nothing of the calibration's other modules is imported here, so that the HDR merge, the band
radiance and the targets' fits take the maps out without importing the module that measures
them (:mod:`~spectralize.nodes.calibration.flat_field`, which says why a polynomial and why
the centre).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4 ("taking images of a white diffuse
   reference surface") and eq. 5 (``I = f^-1(x t Q_lambda)``, here with ``Q_lambda F(p)``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import dask.array as da
import numpy as np
import xarray as xr
from numpy.polynomial import legendre
from scipy import ndimage

from spectralize.schemas import CalibrationError

__all__ = [
    "DEGREE",
    "BLOCKS",
    "OUTLIER_SIGMAS",
    "FlatFieldFit",
    "FlatField",
    "legendre_powers",
    "flat_field_basis",
    "fit_flat_field",
    "BAND_BANDWIDTH",
    "smooth_across_bands",
    "from_calibration",
]

DEGREE = 4
"""Total degree of the flat field's Legendre polynomial in the frame coordinates."""

BLOCKS = 32
"""Block means per frame side the polynomial is fitted to (fewer on smaller frames)."""

OUTLIER_SIGMAS = 5.0
"""Blocks further than this many robust standard deviations from the first fit are left out
of the second (a shadow or a smudge does not bend the map)."""

BAND_BANDWIDTH = 30.0
"""Standard deviation [nm] of the Gaussian kernel in wavelength over which
:func:`smooth_across_bands` fits each band's map from its neighbours'."""


def legendre_powers(degree: int = DEGREE) -> np.ndarray:
    """(term, 2) the Legendre orders ``(i, j)`` in ``y``, ``x`` of every term of total degree
    at most ``degree``, by degree."""
    return np.array([(i, d - i) for d in range(degree + 1) for i in range(d, -1, -1)], dtype=int)


def _coordinates(n: int, start: int = 0, stop: int | None = None, step: int = 1) -> np.ndarray:
    """Pixel centres ``start..stop`` (every ``step``-th) of an axis of ``n`` pixels on
    ``[-1, 1]``."""
    stop = n if stop is None else stop
    return (np.arange(start, stop, step) + 0.5) / n * 2.0 - 1.0


def _legendre(order: int, t: np.ndarray) -> np.ndarray:
    return legendre.legval(t, np.eye(order + 1)[order])


def flat_field_basis(
    powers: np.ndarray, frame: tuple[int, int], y: slice = slice(None), x: slice = slice(None)
) -> np.ndarray:
    """(term, y, x) the Legendre terms ``P_i(v) P_j(u)`` on pixels ``y``, ``x`` of a frame of
    ``frame`` pixels (``u``, ``v`` the pixel centres on ``[-1, 1]``; slices with a step
    sample the frame)."""
    v = _coordinates(frame[0], *y.indices(frame[0]))
    u = _coordinates(frame[1], *x.indices(frame[1]))
    return _outer(powers, v, u)


def _outer(powers: np.ndarray, v: np.ndarray, u: np.ndarray) -> np.ndarray:
    rows = {i: _legendre(i, v) for i in set(powers[:, 0].tolist())}
    cols = {j: _legendre(j, u) for j in set(powers[:, 1].tolist())}
    return np.stack([np.outer(rows[i], cols[j]) for i, j in powers.tolist()])


@dataclass(frozen=True)
class FlatFieldFit:
    """:func:`fit_flat_field` of one white-reference frame."""

    coefficients: np.ndarray
    """(term,) the map's Legendre coefficients, 1 at the frame centre."""
    noise: float
    """The map's noise floor: the largest standard error of the fitted map over the frame
    (from the scatter of the block means about it), relative."""
    unevenness: float
    """The largest local deviation of the white reference from the smooth map (block
    residuals averaged over 3 x 3 blocks), relative, signed: a shadow or a smudge."""
    unevenness_floor: float
    """What the noise alone gives :attr:`unevenness` (six standard deviations of the
    3 x 3 block average)."""
    gradient: float
    """The largest odd part of the map about the frame centre (``(F(p) - F(-p)) / 2``),
    relative: a tilted or unevenly lit target (a centred lens falloff has none)."""
    corner: float
    """The map's corner value farthest from 1."""


def _block_means(frame: np.ndarray, blocks: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means of ``frame`` over at most ``blocks`` x ``blocks`` blocks and the blocks' centres
    on ``[-1, 1]`` (``v`` over rows, ``u`` over columns)."""
    ny, nx = frame.shape
    edges_y = np.linspace(0, ny, min(blocks, ny) + 1).round().astype(int)
    edges_x = np.linspace(0, nx, min(blocks, nx) + 1).round().astype(int)
    sums = np.add.reduceat(np.add.reduceat(frame, edges_y[:-1], axis=0), edges_x[:-1], axis=1)
    counts = np.outer(np.diff(edges_y), np.diff(edges_x))
    v = np.add.reduceat(_coordinates(ny), edges_y[:-1]) / np.diff(edges_y)
    u = np.add.reduceat(_coordinates(nx), edges_x[:-1]) / np.diff(edges_x)
    return sums / counts, v, u


def fit_flat_field(frame: np.ndarray, *, degree: int = DEGREE, blocks: int = BLOCKS) -> FlatFieldFit:
    """The smooth flat field of one white-reference frame, with its noise floor.

    ``F(u, v) = sum_ij c_ij P_i(v) P_j(u)`` (Legendre polynomials of total degree at most
    ``degree``) fitted by least squares to the frame's block means, once more without the
    blocks further than :data:`OUTLIER_SIGMAS` robust standard deviations from the first fit,
    and divided by its value at the frame centre.

    Parameters
    ----------
    frame
        (y, x) the white reference's linear signal (any positive units): an HDR channel or
        a band's dark-subtracted, linearised signal per second.
    degree
        Total degree of the polynomial.
    blocks
        Block means per side fitted (fewer on a smaller frame).

    Returns
    -------
    FlatFieldFit
        Coefficients (1 at the centre), noise floor and the evenness measures.

    Raises
    ------
    CalibrationError
        A frame with fewer blocks than terms, not finite, or not positive at its centre.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    """
    powers = legendre_powers(degree)
    values = np.asarray(frame, dtype=np.float64)
    means, v, u = _block_means(values, blocks)
    if means.size < 2 * len(powers) or not np.all(np.isfinite(means)):
        raise CalibrationError(
            f"flat field: a white-reference frame of {values.shape} px gives {means.shape} "
            f"block means ({'finite' if np.all(np.isfinite(means)) else 'not finite'}); "
            f"at least {2 * len(powers)} finite ones are needed for degree {degree}"
        )
    design = _outer(powers, v, u).reshape(len(powers), -1).T
    target = means.ravel()
    keep = np.ones(target.size, dtype=bool)
    for _ in range(2):
        coefficients = np.linalg.lstsq(design[keep], target[keep], rcond=None)[0]
        residual = target - design @ coefficients
        scale = 1.4826 * np.median(np.abs(residual[keep])) + 1e-12 * np.abs(target).max()
        keep = np.abs(residual) <= OUTLIER_SIGMAS * scale
        keep = keep if keep.sum() >= 2 * len(powers) else np.ones_like(keep)
    centre = float(_outer(powers, np.zeros(1), np.zeros(1)).ravel() @ coefficients)
    if not centre > 0:
        raise CalibrationError(
            f"flat field: the white reference's fitted signal at the frame centre is {centre:.3g}, "
            "not positive"
        )
    coefficients = coefficients / centre
    fitted = (design @ coefficients).reshape(means.shape)
    relative = (target / centre).reshape(means.shape) / fitted - 1.0
    dof = max(int(keep.sum()) - len(powers), 1)
    sigma = float(np.sqrt(np.sum(relative.ravel()[keep] ** 2) / dof))
    leverage = np.einsum("pt,tk,pk->p", design, np.linalg.pinv(design[keep].T @ design[keep]), design)
    local = ndimage.uniform_filter(relative, size=3, mode="nearest")
    worst = np.unravel_index(int(np.argmax(np.abs(local))), local.shape)
    odd = (powers.sum(axis=1) % 2 == 1).astype(float)
    corners = _outer(powers, np.array([-1.0, 1.0]), np.array([-1.0, 1.0])).reshape(len(powers), -1)
    corner_values = corners.T @ coefficients
    return FlatFieldFit(
        coefficients=coefficients,
        noise=float(sigma * np.sqrt(leverage.max())),
        unevenness=float(local[worst]),
        unevenness_floor=float(6.0 * sigma / 3.0),
        gradient=float(np.abs(design @ (coefficients * odd)).max()),
        corner=float(corner_values[np.argmax(np.abs(corner_values - 1.0))]),
    )


def smooth_across_bands(
    coefficients: np.ndarray,
    fits: list[FlatFieldFit],
    wavelengths: np.ndarray,
    *,
    bandwidth: float = BAND_BANDWIDTH,
) -> tuple[np.ndarray, list[FlatFieldFit]]:
    """The spectral camera's per-band maps fitted as a smooth function of wavelength.

    A lens's falloff and a tunable filter's off-axis loss change slowly with the wavelength,
    while the white reference's light does not: the bands at the ends of the range get a
    small share of it, and each one's own map is noisy there. Each band's coefficients (and
    so its map at every pixel, the maps being linear in them) are replaced by the value at
    its wavelength of a local linear fit over the bands, weighted least squares with weights
    ``exp(-(lambda_j - lambda_k)^2 / (2 h^2)) / sigma_j^2`` (``sigma_j`` band ``j``'s noise
    floor, :attr:`FlatFieldFit.noise`; ``h`` the ``bandwidth``): a well-lit band keeps
    nearly its own map, up to the noise its neighbours average out, a weak one takes the
    falloff its better-lit neighbours trace towards it. The fit reproduces a map that is
    the same at every band, so each map stays 1 at the frame centre.

    Parameters
    ----------
    coefficients
        (band, term) each band's Legendre coefficients (:func:`fit_flat_field`).
    fits
        (band,) each band's :class:`FlatFieldFit`.
    wavelengths
        (band,) the bands' wavelengths [nm].
    bandwidth
        Standard deviation of the kernel [nm]; 0 leaves every band its own map.

    Returns
    -------
    tuple
        (band, term) the smoothed coefficients, and the fits with :attr:`FlatFieldFit.noise`
        the smoothed map's (``sqrt(sum_j L_kj^2 sigma_j^2)``, ``L`` the fit's weights; the
        evenness measures stay the band's own frame's).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 and eq. 5.
    .. [2] W. S. Cleveland, S. J. Devlin, "Locally weighted regression: an approach to
       regression analysis by local fitting", Journal of the American Statistical
       Association 83(403), 1988.
    """
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    if not bandwidth > 0 or np.unique(wavelengths).size < 2:
        return coefficients, fits
    noise = np.maximum(np.array([f.noise for f in fits], dtype=np.float64), 1e-9)
    smoother = np.empty((wavelengths.size, wavelengths.size))
    for k, centre in enumerate(wavelengths):
        offset = (wavelengths - centre) / bandwidth
        weight = np.exp(-0.5 * offset**2) / noise**2
        design = np.stack([np.ones_like(offset), offset], axis=1)
        normal = design.T @ (weight[:, None] * design)
        smoother[k] = np.linalg.solve(normal, design.T * weight)[0]  # the fit's value at k
    smoothed = [
        replace(f, noise=float(np.sqrt(np.sum(smoother[k] ** 2 * noise**2)))) for k, f in enumerate(fits)
    ]
    return smoother @ coefficients, smoothed


@dataclass(frozen=True)
class FlatField:
    """Flat fields of several cameras (RGB: per channel) or bands, as Legendre coefficients.

    Row ``r`` of :attr:`coefficients` is the map of the camera or band ``keys[r]``;
    :meth:`divide` takes the maps out of images or shots.
    """

    coefficients: np.ndarray
    """(row, [channel,] term) Legendre coefficients, each map 1 at the frame centre."""
    powers: np.ndarray
    """(term, 2) the Legendre orders (:func:`legendre_powers`)."""
    frame: tuple[int, int]
    """(y, x) pixels of the frames the maps were fitted on."""
    keys: np.ndarray
    """(row,) the camera index or band wavelength [nm] of each row."""

    def rows(self, labels: np.ndarray, what: str) -> np.ndarray:
        """The row of each of ``labels`` (camera indices or wavelengths, nearest within
        1e-6); a :class:`CalibrationError` naming ``what`` where one has none."""
        labels = np.asarray(labels, dtype=float).ravel()
        keys = np.asarray(self.keys, dtype=float)
        index = np.abs(labels[:, None] - keys[None, :]).argmin(axis=1)
        missing = np.abs(keys[index] - labels) > 1e-6
        if missing.any():
            raise CalibrationError(
                f"flat field: no map for {what} {sorted(set(labels[missing].tolist()))}; "
                f"maps exist for {keys.tolist()}"
            )
        return index

    def maps(self, rows: np.ndarray, y: slice = slice(None), x: slice = slice(None)) -> np.ndarray:
        """(row, y, x[, channel]) the maps of ``rows`` on pixels ``y``, ``x``."""
        basis = flat_field_basis(self.powers, self.frame, y, x)
        coefficients = self.coefficients[np.asarray(rows, dtype=int)]
        if coefficients.ndim == 3:
            return np.einsum("rct,tyx->ryxc", coefficients, basis)
        return np.einsum("rt,tyx->ryx", coefficients, basis)

    def divide(
        self, data: xr.DataArray, rows: np.ndarray, origin: tuple[int, int] = (0, 0)
    ) -> xr.DataArray:
        """``data / F``: ``data`` (lead, y, x[, channel]) with ``rows[k]`` the map of its
        ``k``-th leading entry; block by block on a lazy array (each block's maps made
        from the coefficients), at once on a loaded one. ``origin``: the frame pixel of
        ``data``'s first (a region of the frame). The dtype is kept.

        Raises
        ------
        CalibrationError
            Frames of another size than the maps were fitted on.
        """
        size = (data.sizes["y"], data.sizes["x"])
        frame = tuple(int(v) for v in self.frame)
        if (origin == (0, 0) and size != frame) or any(
            o + n > f for o, n, f in zip(origin, size, frame, strict=True)
        ):
            raise CalibrationError(
                f"flat field: frames of {size} px (from pixel {origin}), but the white "
                f"reference's were {frame} px"
            )
        rows = np.asarray(rows, dtype=int)
        oy, ox = origin
        if data.chunks is None:
            values = np.asarray(data.values)
            maps = self.maps(rows, slice(oy, oy + size[0]), slice(ox, ox + size[1]))
            return data.copy(data=(values / maps).astype(values.dtype))

        def block(values: np.ndarray, block_info=None) -> np.ndarray:
            (l0, l1), (y0, y1), (x0, x1) = block_info[0]["array-location"][:3]
            maps = self.maps(rows[l0:l1], slice(oy + y0, oy + y1), slice(ox + x0, ox + x1))
            if maps.ndim == 4:
                c0, c1 = block_info[0]["array-location"][3]
                maps = maps[..., c0:c1]
            return (values / maps).astype(values.dtype)

        return data.copy(data=da.map_blocks(block, data.data, dtype=data.dtype))

    def select(self, keys: list, lender_of: dict | None = None) -> FlatField:
        """The maps of cameras ``keys``, in that order: a camera without white-reference
        frames of its own takes its lender's map (``lender_of``: a camera of the same model,
        whose lens it shares), else none (a map of ones)."""
        known = np.asarray(self.keys).tolist()
        ones = np.zeros(self.coefficients.shape[1:])
        ones[..., 0] = 1.0  # P_0 P_0 = 1
        rows = []
        for key in keys:
            key = key if key in known else (lender_of or {}).get(key, key)
            rows.append(self.coefficients[known.index(key)] if key in known else ones)
        return FlatField(np.stack(rows), self.powers, self.frame, np.asarray(keys))

    def only(self, key: int) -> FlatField:
        """The map of camera ``key`` alone (:meth:`select`), for every image of a series."""
        return self.select([key])


def from_calibration(spectral: xr.Dataset, which: str) -> FlatField | None:
    """The :class:`FlatField` of ``which`` (``"rgb"``: per camera; ``"spectral"``: per band)
    stored in ``calibration/spectral``; None where the group has none."""
    name = "flat_field_rgb" if which == "rgb" else "flat_field"
    if name not in spectral.data_vars:
        return None
    data = spectral[name].load()
    powers = np.stack(
        [np.asarray(spectral["flat_power_y"].values), np.asarray(spectral["flat_power_x"].values)],
        axis=1,
    ).astype(int)
    keys = data["camera" if which == "rgb" else "wavelength"].values
    frame = tuple(int(v) for v in spectral.attrs["flat_field_frame"])
    return FlatField(np.asarray(data.values, dtype=np.float64), powers, frame, np.asarray(keys))  # type: ignore[arg-type]
