"""Estimator core ``shared_texel_refine``: a texel's spectra across a set share a few shapes.

In a rectified BTF set every image sees the same texel ``p`` under another light and view.
A texel integrates a few materials below the pixel (each with its own normal, so its own
shading in every image) and a highlight in the illuminant's spectrum (the dichromatic
model), so the texel's spectra over the set's images ``m`` lie in a subspace of low rank:

``S_m(p) = sum_{k=1..r} a_mk(p) E_k(p) + h_m(p) L``,

with ``r`` per-texel shapes ``E_k(p)`` shared by every image, per-image weights
``a_m(p)`` (shading, coverage) and ``h_m(p)`` (highlight), and the set's highlight
spectrum ``L``.

The model is fitted per texel to every measurement of the texel at once, by alternating
least squares from an initial estimate ``S^0`` (the default solver's):

``min sum_m ||C_m S_m - R_m||^2 / sigma_R,m^2 + sum_i (S_{m_i, b_i} - D_i)^2 / sigma_i^2
+ mu sum_m ||S_m - S^0_m||^2 / sigma_0,m^2``

over ``E`` (one ``r W x r W`` linear system per texel, ``W`` wavelengths) and over
``(a_m, h_m)`` (one ``(r + 1) x (r + 1)`` system per texel and image, then ``>= 0``). The
band shots ``D_i`` of any image constrain the shapes of every image, so an image without
band shots gets the texel's shapes from the others' shots through its own RGB ``R_m``.
The result is projected onto ``C_m S_m = R_m`` and ``S >= 0``; texels whose RGB over
the set the model cannot make (:func:`rgb_misfit`) keep ``S^0``.

The limit is the band noise, not the model: each band is shot once per set, so a texel's
shapes get one value per band, at a band SNR at or below 1 on the hard scenes, whatever the
set's size, and the initial estimate's per-element error is well below that noise. The
shots cannot correct a texel on their own, and ``mu = 1`` keeps the fit close to ``S^0``:
the gain is the consistency over the images (:mod:`.material_pooled` pools the shots of a
material's texels instead). Pass the measured illuminant as ``L``:
:func:`highlight_spectrum`'s estimate loses part of the gain. Measured gains and the
variants tried: ``docs/benchmarks_notes.md`` ("reconstruction").

References
----------
.. [1] Fast Capture of Spectral Image Series, sections 3 and 5 (eq. 1's RGB and band terms;
   BTF sets of rectified images).
.. [2] Shafer, S. A. (1985). Using color to separate reflection components. Color Research
   and Application 10(4) (highlights have the illuminant's spectrum).
.. [3] Keshava, N., Mustard, J. F. (2002). Spectral unmixing. IEEE Signal Processing
   Magazine 19(1) (the linear mixing model).
.. [4] Kolda, T. G., Bader, B. W. (2009). Tensor decompositions and applications. SIAM
   Review 51(3) (alternating least squares for low-rank factorisations).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from spectralize.schemas import ReconstructionError

from ..inputs import ReconstructionInputs
from .endmember_mixture import _project, band_noise_sigma

__all__ = [
    "refit_input_problems",
    "fit_terms",
    "FitTerms",
    "shared_texel_refine",
    "highlight_spectrum",
    "rgb_misfit",
    "DEFAULT_RANK",
    "DEFAULT_PRIOR",
    "DEFAULT_ROUNDS",
    "DEFAULT_MISFIT",
]

DEFAULT_RANK = 1
"""``r``: shapes per texel shared over the set (besides the highlight spectrum)."""

DEFAULT_PRIOR = 1.0
"""``mu``: weight of the initial estimate, per element, in units of ``sigma_0``."""

DEFAULT_ROUNDS = 3
"""Alternating rounds (weights, then shapes)."""

DEFAULT_MISFIT = 0.005
"""``tau``: a texel keeps the initial estimate where :func:`rgb_misfit` exceeds it (its RGB
over the set spans more dimensions than ``r`` shapes and ``L`` can make)."""

PRIOR_RELATIVE_SIGMA = 0.1
"""``sigma_0,m``: the initial estimate's error per element, relative to image ``m``'s mean
radiance."""

SHAPE_RIDGE = 1e-6
"""Ridge of the shapes' systems towards the previous shapes, relative to the median diagonal."""

