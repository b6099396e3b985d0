"""Response algebra: a camera response as an xarray table, and what is done with it.

Vocabulary (paper eq. 5): a pixel value is ``I = floor(f^-1(x t Q) + Delta_ADC + N_sigma)``,
clamped to the bit depth. ``f^-1`` is the OECF; its inverse ``f`` is the camera *response*:
it maps a pixel value (code, DN) to the relative exposure ``x t`` that produced it. A
response is an :class:`xarray.DataArray` named ``response`` over a ``code`` dim (the pixel
value in DN: raw integer codes, or fractional DN above dark when ``attrs["dark_subtracted"]``)
whose values are relative exposures (units ``"1"``), with a ``samples`` coord (samples per
code, 0 where interpolated).

- :func:`apply_response`: linearise pixel values, ``f(I)`` (lazy, any dims);
- :func:`response_at_codes`: the table at other codes;
- :func:`combine_responses`: join a low-SNR response to a full-range one.

Between tabulated codes the response is linear; beyond them it is extrapolated linearly with
the end slopes, so negative dark-subtracted values stay negative instead of being clipped
(clipping biases averages, paper Fig. 2).

References
----------
.. [1] Fast Capture of Spectral Image Series, section 4, eq. 5 and Fig. 2.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping

import numpy as np
import xarray as xr

from spectralize.schemas import CalibrationError, SchemaError
from spectralize.schemas.errors import Problem

__all__ = ["apply_response", "response_at_codes", "combine_responses", "response_dataarray", "lookup"]


def lookup(values: np.ndarray, table: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """Piecewise-linear ``table(values)`` on the increasing grid ``codes``; extrapolates.

    ``table`` has the grid on its last axis and broadcasts against ``values[..., None]``.
    """
    values = np.asarray(values, dtype=np.float64)
    table = np.asarray(table, dtype=np.float64)
    n = codes.size
    nd = max(values.ndim, table.ndim - 1)
    values = values.reshape((1,) * (nd - values.ndim) + values.shape)
    table = table.reshape((1,) * (nd + 1 - table.ndim) + table.shape)
    i = np.clip(np.searchsorted(codes, values, side="right"), 1, n - 1)
    c0 = codes[i - 1]
    frac = (values - c0) / (codes[i] - c0)
    f0 = np.take_along_axis(table, (i - 1)[..., None], axis=-1)[..., 0]
    f1 = np.take_along_axis(table, i[..., None], axis=-1)[..., 0]
    return f0 + frac * (f1 - f0)


def response_dataarray(
    values: np.ndarray,
    samples: np.ndarray,
    dims: tuple[str, ...],
    coords: Mapping[Hashable, object],
    code: np.ndarray,
    attrs: dict[str, object],
) -> xr.DataArray:
    """The response table ``values`` over ``code`` as the ``response`` DataArray."""
    code_coord = xr.DataArray(code, dims=("code",), attrs={"units": "DN", "long_name": "pixel value"})
    out = xr.DataArray(
        values.astype(np.float64),
        dims=dims + ("code",),
        coords={
            **coords,
            "code": code_coord,
            "samples": (
                dims + ("code",),
                samples.astype(np.int64),
                {"long_name": "samples per code (0: interpolated)"},
            ),
        },
        name="response",
        attrs={
            "units": "1",
            "long_name": "camera response f: relative exposure x t per pixel value",
            **attrs,
        },
    )
    return out


def _as_response(response: xr.Dataset | xr.DataArray) -> xr.DataArray:
    """The ``response`` table of a Dataset or DataArray, checked: increasing codes, finite."""
    if isinstance(response, xr.Dataset):
        if "response" not in response.data_vars:
            raise SchemaError(
                "cannot use the response:",
                [
                    Problem(
                        "response",
                        "a data variable 'response'",
                        f"variables {sorted(map(str, response.data_vars))}",
                    )
                ],
            )
        response = response["response"]
    if "code" not in response.dims:
        raise SchemaError(
            "cannot use the response:", [Problem("response", "a 'code' dim", f"dims {response.dims}")]
        )
    code = np.asarray(response["code"].values, dtype=np.float64)
    if code.size < 2 or np.any(np.diff(code) <= 0):
        raise CalibrationError("response: its code coordinate must be strictly increasing")
    if not np.all(np.isfinite(response.values)):
        raise CalibrationError("response: contains NaN or inf values")
    return response


def apply_response(values: xr.DataArray, response: xr.Dataset | xr.DataArray) -> xr.DataArray:
    """Linearise pixel values: relative exposure ``f(values)`` by the response table.

    Parameters
    ----------
    values
        Pixel values [DN]: raw codes for a response over raw codes, dark-subtracted values
        for a low-SNR response (``attrs["dark_subtracted"]``). Any dims; dims the response
        has besides ``code`` (``channel``, ``camera``) are matched by name. Dask-backed input
        stays lazy.
    response
        A response from :func:`~.recover_oecf`, :func:`~.recover_oecf_low_snr` or
        :func:`combine_responses`.

    Returns
    -------
    xarray.DataArray
        float64 relative exposure, dims of ``values`` (plus any response dims it lacked).

    Notes
    -----
    Linear interpolation between tabulated codes; linear extrapolation with the end slopes
    beyond them, so noise-negative dark-subtracted values map to negative exposures instead
    of being clipped (clipping biases averages, paper Fig. 2).

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 5 (``f`` inverts the OECF) and Fig. 2.
    """
    table = _as_response(response)
    grid = np.asarray(table["code"].values, dtype=np.float64)
    table = table.drop_vars([c for c in table.coords if c not in table.dims or c == "code"])
    out = xr.apply_ufunc(
        lookup,
        values,
        table,
        kwargs={"codes": grid},
        input_core_dims=[[], ["code"]],
        output_core_dims=[[]],
        dask="parallelized",
        output_dtypes=[np.float64],
    )
    return out.assign_attrs(units="1", long_name="relative exposure (linearised pixel value)")


def response_at_codes(response: xr.Dataset | xr.DataArray, codes: np.ndarray) -> xr.DataArray:
    """Evaluate a response table at other codes (e.g. integer codes for an HDR merge).

    Parameters
    ----------
    response
        A response table (see :func:`apply_response`).
    codes
        The pixel values [DN] to evaluate it at, 1-D.

    Returns
    -------
    xarray.DataArray
        ``response`` with the same dims, ``code`` replaced by ``codes``; linear between
        tabulated codes, linearly extrapolated beyond them.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, eq. 5.
    """
    table = _as_response(response)
    grid = np.asarray(table["code"].values, dtype=np.float64)
    stacked = table.transpose(..., "code")
    result = lookup(np.asarray(codes, dtype=np.float64), np.asarray(stacked.values)[..., None, :], grid)
    dims = stacked.dims
    coords = {k: v for k, v in stacked.coords.items() if k != "code" and "code" not in v.dims}
    coords["code"] = ("code", np.asarray(codes), table["code"].attrs)
    return xr.DataArray(result, dims=dims, coords=coords, name="response", attrs=dict(table.attrs))


def combine_responses(
    low_snr: xr.Dataset | xr.DataArray,
    full: xr.Dataset | xr.DataArray,
    *,
    dark_level: float | None = None,
    overlap: tuple[float, float] | None = None,
) -> xr.Dataset:
    """Join a low-SNR response (dark-subtracted values) to a full-range Robertson response.

    Parameters
    ----------
    low_snr
        From :func:`~.recover_oecf_low_snr` (monochrome, ``code`` = DN above dark).
    full
        From :func:`~.recover_oecf` on the same camera (monochrome, ``code`` = raw DN).
    dark_level
        Raw value of zero signal [DN], ``code_raw = code_dark_subtracted + dark_level``;
        default ``low_snr.attrs["dark_level"]`` (the mean dark frame).
    overlap
        Interval of dark-subtracted values [DN] where both are trusted; the low-SNR response
        is scaled onto the full one by least squares there and the two are cross-faded
        linearly across it. Default: 50% .. 90% of the low-SNR interval.

    Returns
    -------
    xarray.Dataset
        ``response`` (code) over dark-subtracted values [DN]: the low-SNR grid below the end
        of ``overlap``, the full response's codes (shifted by ``-dark_level``) above;
        normalised like ``full``. Attrs of ``full`` plus ``method="combined"``,
        ``dark_subtracted=True``, ``dark_level``, ``overlap``, ``scale``.

    Raises
    ------
    CalibrationError
        When the overlap holds no code of the full response, or the responses have extra dims.

    Notes
    -----
    ``scale = <g, f_full> / <g, g>`` over the full response's codes inside ``overlap``, ``g``
    the low-SNR response interpolated there; then
    ``f = (1 - alpha) scale f_low + alpha f_full`` with ``alpha`` rising linearly from 0 to 1
    across ``overlap``.

    References
    ----------
    .. [1] Fast Capture of Spectral Image Series, section 4 (the low-SNR extension covers
       the bottom of the range, Robertson's recovery the rest).
    """
    low = _as_response(low_snr)
    high = _as_response(full)
    if low.ndim != 1 or high.ndim != 1:
        raise CalibrationError("combine_responses: both responses must be monochrome (code,)")
    if dark_level is None:
        if "dark_level" not in low.attrs:
            raise CalibrationError("combine_responses: give dark_level (raw DN of zero signal)")
        dark_level = float(low.attrs["dark_level"])
    v_low = np.asarray(low["code"].values, dtype=np.float64)
    f_low = np.asarray(low.values, dtype=np.float64)
    v_high = np.asarray(high["code"].values, dtype=np.float64) - dark_level
    f_high = np.asarray(high.values, dtype=np.float64)
    if overlap is None:
        span = v_low[-1] - v_low[0]
        overlap = (v_low[0] + 0.5 * span, v_low[0] + 0.9 * span)
    a, b = float(overlap[0]), float(overlap[1])
    inside = (v_high >= a) & (v_high <= b)
    if not b > a or inside.sum() < 2:
        raise CalibrationError(
            f"combine_responses: overlap {overlap} DN holds {int(inside.sum())} codes of the "
            "full response; it needs at least 2. Record the low-SNR series up to higher values"
        )
    g = np.interp(v_high[inside], v_low, f_low)
    scale = float(np.dot(g, f_high[inside]) / np.dot(g, g))
    grid = np.concatenate([v_low[v_low <= b], v_high[v_high > b]])
    f_l = lookup(grid, f_low * scale, v_low)
    f_h = lookup(grid, f_high, v_high)
    alpha = np.clip((grid - a) / (b - a), 0.0, 1.0)
    values = (1 - alpha) * f_l + alpha * f_h
    attrs = {
        **high.attrs,
        "method": "combined",
        "dark_subtracted": True,
        "dark_level": float(dark_level),
        "overlap": [a, b],
        "scale": scale,
        "low_snr_method": low.attrs.get("method", ""),
        "converged": bool(low.attrs.get("converged", True)) and bool(high.attrs.get("converged", True)),
    }
    samples = np.concatenate([low["samples"].values[v_low <= b], high["samples"].values[v_high > b]])
    response = response_dataarray(values, samples, (), {}, grid, attrs)
    response["code"].attrs.update(long_name="dark-subtracted pixel value")
    return xr.Dataset({"response": response})
