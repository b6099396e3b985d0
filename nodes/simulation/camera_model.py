"""Camera model of the capture simulation (paper eq. 5).

A pixel value is generated from an incident irradiance ``x`` and an exposure time ``t``
by the camera mapping ``g`` of eq. 5::

    I = g(x, t) = floor(f^-1(x * t * Q) + Delta_ADC + N_sigma),

clamped to the valid range ``[0, 2**bit_depth - 1]``.  ``f^-1`` is the OECF (normalised
exposure -> code), ``Delta_ADC`` the ADC offset, ``N_sigma`` Gaussian noise with standard
deviation ``sigma`` (the paper's model) or, as an option, photon shot noise plus Gaussian
read noise.

The module holds

- a family of true response models (:data:`RESPONSE_MODELS`): linear, gamma, log-like and
  S-curve, each mapping normalised exposure to normalised signal (:meth:`oecf`) and back
  (:meth:`response`, the paper's ``f``);
- :func:`capture`, eq. 5 on numpy arrays or xarray DataArrays, seeded and deterministic;
- :class:`RGBCamera` (spectral sensitivities ``C`` (channel, wavelength), several exposures
  per image) and :class:`SpectralCamera` (monochrome camera behind a tunable filter with a
  quantum efficiency per band and a ~10 nm bandpass);
- the error classes and input checks shared by the simulation modules.

Conventions
-----------
Exposure ``x * t * Q`` is normalised: 1 is the exposure at which the noiseless, offset-free
signal reaches full scale ``2**bit_depth - 1``.  The units of ``x`` (relative radiance, "1")
and ``Q`` (per second per unit radiance, "s-1") are chosen so that this holds.

References
----------
Fast Capture of Spectral Image Series, sec. 4 (calibration) and sec. 5, eq. 5
(``/work/shared/paper/fast-capture-of-spectral-image-series.md``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar, Literal, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt
import xarray as xr

from spectralize.schemas.errors import SimulationError

__all__ = [
    "RESPONSE_MODELS",
    "CameraModelError",
    "SimulationParameterError",
    "ShapeMismatchError",
    "ResponseModel",
    "LinearResponse",
    "GammaResponse",
    "LogResponse",
    "SCurveResponse",
    "response_model",
    "oecf_table",
    "noiseless_signal",
    "capture",
    "capture_with_generator",
    "RGBCamera",
    "SpectralCamera",
    "camera_sensitivities",
    "spectral_quantum_efficiency",
    "gaussian_bandpass",
]

NoiseModel = Literal["gaussian", "shot"]
SeedLike = int | np.random.SeedSequence | np.random.Generator | None

#: Inclusive range of supported bit depths.
BIT_DEPTH_RANGE: tuple[int, int] = (8, 16)


# --------------------------------------------------------------------------------------
# errors and checks (shared by exposure_plan, ground_truth and gantry)
# --------------------------------------------------------------------------------------
class CameraModelError(SimulationError):
    """Base class of the capture simulation's errors.

    A :class:`~spectralize.schemas.SimulationError` (so a
    :class:`~spectralize.schemas.SpectralizeError` and a :class:`ValueError`).
    """


class SimulationParameterError(CameraModelError):
    """A parameter of the simulation is out of its domain; the message names it."""


class ShapeMismatchError(CameraModelError):
    """Arrays that must share a shape or a coordinate do not."""


def check_positive(value: npt.ArrayLike, name: str, *, allow_zero: bool = False) -> np.ndarray:
    """Return ``value`` as a float array after checking it is finite and positive.

    Raises
    ------
    SimulationParameterError
        Naming ``name`` when a value is not finite or not positive.
    """
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise SimulationParameterError(
            f"{name} must be finite; received {_describe(arr)} containing NaN or inf."
        )
    bad = arr < 0 if allow_zero else arr <= 0
    if np.any(bad):
        relation = ">= 0" if allow_zero else "> 0"
        raise SimulationParameterError(
            f"{name} must be {relation}; received {_describe(arr)} with "
            f"{int(np.count_nonzero(bad))} value(s) violating it "
            f"(smallest {float(np.min(arr)):g})."
        )
    return arr


def check_bit_depth(bit_depth: int) -> int:
    """Check ``bit_depth`` is an integer in :data:`BIT_DEPTH_RANGE` and return it."""
    lo, hi = BIT_DEPTH_RANGE
    if isinstance(bit_depth, bool) or not isinstance(bit_depth, int | np.integer):
        raise SimulationParameterError(
            f"bit_depth must be an integer in {lo}..{hi}; received {bit_depth!r} "
            f"of type {type(bit_depth).__name__}."
        )
    if not lo <= int(bit_depth) <= hi:
        raise SimulationParameterError(
            f"bit_depth must be in {lo}..{hi} (uint16 counts); received {bit_depth}."
        )
    return int(bit_depth)


def check_wavelength(wavelength: npt.ArrayLike, name: str = "wavelength") -> np.ndarray:
    """Check a wavelength axis [nm] is 1-D, finite, positive and strictly increasing."""
    wl = np.asarray(wavelength, dtype=np.float64)
    if wl.ndim != 1 or wl.size == 0:
        raise ShapeMismatchError(
            f"{name} must be a non-empty 1-D array of wavelengths in nm; received shape {wl.shape}."
        )
    if not np.all(np.isfinite(wl)) or np.any(wl <= 0):
        raise SimulationParameterError(f"{name} must be finite and > 0 nm; received {wl}.")
    if wl.size > 1 and np.any(np.diff(wl) <= 0):
        i = int(np.argmax(np.diff(wl) <= 0))
        raise SimulationParameterError(
            f"{name} must be strictly increasing; received {wl[i]:g} nm followed by "
            f"{wl[i + 1]:g} nm at index {i}. Sort it (e.g. `da.sortby('wavelength')`)."
        )
    return wl


def as_generator(seed: SeedLike) -> np.random.Generator:
    """Return a numpy Generator for an int, a SeedSequence, a Generator or None (seed 0)."""
    if isinstance(seed, np.random.Generator):
        return seed
    if seed is None:
        seed = 0
    if isinstance(seed, np.random.SeedSequence):
        return np.random.Generator(np.random.PCG64(seed))
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise SimulationParameterError(
            f"seed must be a non-negative int, a numpy SeedSequence or Generator; received {seed!r}."
        )
    return np.random.default_rng(int(seed))


def _describe(arr: np.ndarray) -> str:
    return f"an array of shape {arr.shape}" if arr.ndim else f"{float(arr)!r}"


# --------------------------------------------------------------------------------------
# response models (true OECFs)
# --------------------------------------------------------------------------------------
@runtime_checkable
class ResponseModel(Protocol):
    """A true camera response: normalised exposure <-> normalised signal.

    ``oecf`` is the paper's ``f^-1`` (exposure -> signal), ``response`` its inverse ``f``.
    Both are monotone increasing on [0, 1], map 0 to 0 and 1 to 1; exposures above 1
    saturate at signal 1.
    """

    name: ClassVar[str]

    def oecf(self, exposure: npt.ArrayLike) -> np.ndarray: ...

    def response(self, signal: npt.ArrayLike) -> np.ndarray: ...

    def parameters(self) -> dict[str, float]: ...


def _clip01(a: npt.ArrayLike) -> np.ndarray:
    return np.clip(np.asarray(a, dtype=np.float64), 0.0, 1.0)


@dataclass(frozen=True)
class LinearResponse:
    """Linear response, ``v = e`` (an ideal CCD)."""

    name: ClassVar[str] = "linear"

    def oecf(self, exposure: npt.ArrayLike) -> np.ndarray:
        return _clip01(exposure)

    def response(self, signal: npt.ArrayLike) -> np.ndarray:
        return _clip01(signal)

    def parameters(self) -> dict[str, float]:
        return {}


@dataclass(frozen=True)
class GammaResponse:
    """Power-law response ``v = e ** (1 / gamma)``."""

    gamma: float = 2.2
    name: ClassVar[str] = "gamma"

    def __post_init__(self) -> None:
        check_positive(self.gamma, "gamma")

    def oecf(self, exposure: npt.ArrayLike) -> np.ndarray:
        return _clip01(exposure) ** (1.0 / self.gamma)

    def response(self, signal: npt.ArrayLike) -> np.ndarray:
        return _clip01(signal) ** self.gamma

    def parameters(self) -> dict[str, float]:
        return {"gamma": float(self.gamma)}


@dataclass(frozen=True)
class LogResponse:
    """Log-like response ``v = log(1 + a e) / log(1 + a)`` (near linear for small ``a``)."""

    a: float = 10.0
    name: ClassVar[str] = "log"

    def __post_init__(self) -> None:
        check_positive(self.a, "a")

    def oecf(self, exposure: npt.ArrayLike) -> np.ndarray:
        return np.log1p(self.a * _clip01(exposure)) / math.log1p(self.a)

    def response(self, signal: npt.ArrayLike) -> np.ndarray:
        return np.expm1(_clip01(signal) * math.log1p(self.a)) / self.a

    def parameters(self) -> dict[str, float]:
        return {"a": float(self.a)}


@dataclass(frozen=True)
class SCurveResponse:
    """Film-like S-curve ``v = (tanh(k (e - c)) + tanh(k c)) / (tanh(k (1 - c)) + tanh(k c))``.

    ``contrast`` is ``k``, ``midpoint`` is ``c``; toe below ``c``, shoulder above it.
    """

    contrast: float = 4.0
    midpoint: float = 0.35
    name: ClassVar[str] = "s_curve"

    def __post_init__(self) -> None:
        check_positive(self.contrast, "contrast")
        if not 0.0 < self.midpoint < 1.0:
            raise SimulationParameterError(f"midpoint must be in (0, 1); received {self.midpoint!r}.")

    @property
    def _t0(self) -> float:
        return math.tanh(self.contrast * self.midpoint)

    @property
    def _t1(self) -> float:
        return math.tanh(self.contrast * (1.0 - self.midpoint))

    def oecf(self, exposure: npt.ArrayLike) -> np.ndarray:
        e = _clip01(exposure)
        return (np.tanh(self.contrast * (e - self.midpoint)) + self._t0) / (self._t0 + self._t1)

    def response(self, signal: npt.ArrayLike) -> np.ndarray:
        v = _clip01(signal)
        arg = np.clip(v * (self._t0 + self._t1) - self._t0, -1.0, 1.0)
        return _clip01(self.midpoint + np.arctanh(arg) / self.contrast)

    def parameters(self) -> dict[str, float]:
        return {"contrast": float(self.contrast), "midpoint": float(self.midpoint)}


#: Dispatch table of the response model family (name -> class).
RESPONSE_MODELS: Mapping[str, type] = {
    LinearResponse.name: LinearResponse,
    GammaResponse.name: GammaResponse,
    LogResponse.name: LogResponse,
    SCurveResponse.name: SCurveResponse,
}


def response_model(name: str, **parameters: float) -> ResponseModel:
    """Build a response model by name from :data:`RESPONSE_MODELS`.

    Examples
    --------
    >>> response_model("gamma", gamma=1.8).oecf(0.25).round(3)
    np.float64(0.463)
    """
    try:
        cls = RESPONSE_MODELS[name]
    except KeyError:
        raise SimulationParameterError(
            f"response model {name!r} is unknown; known models: {sorted(RESPONSE_MODELS)}."
        ) from None
    try:
        return cls(**parameters)
    except TypeError as exc:
        raise SimulationParameterError(
            f"response model {name!r} does not take parameters {sorted(parameters)}: {exc}"
        ) from None


def full_scale(bit_depth: int) -> int:
    """Largest code of an unsigned ``bit_depth``-bit camera, ``2**bit_depth - 1``."""
    return (1 << check_bit_depth(bit_depth)) - 1


def oecf_table(response: ResponseModel, *, bit_depth: int = 10) -> np.ndarray:
    """Tabulate the true response ``f`` per code: the exposure yielding each code.

    Returns an array of length ``2**bit_depth`` whose entry ``m`` is the normalised exposure
    ``x t Q`` for which the noiseless, offset-free output ``f^-1(x t Q)`` equals ``m``.
    This is what Robertson's algorithm recovers (its ``I_m``), up to scale.
    """
    n = full_scale(bit_depth)
    return response.response(np.arange(n + 1, dtype=np.float64) / n)


# --------------------------------------------------------------------------------------
# eq. 5
# --------------------------------------------------------------------------------------
def noiseless_signal(
    irradiance: npt.ArrayLike,
    exposure_time: npt.ArrayLike,
    *,
    response: ResponseModel,
    quantum_efficiency: npt.ArrayLike = 1.0,
    adc_offset: npt.ArrayLike = 0.0,
    bit_depth: int = 10,
) -> np.ndarray:
    """The continuous, noiseless argument of the floor in eq. 5: ``f^-1(x t Q) + Delta_ADC``.

    With Gaussian noise of ``sigma`` >~ 0.5 DN and no clamping, the mean of many frames of
    :func:`capture` converges to this value minus 1/2 (the floor's bias).
    """
    x = np.asarray(irradiance, dtype=np.float64)
    t = np.asarray(exposure_time, dtype=np.float64)
    q = np.asarray(quantum_efficiency, dtype=np.float64)
    return response.oecf(x * t * q) * full_scale(bit_depth) + np.asarray(adc_offset, np.float64)


def capture_with_generator(
    irradiance: np.ndarray,
    exposure_time: npt.ArrayLike,
    rng: np.random.Generator,
    *,
    response: ResponseModel,
    quantum_efficiency: npt.ArrayLike = 1.0,
    adc_offset: npt.ArrayLike = 0.0,
    noise_sigma: float = 0.0,
    bit_depth: int = 10,
    noise: NoiseModel = "gaussian",
    full_well: float = 20000.0,
) -> np.ndarray:
    """Eq. 5 without input checks (the fast path used by the generators); uint16 counts.

    Draws noise from ``rng`` in a fixed order (shot noise first, then Gaussian), so a
    Generator seeded the same way gives the same frame.
    """
    n = (1 << bit_depth) - 1
    e = irradiance * (np.asarray(exposure_time) * np.asarray(quantum_efficiency))
    e = np.broadcast_to(e, np.broadcast_shapes(np.shape(e), np.shape(adc_offset)))
    if noise == "shot":
        electrons = rng.poisson(np.clip(e, 0.0, 2.0) * full_well)
        e = electrons / full_well
    value = response.oecf(e) * n + adc_offset
    if noise_sigma > 0:
        value = value + rng.normal(0.0, noise_sigma, size=value.shape)
    return np.clip(np.floor(value), 0, n).astype(np.uint16)


def capture(
    irradiance: npt.ArrayLike | xr.DataArray,
    exposure_time: npt.ArrayLike,
    *,
    response: ResponseModel | None = None,
    quantum_efficiency: npt.ArrayLike = 1.0,
    adc_offset: npt.ArrayLike = 0.0,
    noise_sigma: float = 0.0,
    bit_depth: int = 10,
    noise: NoiseModel = "gaussian",
    full_well: float = 20000.0,
    seed: SeedLike = None,
) -> np.ndarray | xr.DataArray:
    """Simulate camera counts from irradiance and exposure time (paper eq. 5).

    ``I = clip(floor(f^-1(x t Q) + Delta_ADC + N_sigma), 0, 2**bit_depth - 1)``.

    Parameters
    ----------
    irradiance
        ``x``: incident irradiance in relative units, any shape, finite and >= 0.
        A DataArray gives a DataArray with the same dims and coords (a dask-backed one is
        computed: for lazy, chunk-independent frames use :mod:`spectralize.nodes.simulation.rendering`).
    exposure_time
        ``t`` [s], > 0; broadcast against ``irradiance``.
    response
        True response model; its ``oecf`` is ``f^-1``. Default :class:`LinearResponse`.
    quantum_efficiency
        ``Q`` [s-1 per unit irradiance], > 0; broadcast against ``irradiance``.
    adc_offset
        ``Delta_ADC`` [DN], >= 0; scalar or an array broadcastable to ``irradiance``
        (a fixed-pattern offset, possibly including dark current times ``t``).
    noise_sigma
        ``sigma`` of the Gaussian noise ``N_sigma`` [DN], >= 0.
    bit_depth
        Bits of the ADC, 8..16; counts are clamped to ``[0, 2**bit_depth - 1]``.
    noise
        ``"gaussian"`` (the paper's model) or ``"shot"``: Poisson photon noise on
        ``full_well * x t Q`` electrons before the OECF, plus the Gaussian ``N_sigma``.
    full_well
        Electrons at normalised exposure 1 (only for ``noise="shot"``).
    seed
        int, SeedSequence or Generator; the same seed gives the same frame.

    Returns
    -------
    numpy.ndarray or xarray.DataArray
        uint16 counts [DN], shape of ``irradiance`` broadcast with the other inputs.

    Notes
    -----
    Domain: normalised exposure ``x t Q`` in [0, 1] maps to [0, full scale]; larger
    exposures saturate. With Gaussian noise, ``E[I] = f^-1(x t Q) + Delta_ADC - 1/2``
    for ``sigma`` >~ 0.5 DN away from the clamps (see :func:`noiseless_signal`).

    References
    ----------
    Fast Capture of Spectral Image Series, sec. 5, eq. 5.

    Examples
    --------
    >>> capture(np.full(3, 0.5), 1.0, adc_offset=10, bit_depth=8, seed=1)
    array([137, 137, 137], dtype=uint16)
    """
    response = LinearResponse() if response is None else response
    if not isinstance(response, ResponseModel):
        raise SimulationParameterError(
            f"response must be a response model (see RESPONSE_MODELS); received {response!r}."
        )
    bit_depth = check_bit_depth(bit_depth)
    is_da = isinstance(irradiance, xr.DataArray)
    x = check_positive(irradiance.values if is_da else irradiance, "irradiance", allow_zero=True)
    t = check_positive(exposure_time, "exposure_time")
    q = check_positive(quantum_efficiency, "quantum_efficiency")
    off = check_positive(adc_offset, "adc_offset", allow_zero=True)
    check_positive(noise_sigma, "noise_sigma", allow_zero=True)
    check_positive(full_well, "full_well")
    if noise not in ("gaussian", "shot"):
        raise SimulationParameterError(f"noise must be 'gaussian' or 'shot'; received {noise!r}.")
    try:
        shape = np.broadcast_shapes(x.shape, t.shape, q.shape, off.shape)
    except ValueError:
        raise ShapeMismatchError(
            "irradiance, exposure_time, quantum_efficiency and adc_offset must broadcast "
            f"together; received shapes {x.shape}, {t.shape}, {q.shape} and {off.shape}."
        ) from None
    if is_da and shape != x.shape:
        raise ShapeMismatchError(
            f"with a DataArray irradiance of shape {x.shape} the other inputs may not add "
            f"dimensions; they broadcast to {shape}. Use xarray broadcasting first."
        )
    counts = capture_with_generator(
        np.broadcast_to(x, shape),
        t,
        as_generator(seed),
        response=response,
        quantum_efficiency=q,
        adc_offset=off,
        noise_sigma=float(noise_sigma),
        bit_depth=bit_depth,
        noise=noise,
        full_well=float(full_well),
    )
    if not is_da:
        return counts
    return xr.DataArray(
        counts,
        dims=irradiance.dims,
        coords=irradiance.coords,
        name="counts",
        attrs={"units": "DN", "long_name": "raw camera counts", "bit_depth": bit_depth},
    )


# --------------------------------------------------------------------------------------
# spectral data of the cameras
# --------------------------------------------------------------------------------------
def camera_sensitivities(wavelength: npt.ArrayLike, *, name: str = "Nikon 5100 (NPL)") -> xr.DataArray:
    """Measured RGB camera sensitivities shipped by colour-science, sampled at ``wavelength``.

    Returns a DataArray (channel, wavelength), channel ``['R', 'G', 'B']``, normalised so the
    largest value is 1 (relative).
    """
    import colour

    wl = check_wavelength(wavelength)
    try:
        msds = colour.MSDS_CAMERA_SENSITIVITIES[name]
    except KeyError:
        raise SimulationParameterError(
            f"camera sensitivities {name!r} are not shipped by colour-science; known: "
            f"{sorted(colour.MSDS_CAMERA_SENSITIVITIES)}."
        ) from None
    lo, hi = msds.shape.start, msds.shape.end
    if wl[0] < lo or wl[-1] > hi:
        raise SimulationParameterError(
            f"wavelength must lie in {lo:g}..{hi:g} nm for {name!r}; received {wl[0]:g}..{wl[-1]:g} nm."
        )
    values = np.clip(np.asarray(msds[wl], dtype=np.float64).T, 0.0, None)
    values = values / values.max()
    return xr.DataArray(
        values,
        dims=("channel", "wavelength"),
        coords={"channel": ["R", "G", "B"], "wavelength": _wavelength_coord(wl)},
        name="camera_sensitivities",
        attrs={
            "units": "1",
            "long_name": f"relative spectral sensitivity ({name})",
            "source": f"colour.MSDS_CAMERA_SENSITIVITIES[{name!r}]",
        },
    )


def spectral_quantum_efficiency(wavelength: npt.ArrayLike, *, peak: float = 1.0) -> xr.DataArray:
    """Combined quantum efficiency ``Q`` of a monochrome CCD behind a liquid-crystal filter.

    Smooth model of an interline CCD's QE (peak ~0.55 near 490 nm) times the peak
    transmission of a visible LCTF (~7 % at 410 nm rising to ~57 % at 720 nm), as in the
    paper's Figure 3 in shape: blue and red bands are weak. Scaled so the maximum is
    ``peak`` [s-1 per unit radiance].
    """
    wl = check_wavelength(wavelength)
    check_positive(peak, "peak")
    sensor = 0.55 * np.exp(-0.5 * ((wl - 490.0) / 150.0) ** 2)
    lctf = 0.02 + 0.55 / (1.0 + np.exp(-(wl - 500.0) / 40.0))
    q = sensor * lctf
    return xr.DataArray(
        q / q.max() * peak,
        dims=("wavelength",),
        coords={"wavelength": _wavelength_coord(wl)},
        name="quantum_efficiency",
        attrs={
            "units": "s-1",
            "long_name": "quantum efficiency Q of the spectral camera "
            "system (sensor x tunable filter x gain)",
        },
    )


def gaussian_bandpass(wavelength: npt.ArrayLike, *, fwhm: float = 10.0) -> xr.DataArray:
    """Bandpass matrix (band, wavelength) of a tunable filter with Gaussian passbands.

    Rows are centred at each ``wavelength`` and sum to 1; ``fwhm = 0`` gives the identity
    (ideal band sampling as in the paper's simulation).
    """
    wl = check_wavelength(wavelength)
    check_positive(fwhm, "fwhm", allow_zero=True)
    if fwhm == 0:
        m = np.eye(wl.size)
    else:
        s = fwhm / (2.0 * math.sqrt(2.0 * math.log(2.0)))
        m = np.exp(-0.5 * ((wl[None, :] - wl[:, None]) / s) ** 2)
        m /= m.sum(axis=1, keepdims=True)
    return xr.DataArray(
        m,
        dims=("band", "wavelength"),
        coords={"band": _wavelength_coord(wl, "band"), "wavelength": _wavelength_coord(wl)},
        name="bandpass",
        attrs={
            "units": "1",
            "long_name": "tunable filter bandpass weights per band",
            "fwhm_nm": float(fwhm),
        },
    )


def _wavelength_coord(wl: np.ndarray, dim: str = "wavelength") -> xr.Variable:
    return xr.Variable(
        (dim,),
        wl,
        attrs={
            "units": "nm",
            "long_name": "wavelength" if dim == "wavelength" else "centre wavelength of the filter band",
        },
    )


# --------------------------------------------------------------------------------------
# cameras
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RGBCamera:
    """RGB camera: spectral sensitivities ``C`` and one true response per channel.

    The channel irradiance is ``x_c = sum_lambda C[c, lambda] radiance[lambda]`` (``C``
    already contains the camera's gain and quantum efficiency, so ``Q = 1`` in eq. 5);
    counts follow eq. 5 per channel, with several exposure times per image.

    Parameters
    ----------
    camera_matrix
        ``C`` (channel, wavelength) [s-1 per unit radiance], channels ``R, G, B``.
    responses
        Mapping channel -> true response model (the OECFs).
    adc_offset, noise_sigma, bit_depth, noise, full_well
        As in :func:`capture`.
    """

    camera_matrix: xr.DataArray
    responses: Mapping[str, ResponseModel]
    adc_offset: float = 16.0
    noise_sigma: float = 1.0
    bit_depth: int = 10
    noise: NoiseModel = "gaussian"
    full_well: float = 20000.0
    channels: tuple[str, ...] = field(init=False, default=("R", "G", "B"))

    def __post_init__(self) -> None:
        c = self.camera_matrix
        if not isinstance(c, xr.DataArray) or c.dims != ("channel", "wavelength"):
            raise ShapeMismatchError(
                "camera_matrix must be a DataArray with dims ('channel', 'wavelength'); "
                f"received {getattr(c, 'dims', type(c).__name__)}."
            )
        check_wavelength(c["wavelength"].values, "camera_matrix.wavelength")
        check_positive(c.values, "camera_matrix", allow_zero=True)
        object.__setattr__(self, "channels", tuple(str(v) for v in c["channel"].values))
        missing = set(self.channels) - set(self.responses)
        if missing:
            raise SimulationParameterError(
                f"responses must give a model for every channel {self.channels}; "
                f"missing {sorted(missing)}."
            )
        check_bit_depth(self.bit_depth)
        check_positive(self.adc_offset, "adc_offset", allow_zero=True)
        check_positive(self.noise_sigma, "noise_sigma", allow_zero=True)

    def channel_irradiance(self, radiance: xr.DataArray) -> xr.DataArray:
        """``C S``: integrate a spectral radiance (..., wavelength, ...) to channels."""
        if "wavelength" not in radiance.dims:
            raise ShapeMismatchError(
                f"radiance must have a 'wavelength' dim; received dims {radiance.dims}."
            )
        wl_r = radiance["wavelength"].values
        wl_c = self.camera_matrix["wavelength"].values
        if wl_r.shape != wl_c.shape or not np.allclose(wl_r, wl_c):
            raise ShapeMismatchError(
                f"radiance wavelengths ({wl_r.size} from {wl_r[0]:g} nm) must equal the "
                f"camera_matrix wavelengths ({wl_c.size} from {wl_c[0]:g} nm); resample "
                "with `radiance.interp(wavelength=camera.camera_matrix.wavelength)`."
            )
        out = xr.dot(
            self.camera_matrix.drop_vars("wavelength"),
            radiance.drop_vars("wavelength"),
            dim="wavelength",
        )
        dims = [d for d in radiance.dims if d != "wavelength"] + ["channel"]
        return out.transpose(*dims)

    def capture(
        self,
        radiance: xr.DataArray,
        exposure_time: Sequence[float] | npt.ArrayLike,
        *,
        seed: SeedLike = None,
    ) -> xr.DataArray:
        """Exposure series of a spectral radiance: counts (..., exposure, y, x, channel).

        ``radiance`` must have dims (..., wavelength, y, x); uint16 counts are returned
        with an ``exposure_time`` coordinate over the new ``exposure`` dim.
        """
        times = check_positive(np.atleast_1d(exposure_time), "exposure_time")
        if times.ndim != 1:
            raise ShapeMismatchError(f"exposure_time must be 1-D; received shape {times.shape}.")
        x = self.channel_irradiance(radiance)  # (..., y, x, channel)
        rng = as_generator(seed)
        frames = []
        for t in times:
            per_channel = [
                capture_with_generator(
                    x.isel(channel=i).values,
                    t,
                    rng,
                    response=self.responses[ch],
                    adc_offset=self.adc_offset,
                    noise_sigma=self.noise_sigma,
                    bit_depth=self.bit_depth,
                    noise=self.noise,
                    full_well=self.full_well,
                )
                for i, ch in enumerate(self.channels)
            ]
            frames.append(np.stack(per_channel, axis=-1))
        counts = np.stack(frames, axis=-4)  # (..., exposure, y, x, channel)
        dims = list(x.dims[:-3]) + ["exposure", *x.dims[-3:]]
        coords = {k: v for k, v in x.coords.items() if set(v.dims) <= set(dims)}
        da = xr.DataArray(
            counts,
            dims=dims,
            coords=coords,
            name="counts",
            attrs={"units": "DN", "long_name": "raw RGB counts", "bit_depth": self.bit_depth},
        )
        return da.assign_coords(
            exposure_time=("exposure", times, {"units": "s", "long_name": "exposure time"})
        )


@dataclass(frozen=True)
class SpectralCamera:
    """Monochrome camera behind a tunable bandpass filter.

    The band irradiance of band ``i`` is ``x_i = sum_lambda B[i, lambda] radiance[lambda]``
    with the bandpass matrix ``B`` (:func:`gaussian_bandpass`); counts follow eq. 5 with
    the band's quantum efficiency ``Q_i``.

    Parameters
    ----------
    quantum_efficiency
        ``Q`` (wavelength) [s-1 per unit radiance], > 0, one value per filter band.
    response
        True response model (OECF) of the monochrome sensor.
    bandpass_fwhm
        Full width at half maximum of the filter passbands [nm]; 0 is ideal sampling.
    adc_offset, noise_sigma, bit_depth, noise, full_well
        As in :func:`capture`.
    """

    quantum_efficiency: xr.DataArray
    response: ResponseModel = field(default_factory=LinearResponse)
    bandpass_fwhm: float = 10.0
    adc_offset: float = 16.0
    noise_sigma: float = 3.0
    bit_depth: int = 10
    noise: NoiseModel = "gaussian"
    full_well: float = 20000.0

    def __post_init__(self) -> None:
        q = self.quantum_efficiency
        if not isinstance(q, xr.DataArray) or q.dims != ("wavelength",):
            raise ShapeMismatchError(
                "quantum_efficiency must be a DataArray with dims ('wavelength',); "
                f"received {getattr(q, 'dims', type(q).__name__)}."
            )
        check_wavelength(q["wavelength"].values, "quantum_efficiency.wavelength")
        check_positive(q.values, "quantum_efficiency")
        check_bit_depth(self.bit_depth)
        check_positive(self.adc_offset, "adc_offset", allow_zero=True)
        check_positive(self.noise_sigma, "noise_sigma", allow_zero=True)

    @property
    def wavelength(self) -> np.ndarray:
        return self.quantum_efficiency["wavelength"].values

    def bandpass(self) -> xr.DataArray:
        """Bandpass matrix ``B`` (band, wavelength)."""
        return gaussian_bandpass(self.wavelength, fwhm=self.bandpass_fwhm)

    def band_index(self, wavelength: float) -> int:
        """Index of the filter band centred at ``wavelength`` [nm]."""
        i = int(np.argmin(np.abs(self.wavelength - wavelength)))
        if not np.isclose(self.wavelength[i], wavelength):
            raise SimulationParameterError(
                f"wavelength {wavelength:g} nm is not a band of the spectral camera; "
                f"bands are {self.wavelength.min():g}..{self.wavelength.max():g} nm in "
                f"{self.wavelength.size} steps."
            )
        return i

    def band_irradiance(self, radiance: xr.DataArray, wavelength: float) -> xr.DataArray:
        """``x_i``: radiance (..., wavelength, ...) seen through band ``wavelength``."""
        i = self.band_index(wavelength)
        wl_r = radiance["wavelength"].values
        if wl_r.shape != self.wavelength.shape or not np.allclose(wl_r, self.wavelength):
            raise ShapeMismatchError(
                f"radiance wavelengths ({wl_r.size}) must equal the camera's bands "
                f"({self.wavelength.size}); resample the radiance first."
            )
        weights = xr.DataArray(self.bandpass().values[i], dims=("wavelength",))
        return xr.dot(weights, radiance.drop_vars("wavelength"), dim="wavelength")

    def capture(
        self,
        radiance: xr.DataArray,
        *,
        wavelength: float,
        exposure_time: float,
        adc_offset: npt.ArrayLike | None = None,
        seed: SeedLike = None,
    ) -> xr.DataArray:
        """One band shot of a spectral radiance (..., wavelength, y, x): counts (..., y, x).

        ``adc_offset`` overrides the scalar offset (e.g. with a per-pixel dark pattern).
        """
        x = self.band_irradiance(radiance, wavelength)
        q = float(self.quantum_efficiency.values[self.band_index(wavelength)])
        out = capture(
            x,
            exposure_time,
            response=self.response,
            quantum_efficiency=q,
            adc_offset=self.adc_offset if adc_offset is None else adc_offset,
            noise_sigma=self.noise_sigma,
            bit_depth=self.bit_depth,
            noise=self.noise,
            full_well=self.full_well,
            seed=seed,
        )
        return out.assign_coords(
            wavelength=((), float(wavelength), {"units": "nm", "long_name": "band centre"}),
            exposure_time=((), float(exposure_time), {"units": "s", "long_name": "exposure time"}),
        )