RGB_RELATIVE_SIGMA = 0.005
"""``sigma_R,m``: RGB noise relative to image ``m``'s mean RGB per channel (HDR merge); the
floor of :func:`~.material_pooled.rgb_noise_sigma`, which estimates it from the set."""


def refit_input_problems(
    inputs: ReconstructionInputs, initial: np.ndarray, highlight: np.ndarray
) -> list[str]:
    """What is wrong with a set model's ``initial`` cube and ``highlight`` spectrum (empty:
    nothing), each naming the array, what was expected and what was found."""
    problems = []
    if initial.shape != inputs.cube_shape:
        problems.append(f"initial: expected shape {inputs.cube_shape}, found {initial.shape}")
    elif not np.all(np.isfinite(initial)):
        problems.append(
            f"initial: expected finite values, found {int((~np.isfinite(initial)).sum())} not"
        )
    if highlight.shape != (inputs.n_wavelength,):
        problems.append(f"highlight: expected shape ({inputs.n_wavelength},), found {highlight.shape}")
    elif not np.all(np.isfinite(highlight)) or not np.any(highlight > 0):
        problems.append("highlight: expected a finite spectrum with a positive value")
    return problems


def _check(inputs: ReconstructionInputs, initial: np.ndarray, highlight: np.ndarray, rank: int) -> None:
    problems = refit_input_problems(inputs, initial, highlight)
    if not 1 <= rank <= inputs.n_image:
        problems.append(f"rank: expected 1 .. n_image={inputs.n_image}, found {rank}")
    if problems:
        raise ReconstructionError("; ".join(problems))


def highlight_spectrum(initial: np.ndarray) -> np.ndarray:
    """The set's highlight spectrum ``L`` (unit norm, ``>= 0``) from an estimate of its spectra.

    Every texel's spectra over the set span its material shapes and ``L``; ``L`` is the one
    direction common to all texels. With ``V_p`` the top two right singular vectors of
    texel ``p``'s ``(n_image, n_wavelength)`` spectra and ``w_p = sigma_2 / sigma_1`` (how
    much a second direction, a highlight, shows), ``L`` is the top eigenvector of
    ``sum_p w_p V_p^T V_p``.

    Parameters
    ----------
    initial
        ``(n_wavelength, n_image, height, width)`` spectra of one set (``n_image >= 2``).

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength,)`` float64.
    """
    x = np.asarray(initial, dtype=np.float64)
    if x.ndim != 4 or x.shape[1] < 2:
        raise ReconstructionError(
            f"initial: expected (n_wavelength, n_image >= 2, height, width), found shape {x.shape}"
        )
    n_w, n_m = x.shape[:2]
    stack = x.reshape(n_w, n_m, -1).transpose(2, 1, 0)  # (n, m, w)
    _, s, vt = np.linalg.svd(stack, full_matrices=False)
    weight = s[:, 1] / np.maximum(s[:, 0], 1e-300)
    scatter = np.einsum("n,nkw,nkv->wv", weight, vt[:, :2], vt[:, :2])
    _, vectors = np.linalg.eigh(scatter)
    ell = vectors[:, -1]
    ell = ell if ell.sum() >= 0 else -ell
    return np.maximum(ell, 0.0) / max(float(np.linalg.norm(np.maximum(ell, 0.0))), 1e-300)


def rgb_misfit(inputs: ReconstructionInputs, rank: int) -> np.ndarray:
    """Per texel, how far its RGB over the set is from the ``r + 1`` dimensions of the model.

    Under the model every image's RGB ``R_m(p) = C (sum_k a_mk E_k + h_m L)`` lies in the
    span of ``r + 1`` colours, so the ``(n_image, 3)`` stack of a texel's RGB has rank
    ``r + 1`` (at most 3). Returns ``sigma_{r+2} / sigma_1`` of that stack, ``(height,
    width)`` (0 for ``r >= 2``: three channels cannot show more).
    """
    n = inputs.height * inputs.width
    if rank + 1 >= 3:
        return np.zeros((inputs.height, inputs.width))
    stack = inputs.rgb.reshape(inputs.n_image, n, 3).transpose(1, 0, 2).astype(np.float64)
    # singular values from the 3 x 3 Gram matrices (increasing eigenvalues)
    power = np.linalg.eigvalsh(np.matmul(np.swapaxes(stack, 1, 2), stack))
    s = np.sqrt(np.maximum(power[:, ::-1], 0.0))
    return (s[:, rank + 1] / np.maximum(s[:, 0], 1e-300)).reshape(inputs.height, inputs.width)


class FitTerms(NamedTuple):
    """The fixed terms of a set model's fit, per texel ``n`` (the ``active`` ones), image
    ``m``, wavelength ``w`` and shot: :func:`fit_terms`."""

    ell: np.ndarray  # (w,) L / ||L||
    x0: np.ndarray  # (n, m, w) S^0
    rgb: np.ndarray  # (n, m, 3) R_m
    cams: np.ndarray  # (m, 3, w) C_m
    rgb_weight: np.ndarray  # (m, 3) 1 / sigma_R,m^2
    prior_weight: np.ndarray  # (m,) mu / sigma_0,m^2
    shot_image: np.ndarray  # (shots,) m_i
    shot_band: np.ndarray  # (shots,) b_i
    data: np.ndarray  # (n, shots) D_i
    shot_weight: np.ndarray  # (shots,) 1 / sigma_i^2
    ctc: np.ndarray  # (m, w, w) C_m^T W_R C_m


def image_means(initial: np.ndarray) -> np.ndarray:
    """``(n_image,)``: each image's mean of a cube ``(n_wavelength, n_image, height, width)``
    in float64, the same bits as ``initial.astype(np.float64).mean(axis=(0, 2, 3))``.

    A C-contiguous cube in another dtype (the solvers' float32) is summed band by band,
    each band cast on its own, instead of through a float64 copy of the whole cube: numpy
    sums a C-contiguous float64 cube over these axes band after band, each band's plane
    pairwise, which a cast made during the sum would change (its buffer splits the planes
    into other blocks)."""
    if initial.dtype == np.float64 or not initial.flags.c_contiguous or initial.ndim != 4:
        return np.asarray(initial, dtype=np.float64).mean(axis=(0, 2, 3))
    total = np.add.reduce(initial[0].astype(np.float64), axis=(1, 2))
    for band in initial[1:]:
        total += np.add.reduce(band.astype(np.float64), axis=(1, 2))
    return total / (initial.shape[0] * initial.shape[2] * initial.shape[3])


def fit_terms(
    inputs: ReconstructionInputs,
    initial: np.ndarray,
    highlight: np.ndarray,
    prior: float,
    band_sigma: np.ndarray | None,
    active: np.ndarray | None = None,
) -> FitTerms:
    """The fixed terms of the set models' least squares (module docstring's energy) for the
    texels ``active`` (flat indices; None: all), shared by :func:`shared_texel_refine` and
    :func:`~.material_pooled.material_pooled_refine`."""
    n_w, n_m, h, w = inputs.cube_shape
    n = h * w
    cube = initial.reshape(n_w, n_m, n)
    # every texel: the cube itself, transposed (and a float32 cube cast) in one copy (an
    # index array would copy it first into a layout whose transpose is slow to gather)
    x0 = cube.transpose(2, 1, 0) if active is None else cube[:, :, active].transpose(2, 1, 0)
    active = np.arange(n) if active is None else active
    if band_sigma is None:
        band_sigma = band_noise_sigma(inputs)
    band_sigma = np.maximum(np.asarray(band_sigma, dtype=np.float64), 1e-12)
    cams = np.stack([inputs.camera_of(m) for m in range(n_m)]).astype(np.float64)
    rgb_sigma = RGB_RELATIVE_SIGMA * np.maximum(
        np.abs(inputs.rgb.reshape(n_m, -1, 3).mean(axis=1)), 1e-12
    )
    rgb_weight = 1.0 / rgb_sigma**2
    prior_sigma = PRIOR_RELATIVE_SIGMA * np.maximum(image_means(initial), 1e-12)
    shot_band = np.asarray(inputs.band, dtype=np.int64)
    return FitTerms(
        ell=highlight / np.linalg.norm(highlight),
        x0=np.ascontiguousarray(x0, dtype=np.float64),
        rgb=inputs.rgb.reshape(n_m, n, 3)[:, active].transpose(1, 0, 2).astype(np.float64),
        cams=cams,
        rgb_weight=rgb_weight,
        prior_weight=prior / prior_sigma**2,
        shot_image=np.asarray(inputs.image, dtype=np.int64),
        shot_band=shot_band,
        data=inputs.band_data.reshape(len(shot_band), n)[:, active].T.astype(np.float64),
        shot_weight=1.0 / band_sigma**2,
        ctc=np.matmul(np.swapaxes(cams, 1, 2) * rgb_weight[:, None, :], cams),
    )


def shared_texel_refine(
    inputs: ReconstructionInputs,
    initial: np.ndarray,
    highlight: np.ndarray | None = None,
    *,
    misfit: float | None = DEFAULT_MISFIT,
    rank: int = DEFAULT_RANK,
    prior: float = DEFAULT_PRIOR,
    rounds: int = DEFAULT_ROUNDS,
    band_sigma: np.ndarray | None = None,
) -> np.ndarray:
    """Refit a set's spectra with per-texel shapes shared by all images (module docstring).

    Parameters
    ----------
    inputs
        The checked inputs of one set (rectified images: pixel ``(y, x)`` is the same texel
        in every image).
    initial
        ``S^0``, ``(n_wavelength, n_image, height, width)``: the estimate to start from and
        to be held towards.
    highlight
        ``L``, ``(n_wavelength,)``: the highlight (illuminant) spectrum, any scale; None:
        :func:`highlight_spectrum` of ``initial``.
    misfit
        ``tau``: texels whose :func:`rgb_misfit` exceeds it keep ``initial`` (None: none).
    rank
        ``r``, shapes per texel besides ``L``.
    prior
        ``mu``, weight of ``S^0``.
    rounds
        Alternating rounds.
    band_sigma
        Per shot, the band noise's standard deviation (default:
        :func:`~.endmember_mixture.band_noise_sigma`).

    Returns
    -------
    numpy.ndarray
        ``(n_wavelength, n_image, height, width)`` float64, ``>= 0``.

    Raises
    ------
    ReconstructionError
        For an ``initial`` or ``highlight`` of the wrong shape or not finite, or a rank
        outside ``1 .. n_image``.
    """

    initial = np.asarray(initial, dtype=np.float64)
    if highlight is None:
        highlight = highlight_spectrum(initial)
    highlight = np.asarray(highlight, dtype=np.float64)
    rank = int(rank)
    _check(inputs, initial, highlight, rank)
    n_w, n_m, h, w = inputs.cube_shape
    n = h * w
    # only the texels the model can fit are refitted (the others keep S^0): the cost is
    # per refitted texel
    keep = None if misfit is None else (rgb_misfit(inputs, rank) > misfit).ravel()  # (n,)
    active = np.arange(n) if keep is None else np.flatnonzero(~keep)
    t = fit_terms(inputs, initial, highlight, prior, band_sigma, active)
    ell, x0, rgb, cams, rgb_weight, prior_weight, shot_image, shot_band, data, shot_weight, ctc = t

    # initial shapes: the texel's rank-r SVD of S^0 (L is not projected out: every
    # radiance is L times a reflectance, so most of a material's spectrum lies along L)
    shapes = _top_shapes(x0, rank)  # (n, r, w)
    sign = np.where(shapes.sum(axis=2) < 0, -1.0, 1.0)
    shapes *= sign[:, :, None]

    # per image: C_m^T W_R R_m (fixed over the rounds; C_m^T W_R C_m is ctc)
    ctr = np.matmul((rgb * rgb_weight)[:, :, None, :], cams[None])[:, :, 0, :]  # (n, m, w)
    weights = None
    for _ in range(int(rounds)):
        weights = _weights_step(
            shapes,
            ell,
            cams,
            rgb_weight,
            rgb,
            x0,
            prior_weight,
            data,
            shot_image,
            shot_band,
            shot_weight,
        )
        shapes = _shapes_step(
            shapes, weights, ell, ctc, ctr, x0, prior_weight, data, shot_image, shot_band, shot_weight
        )
    weights = _weights_step(
        shapes, ell, cams, rgb_weight, rgb, x0, prior_weight, data, shot_image, shot_band, shot_weight
    )
    basis = np.concatenate([shapes, np.broadcast_to(ell, (active.size, 1, n_w))], axis=1)
    fit = initial.reshape(n_w, n_m, n).copy()
    fit[:, :, active] = np.einsum("nmk,nkw->wmn", weights, basis)  # (w, m, n_active)
    fit = _project(np.ascontiguousarray(fit.reshape(n_w, n_m, h, w)), inputs)  # per texel
    if keep is not None:  # the model cannot fit these: S^0 as given
        fit.reshape(n_w, n_m, n)[:, :, keep] = initial.reshape(n_w, n_m, n)[:, :, keep]
    return fit


def _top_shapes(x0: np.ndarray, rank: int, iterations: int = 30) -> np.ndarray:
    """``(n, r, w)``: per texel the top ``r`` right singular vectors of its ``(m, w)``
    spectra times their singular values, by power iteration with deflation on the
    ``w x w`` Gram matrices (started from the mean spectrum, which is close to the top one)."""
    gram = np.matmul(np.swapaxes(x0, 1, 2), x0)  # (n, w, w)
    out = np.empty((x0.shape[0], rank, x0.shape[2]))
    start = x0.mean(axis=1)
    for k in range(rank):
        v = start + (1e-3 * (k + 1)) * np.abs(start).mean(axis=1, keepdims=True) * np.cos(
            np.arange(x0.shape[2]) * (k + 1)
        )
        for _ in range(iterations):
            v = np.matmul(gram, v[..., None])[..., 0]
            v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-300)
        power = np.einsum("nw,nwv,nv->n", v, gram, v)
        out[:, k] = v * np.sqrt(np.maximum(power, 0.0))[:, None]
        gram = gram - power[:, None, None] * v[:, :, None] * v[:, None, :]
        start = np.matmul(gram, start[..., None])[..., 0]
    return out


def _weights_step(
    shapes, ell, cams, rgb_weight, rgb, x0, prior_weight, data, shot_image, shot_band, shot_weight
):
    """Per texel and image, ``(a_m, h_m) >= 0`` for fixed shapes (normal equations, clipped)."""
    n, r, n_w = shapes.shape
    basis = np.concatenate([shapes, np.broadcast_to(ell, (n, 1, n_w))], axis=1)  # (n, k, w)
    # RGB term through each image's camera: (n, m, k, 3)
    seen = np.matmul(basis[:, None], np.swapaxes(cams, 1, 2)[None])
    weighted = seen * rgb_weight[None, :, None, :]
    gram = np.matmul(weighted, np.swapaxes(seen, 2, 3))  # (n, m, k, k)
    rhs = np.matmul(weighted, rgb[..., None])[..., 0]  # (n, m, k)
    # prior term
    gram += prior_weight[None, :, None, None] * np.matmul(basis, np.swapaxes(basis, 1, 2))[:, None]
    rhs += prior_weight[None, :, None] * np.matmul(x0, np.swapaxes(basis, 1, 2))
    # band shots of each image
    for i, (m, b) in enumerate(zip(shot_image, shot_band, strict=True)):
        g = basis[:, :, b]  # (n, k)
        gram[:, m] += shot_weight[i] * g[:, :, None] * g[:, None, :]
        rhs[:, m] += shot_weight[i] * g * data[:, i, None]
    k = basis.shape[1]
    gram += 1e-9 * np.trace(gram, axis1=2, axis2=3)[..., None, None] / k * np.eye(k)
    if k == 2:  # rank 1 (the default): 2 x 2 systems in closed form (Cramer's rule)
        g00, g01, g10, g11 = gram[..., 0, 0], gram[..., 0, 1], gram[..., 1, 0], gram[..., 1, 1]
        det = g00 * g11 - g01 * g10
        det = np.where(det > 0, det, 1e-300)
        solved = np.stack(
            [
                (g11 * rhs[..., 0] - g01 * rhs[..., 1]) / det,
                (g00 * rhs[..., 1] - g10 * rhs[..., 0]) / det,
            ],
            axis=-1,
        )
    else:
        solved = np.linalg.solve(gram, rhs[..., None])[..., 0]
    return np.maximum(solved, 0.0)


def _shapes_step(
    previous, weights, ell, ctc, ctr, x0, prior_weight, data, shot_image, shot_band, shot_weight
):
    """Per texel, the ``r`` shapes for fixed weights: one ``r W`` linear system."""
    n, n_m, k = weights.shape
    r = k - 1
    n_w = ell.size
    a, hl = weights[:, :, :r], weights[:, :, r]
    # targets with the highlight taken out: RGB rhs and prior target
    ctr_rest = ctr - hl[:, :, None] * np.einsum("mwv,v->mw", ctc, ell)[None]
    prior_rest = prior_weight[None, :, None] * (x0 - hl[:, :, None] * ell)
    # normal matrix (n, r, w, r, w)
    aa = (a[:, :, :, None] * a[:, :, None, :]).reshape(n, n_m, r * r)
    mat = np.matmul(np.swapaxes(aa, 1, 2), ctc.reshape(n_m, n_w * n_w))  # (n, r r, w w)
    mat = np.ascontiguousarray(mat.reshape(n, r, r, n_w, n_w).transpose(0, 1, 3, 2, 4))
    prior_aa = np.matmul(np.swapaxes(aa, 1, 2), prior_weight).reshape(n, r, r)
    idx = np.arange(n_w)
    for kk in range(r):
        for jj in range(r):
            mat[:, kk, idx, jj, idx] += prior_aa[:, kk, jj, None]
    rhs = np.matmul(np.swapaxes(a, 1, 2), ctr_rest + prior_rest)  # (n, r, w)
    for i, (m, b) in enumerate(zip(shot_image, shot_band, strict=True)):
        am = a[:, m]  # (n, r)
        mat[:, :, b, :, b] += shot_weight[i] * am[:, :, None] * am[:, None, :]
        rhs[:, :, b] += shot_weight[i] * am * (data[:, i] - hl[:, m] * ell[b])[:, None]
    mat = mat.reshape(n, r * n_w, r * n_w)
    # a small ridge towards the previous shapes (a texel whose weights are all 0 keeps them)
    ridge = SHAPE_RIDGE * max(float(np.median(np.einsum("nii->n", mat))) / (r * n_w), 1e-300)
    mat += ridge * np.eye(r * n_w)
    rhs = rhs.reshape(n, r * n_w) + ridge * previous.reshape(n, r * n_w)
    return np.linalg.solve(mat, rhs[..., None])[..., 0].reshape(n, r, n_w)
