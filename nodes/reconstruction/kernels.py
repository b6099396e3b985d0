"""Compiled inner loops of the eq. 1 solvers, on pixel-major cubes.

The conjugate-gradient solvers spend their time in a handful of passes over the cube per
iteration: the normal operator ``A^T A`` (RGB term, neighbour Laplacian, ridge), the block
Jacobi preconditioner and the vector updates. Written with numpy each pass would allocate a
temporary, and the neighbour Laplacian needs the cube pixel-major (one row of
``n_wavelength`` values per pixel) while the per-band filters want it band-major, so the
cube would be transposed twice per iteration. These kernels work on the pixel-major cube
``(n_pixels, n_wavelength)`` and fuse each step into one pass, with no temporaries and no
transposes (``benchmarks/reconstruction.py`` times the solvers that run on them).

Why hand-written: no library fuses a sparse gather with a per-pixel 3 x n_wavelength
product; numba compiles these loops to machine code. They run on one thread and release
the GIL (``nogil``), so dask runs tiles or sets side by side; compiled code is cached on
disk after the first call.

References
----------
.. [1] Fast Capture of Spectral Image Series, section 3, "Optimization".
.. [2] Lam, S. K., Pitrou, A. and Seibert, S. (2015). Numba: a LLVM-based Python JIT
   compiler. Proceedings of the Second Workshop on the LLVM Compiler Infrastructure in HPC.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "normal_pixels",
    "prior_normal_pixels",
    "block_jacobi_pixels",
    "block_jacobi_setup",
    "neighbour_spread",
    "cg_step",
    "gather_bands",
    "scatter_add_bands",
    "cg_step_block_jacobi",
    "cg_direction",
    "dot",
    "projected_step",
    "step_dots",
    "mixture_abundances",
    "project_rgb_nonnegative",
    "mixture_gram",
    "mixture_rhs",
    "nearest_centres",
    "share_planes",
    "top_planes",
    "mix_atoms",
    "box_mean_rows",
    "box_mean_columns",
    "group_sums",
    "GROUP_SUM_MEMBERS",
    "laplacian_rows",
    "dichromatic_costs",
    "support_costs_pixels",
]

_jit = njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
"""The compilation every kernel gets: machine code cached on disk, the GIL released, fast
floating-point maths, numpy's error model (no exceptions for division by zero)."""

_jit_inline = njit(inline="always", cache=True, nogil=True, fastmath=True, error_model="numpy")
""":data:`_jit` for helpers inlined into the kernels that call them."""

_jit_exact = njit(cache=True, nogil=True, error_model="numpy")
""":data:`_jit` without fast maths: every addition in the order written, for a kernel that
must give numpy's own result bit for bit."""


@_jit
def normal_pixels(
    x, camera, camera_index, beta, indptr, indices, data, gamma, epsilon, image, out
):  # pragma: no cover - compiled
    """``out = beta C_m^T C_m x + gamma L x + epsilon x`` per pixel (no filter term).

    Parameters
    ----------
    x, out
        ``(n_pixels, n_wavelength)`` float32, pixel-major; ``out`` is overwritten.
    camera
        The distinct camera matrices ``C``, ``(n_camera, 3, n_wavelength)``.
    camera_index
        ``(n_image,)``: image ``m`` is seen through ``camera[camera_index[m]]``.
    beta, gamma
        Weights of the RGB and neighbour terms (eq. 4).
    indptr, indices, data
        The neighbour Laplacian ``L`` in CSR form (``n_pixels x n_pixels``).
    epsilon
        Ridge per image and wavelength, ``(n_image, n_wavelength)``.
    image
        ``(n_pixels,)``: the image of every pixel.
    """
    n_pixels, n_wavelength = x.shape
    for p in range(n_pixels):
        m = image[p]
        c = camera[camera_index[m]]
        v0 = 0.0
        v1 = 0.0
        v2 = 0.0
        for w in range(n_wavelength):
            value = x[p, w]
            v0 += c[0, w] * value
            v1 += c[1, w] * value
            v2 += c[2, w] * value
        v0 *= beta
        v1 *= beta
        v2 *= beta
        for w in range(n_wavelength):
            out[p, w] = c[0, w] * v0 + c[1, w] * v1 + c[2, w] * v2 + epsilon[m, w] * x[p, w]
        for j in range(indptr[p], indptr[p + 1]):
            column = indices[j]
            weight = gamma * data[j]
            for w in range(n_wavelength):
                out[p, w] += weight * x[column, w]


@_jit
def prior_normal_pixels(
    x,
    camera,
    camera_index,
    beta,
    indptr,
    indices,
    data,
    gamma,
    epsilon,
    image,
    precision,
    weight,
    brightness,
    shots,
    subtract,
    out,
):  # pragma: no cover - compiled
    """:func:`normal_pixels` plus the priors' per-pixel terms in the same pass; returns
    ``x . out`` (float64).

    ``out = beta C_m^T C_m x + gamma L x + epsilon x + w_p Q x_p + f_p shots[m] x_p -
    subtract``, per pixel ``p`` of image ``m``: the spectral prior ``w_p Q`` (``precision``
    ``Q`` ``(n_wavelength, n_wavelength)``, ``weight`` ``w_p`` ``(n_pixels,)``), the
    brightness-weighted guided prior (``brightness`` ``f_p`` ``(n_pixels,)``, ``shots``
    ``(n_image, n_wavelength)``) and a vector to subtract (``(n_pixels, n_wavelength)``, the
    right-hand side of a gradient ``H x - b``). An empty ``weight``, ``brightness`` or
    ``subtract`` (size 0) leaves its term out. Without ``subtract``, the returned
    ``x . out`` is the curvature ``x^T H x`` CG needs (the filter term's share is added by
    its own pass); with it, the value means nothing.
    """
    n_pixels, n_wavelength = x.shape
    use_prior = weight.size > 0
    use_brightness = brightness.size > 0
    use_subtract = subtract.size > 0
    row = np.empty(n_wavelength, dtype=out.dtype)  # the pixel's result, written once
    here = np.empty(n_wavelength, dtype=out.dtype)
    total = 0.0
    block = 64
    prior_block = np.zeros((block, n_wavelength), dtype=out.dtype)
    for p in range(n_pixels):
        if use_prior and p % block == 0:  # Q x for a block of pixels: one small GEMM
            last = min(p + block, n_pixels)
            prior_block[: last - p] = np.dot(x[p:last], precision)
        m = image[p]
        c = camera[camera_index[m]]
        v0 = 0.0
        v1 = 0.0
        v2 = 0.0
        for w in range(n_wavelength):
            value = x[p, w]
            here[w] = value
            v0 += c[0, w] * value
            v1 += c[1, w] * value
            v2 += c[2, w] * value
        v0 *= beta
        v1 *= beta
        v2 *= beta
        for w in range(n_wavelength):
            row[w] = c[0, w] * v0 + c[1, w] * v1 + c[2, w] * v2 + epsilon[m, w] * here[w]
        for j in range(indptr[p], indptr[p + 1]):
            column = indices[j]
            coupling = gamma * data[j]
            for w in range(n_wavelength):
                row[w] += coupling * x[column, w]
        if use_prior:  # Q is symmetric: its rows scaled by x_p, added (vectorises)
            wp = weight[p]
            qx = prior_block[p % block]
            for w in range(n_wavelength):
                row[w] += wp * qx[w]
        if use_brightness:
            fp = brightness[p]
            for w in range(n_wavelength):
                row[w] += fp * shots[m, w] * here[w]
        if use_subtract:
            for w in range(n_wavelength):
                row[w] -= subtract[p, w]
        part = 0.0
        for w in range(n_wavelength):
            out[p, w] = row[w]
            part += here[w] * row[w]
        total += part
    return total


@_jit
def block_jacobi_pixels(
    r, inverse_diagonal, camera, camera_index, image, small_inverse, out
):  # pragma: no cover - compiled
    """``out = M^-1 r`` for the block-Jacobi preconditioner; returns ``r . out``.

    The per-pixel block ``diag(a) + beta C^T C`` is inverted with the Woodbury identity:
    ``M^-1 r = u - a^-1 C^T T C u`` with ``u = r / a`` and ``T`` the pixel's 3 x 3
    ``(I / beta + C a^-1 C^T)^-1`` (``small_inverse``, ``(n_pixels, 3, 3)``). ``C`` of
    pixel ``p`` is ``camera[camera_index[image[p]]]`` (as :func:`normal_pixels`).
    """
    total = 0.0
    if camera.shape[0] == 1:  # one C for every pixel: looked up once
        only = camera[0]
        for p in range(r.shape[0]):
            total = _block_jacobi_pixel(p, r, inverse_diagonal, only, small_inverse, out, total)
    else:
        for p in range(r.shape[0]):
            c = camera[camera_index[image[p]]]
            total = _block_jacobi_pixel(p, r, inverse_diagonal, c, small_inverse, out, total)
    return total


@_jit_inline
def _block_jacobi_pixel(p, r, inverse_diagonal, camera, small_inverse, out, total):  # pragma: no cover
    """:func:`block_jacobi_pixels` on pixel ``p`` with its ``C`` ``(3, n_wavelength)``;
    returns ``total`` plus its share of ``r . out`` (summed in the same order as one loop)."""
    n_wavelength = r.shape[1]
    v0 = 0.0
    v1 = 0.0
    v2 = 0.0
    for w in range(n_wavelength):
        u = r[p, w] * inverse_diagonal[p, w]
        out[p, w] = u
        v0 += camera[0, w] * u
        v1 += camera[1, w] * u
        v2 += camera[2, w] * u
    t0 = small_inverse[p, 0, 0] * v0 + small_inverse[p, 0, 1] * v1 + small_inverse[p, 0, 2] * v2
    t1 = small_inverse[p, 1, 0] * v0 + small_inverse[p, 1, 1] * v1 + small_inverse[p, 1, 2] * v2
    t2 = small_inverse[p, 2, 0] * v0 + small_inverse[p, 2, 1] * v1 + small_inverse[p, 2, 2] * v2
    for w in range(n_wavelength):
        z = out[p, w] - inverse_diagonal[p, w] * (
            camera[0, w] * t0 + camera[1, w] * t1 + camera[2, w] * t2
        )
        out[p, w] = z
        total += r[p, w] * z
    return total


@_jit
def block_jacobi_setup(
    inverse_diagonal, camera, pixel_camera, beta, small_inverse
):  # pragma: no cover - compiled
    """``small_inverse[p] = (I / beta + C a_p^-1 C^T)^-1`` per pixel, in float64 by the
    closed-form inverse of a symmetric 3 x 3 matrix (cofactors), stored in the dtype of
    ``small_inverse`` ``(n_pixels, 3, 3)``; ``C`` of pixel ``p`` is
    ``camera[pixel_camera[p]]`` (``camera`` float64 ``(n_camera, 3, n_wavelength)``)."""
    n_pixels, n_wavelength = inverse_diagonal.shape
    floor = 1.0 / beta
    for p in range(n_pixels):
        c = camera[pixel_camera[p]]
        s00 = s01 = s02 = s11 = s12 = s22 = 0.0
        for w in range(n_wavelength):
            a = np.float64(inverse_diagonal[p, w])
            c0 = c[0, w] * a
            c1 = c[1, w] * a
            s00 += c0 * c[0, w]
            s01 += c0 * c[1, w]
            s02 += c0 * c[2, w]
            s11 += c1 * c[1, w]
            s12 += c1 * c[2, w]
            s22 += c[2, w] * a * c[2, w]
        s00 += floor
        s11 += floor
        s22 += floor
        i00 = s11 * s22 - s12 * s12
        i01 = s02 * s12 - s01 * s22
        i02 = s01 * s12 - s02 * s11
        i11 = s00 * s22 - s02 * s02
        i12 = s01 * s02 - s00 * s12
        i22 = s00 * s11 - s01 * s01
        scale = 1.0 / (s00 * i00 + s01 * i01 + s02 * i02)
        small_inverse[p, 0, 0] = i00 * scale
        small_inverse[p, 0, 1] = i01 * scale
        small_inverse[p, 0, 2] = i02 * scale
        small_inverse[p, 1, 0] = i01 * scale
        small_inverse[p, 1, 1] = i11 * scale
        small_inverse[p, 1, 2] = i12 * scale
        small_inverse[p, 2, 0] = i02 * scale
        small_inverse[p, 2, 1] = i12 * scale
        small_inverse[p, 2, 2] = i22 * scale


@_jit
def neighbour_spread(flat, pixels, neighbours, ratios, squared):  # pragma: no cover - compiled
    """``squared[i] += sum_j mean_w (r_ij S_w(n_ij) - S_w(p_i))^2`` in float64 for the
    pixels ``p_i`` = ``pixels[i]``, band by band (``flat`` ``(n_wavelength, n_pixels)``
    band-major: each band's row is gathered, no strided columns); ``neighbours``,
    ``ratios`` ``(n_chosen, k)``: row ``i`` those of ``p_i``."""
    n_wavelength = flat.shape[0]
    k = neighbours.shape[1]
    for w in range(n_wavelength):
        band = flat[w]
        for i in range(pixels.size):
            value = np.float64(band[pixels[i]])
            total = 0.0
            for j in range(k):
                gap = ratios[i, j] * np.float64(band[neighbours[i, j]]) - value
                total += gap * gap
            squared[i] += total / n_wavelength


@_jit
def gather_bands(x, positions, bands, planes):  # pragma: no cover - compiled
    """``planes[j, i] = x[positions[i], bands[j]]``: an image's band planes out of a
    pixel-major cube, every pixel's row visited once for all its bands."""
    for i in range(positions.size):
        row = positions[i]
        for j in range(bands.size):
            planes[j, i] = x[row, bands[j]]


@_jit
def scatter_add_bands(out, positions, bands, planes):  # pragma: no cover - compiled
    """``out[positions[i], bands[j]] += planes[j, i]`` (the adjoint of
    :func:`gather_bands`), in the order of ``bands`` per pixel."""
    for i in range(positions.size):
        row = positions[i]
        for j in range(bands.size):
            out[row, bands[j]] += planes[j, i]


@_jit
def cg_step(x, r, p, q, step):  # pragma: no cover - compiled
    """``x += step p``, ``r -= step q`` in one pass; returns the new ``r . r``."""
    xf, rf, pf, qf = x.ravel(), r.ravel(), p.ravel(), q.ravel()
    total = 0.0
    for i in range(xf.size):
        xf[i] += step * pf[i]
        value = rf[i] - step * qf[i]
        rf[i] = value
        total += value * value
    return total


@_jit
def cg_step_block_jacobi(
    x, r, p, q, step, inverse_diagonal, camera, camera_index, image, small_inverse
):  # pragma: no cover - compiled
    """:func:`cg_step` and :func:`block_jacobi_pixels` in one pass: ``x += step p``,
    ``r -= step q``, then ``q = M^-1 r`` (the preconditioned residual ``z`` takes the place
    of ``q``, used up by then); returns ``(r . r, r . z)``."""
    n_pixels, n_wavelength = r.shape
    rr = 0.0
    rz = 0.0
    for i in range(n_pixels):
        part = 0.0
        for w in range(n_wavelength):
            x[i, w] += step * p[i, w]
            value = r[i, w] - step * q[i, w]
            r[i, w] = value
            part += value * value
        rr += part
        c = camera[camera_index[image[i]]]
        rz = _block_jacobi_pixel(i, r, inverse_diagonal, c, small_inverse, q, rz)
    return rr, rz


@_jit
def cg_direction(p, z, beta):  # pragma: no cover - compiled
    """``p = z + beta p`` in place."""
    pf, zf = p.ravel(), z.ravel()
    for i in range(pf.size):
        pf[i] = zf[i] + beta * pf[i]


@_jit
def dot(a, b):  # pragma: no cover - compiled
    """``sum(a * b)`` accumulated in float64."""
    af, bf = a.ravel(), b.ravel()
    total = 0.0
    for i in range(af.size):
        total += np.float64(af[i]) * bf[i]
    return total


@_jit
def projected_step(x, g, scale, step, out):  # pragma: no cover - compiled
    """``out = max(x - step * scale * g, 0)`` in one pass (a scaled projected-gradient step
    onto ``S >= 0``)."""
    xf, gf, sf, of = x.ravel(), g.ravel(), scale.ravel(), out.ravel()
    for i in range(xf.size):
        value = xf[i] - step * sf[i] * gf[i]
        of[i] = value if value > 0.0 else 0.0


@_jit
def step_dots(new, x, new_g, g, scale):  # pragma: no cover - compiled
    """``(s . y, s . (s / scale))`` with ``s = new - x``, ``y = new_g - g``, accumulated in
    float64 in one pass without forming ``s`` or ``y`` (the Barzilai-Borwein step)."""
    nf, xf, ngf, gf, sf = new.ravel(), x.ravel(), new_g.ravel(), g.ravel(), scale.ravel()
    sy = 0.0
    ss = 0.0
    for i in range(nf.size):
        d = np.float64(nf[i]) - xf[i]
        sy += d * (np.float64(ngf[i]) - gf[i])
        ss += d * d / sf[i]
    return sy, ss


@_jit
def project_rgb_nonnegative(
    cube, camera, pseudo, camera_of_image, rgb, rounds
):  # pragma: no cover - compiled
    """``rounds`` times, per pixel: ``S += C^+ (R - C S)`` (the smallest change that makes
    ``C S = R``), then ``S = max(S, 0)``; in place, in one pass over the cube.

    Parameters
    ----------
    cube
        ``(n_wavelength, n_image, n_pixels)`` float64, C-contiguous (each image's pixels).
    camera, pseudo
        Per camera ``C`` ``(n_camera, 3, n_wavelength)`` and its pseudo-inverse ``C^T (C
        C^T)^-1`` ``(n_camera, n_wavelength, 3)``, float64.
    camera_of_image
        ``(n_image,)``: the camera of each image.
    rgb
        ``(n_image, n_pixels, 3)``: ``R``.
    rounds
        Alternations of the projection and the clipping.

    Every pixel's alternation is its own (no pixel looks at another), so one pass that
    alternates each pixel ``rounds`` times in registers is the same as ``rounds`` passes of
    each step over the whole cube.
    """
    n_wavelength, n_image, n_pixels = cube.shape
    s = np.empty(n_wavelength)
    for m in range(n_image):
        c = camera[camera_of_image[m]]
        inverse = pseudo[camera_of_image[m]]
        for q in range(n_pixels):
            for w in range(n_wavelength):
                s[w] = cube[w, m, q]
            r0 = np.float64(rgb[m, q, 0])
            r1 = np.float64(rgb[m, q, 1])
            r2 = np.float64(rgb[m, q, 2])
            for _ in range(rounds):
                g0 = r0
                g1 = r1
                g2 = r2
                for w in range(n_wavelength):
                    g0 -= c[0, w] * s[w]
                    g1 -= c[1, w] * s[w]
                    g2 -= c[2, w] * s[w]
                for w in range(n_wavelength):
                    value = s[w] + inverse[w, 0] * g0 + inverse[w, 1] * g1 + inverse[w, 2] * g2
                    s[w] = value if value > 0.0 else 0.0
            for w in range(n_wavelength):
                cube[w, m, q] = s[w]


@_jit
def _solve_passive(hessian, rhs, passive, n_passive, system, z):  # pragma: no cover - compiled
    """``z[:n] = H_PP^-1 rhs_P`` for the first ``n_passive`` indices of ``passive``
    (Gaussian elimination with partial pivoting); False if singular."""
    s = n_passive
    for i in range(s):
        for j in range(s):
            system[i, j] = hessian[passive[i], passive[j]]
        system[i, s] = rhs[passive[i]]
    for col in range(s):
        pivot = col
        for row in range(col + 1, s):
            if abs(system[row, col]) > abs(system[pivot, col]):
                pivot = row
        if system[pivot, col] == 0.0:
            return False
        if pivot != col:
            for j in range(col, s + 1):
                tmp = system[col, j]
                system[col, j] = system[pivot, j]
                system[pivot, j] = tmp
        for row in range(col + 1, s):
            factor = system[row, col] / system[col, col]
            for j in range(col, s + 1):
                system[row, j] -= factor * system[col, j]
    for i in range(s - 1, -1, -1):
        value = system[i, s]
        for j in range(i + 1, s):
            value -= system[i, j] * z[j]
        z[i] = value / system[i, i]
    return True


@_jit
def mixture_abundances(projected, near, rgb, ridge, out):  # pragma: no cover - compiled
    """Per pixel the non-negative least-squares weights of its candidate atoms' RGB.

    ``min ||sum_k w_k projected[near[p, k]] - rgb[p]||^2 + ridge_p ||w||^2`` over ``w >= 0``
    with ``ridge_p = ridge * trace(Gram)``, by the active-set method of Lawson and Hanson:
    atoms enter the passive set by largest gradient, and a step that would make a weight
    negative stops at the boundary and drops it. The ridge makes the problem strictly
    convex, so this is its unique minimiser, found without enumerating the ``2^k`` supports.

    Parameters
    ----------
    projected
        ``(n_atoms, 3)``: every atom's RGB.
    near
        ``(n_pixels, k)`` candidate atoms per pixel.
    rgb
        ``(n_pixels, 3)``.
    ridge
        Relative ridge.
    out
        ``(n_pixels, k)``, overwritten with the weights.

    References
    ----------
    .. [1] Lawson, C. L., Hanson, R. J. (1974). Solving Least Squares Problems, chapter 23.
    """
    n_pixels, k = near.shape
    hessian = np.empty((k, k))
    rhs = np.empty(k)
    system = np.empty((k, k + 1))
    passive = np.empty(k, dtype=np.int64)
    in_passive = np.zeros(k, dtype=np.bool_)
    z = np.empty(k)
    w = np.empty(k)
    for p in range(n_pixels):
        trace = 0.0
        scale = 0.0
        for a in range(k):
            ia = near[p, a]
            rhs[a] = (
                projected[ia, 0] * rgb[p, 0]
                + projected[ia, 1] * rgb[p, 1]
                + projected[ia, 2] * rgb[p, 2]
            )
            scale = max(scale, abs(rhs[a]))
            for c in range(k):
                ic = near[p, c]
                hessian[a, c] = (
                    projected[ia, 0] * projected[ic, 0]
                    + projected[ia, 1] * projected[ic, 1]
                    + projected[ia, 2] * projected[ic, 2]
                )
            trace += hessian[a, a]
        lam = ridge * trace + 1e-300
        for a in range(k):
            hessian[a, a] += lam
            w[a] = 0.0
            in_passive[a] = False
        n_passive = 0
        tolerance = 1e-12 * scale
        for _ in range(3 * k):
            best, entering = tolerance, -1  # the most negative gradient outside the set
            for a in range(k):
                if in_passive[a]:
                    continue
                gradient = rhs[a]
                for c in range(k):
                    gradient -= hessian[a, c] * w[c]
                if gradient > best:
                    best, entering = gradient, a
            if entering < 0:
                break
            passive[n_passive] = entering
            in_passive[entering] = True
            n_passive += 1
            for _inner in range(k + 1):
                if not _solve_passive(hessian, rhs, passive, n_passive, system, z):
                    break
                alpha, blocking = 1.0, -1  # the step stops where a weight would turn negative
                for i in range(n_passive):
                    if z[i] <= 0.0:
                        wi = w[passive[i]]
                        t = wi / (wi - z[i])
                        if t < alpha:
                            alpha, blocking = t, i
                if blocking < 0:
                    for i in range(n_passive):
                        w[passive[i]] = z[i]
                    break
                kept = 0
                for i in range(n_passive):
                    a = passive[i]
                    w[a] += alpha * (z[i] - w[a])
                    if i == blocking or w[a] <= 0.0:
                        w[a] = 0.0
                        in_passive[a] = False
                    else:
                        passive[kept] = a
                        kept += 1
                n_passive = kept
                if n_passive == 0:
                    break
        for a in range(k):
            out[p, a] = w[a]


@_jit
def mixture_gram(near, weights, gram):  # pragma: no cover - compiled
    """``gram[a, c] += sum_p w_pa w_pc`` over the pixels, atoms scattered by ``near``."""
    n_pixels, k = near.shape
    for p in range(n_pixels):
        for a in range(k):
            wa = weights[p, a]
            if wa == 0.0:
                continue
            ia = near[p, a]
            for c in range(k):
                gram[ia, near[p, c]] += wa * weights[p, c]


@_jit
def mixture_rhs(near, weights, data, rhs):  # pragma: no cover - compiled
    """``rhs[a] += sum_p w_pa d_p`` over the pixels, atoms scattered by ``near``."""
    n_pixels, k = near.shape
    for p in range(n_pixels):
        d = data[p]
        for a in range(k):
            rhs[near[p, a]] += weights[p, a] * d


@_jit
def nearest_centres(chroma, centres, k, near):  # pragma: no cover - compiled
    """Per pixel the ``k`` centres nearest in (squared Euclidean) distance, nearest first.

    Ties go to the lower centre index (a stable insertion into the running ``k`` best), as
    numpy's stable sort of the distances would order them.

    Parameters
    ----------
    chroma
        ``(n_pixels, 2)`` points.
    centres
        ``(n_centres, 2)``, ``n_centres >= k``.
    k
        Centres per pixel.
    near
        ``(n_pixels, >= k)`` int64; its first ``k`` columns are overwritten.
    """
    n_pixels = chroma.shape[0]
    n_centres = centres.shape[0]
    best = np.empty(k)
    for p in range(n_pixels):
        x0 = chroma[p, 0]
        x1 = chroma[p, 1]
        for c in range(k):
            best[c] = np.inf
        for j in range(n_centres):
            d0 = x0 - centres[j, 0]
            d1 = x1 - centres[j, 1]
            d = d0 * d0 + d1 * d1
            if not d < best[k - 1]:
                continue
            c = k - 1
            while c > 0 and d < best[c - 1]:
                best[c] = best[c - 1]
                near[p, c] = near[p, c - 1]
                c -= 1
            best[c] = d
            near[p, c] = j


@_jit
def share_planes(near, weights, skip, planes):  # pragma: no cover - compiled
    """``planes[j, p] += w_pa / sum_a w_pa`` for every candidate ``a`` of pixel ``p`` with
    ``near[p, a] = j != skip``: each atom's abundance share map, in one pass.

    Parameters
    ----------
    near, weights
        ``(n_pixels, k)`` candidate atoms and their abundances.
    skip
        An atom left out (the highlight atom).
    planes
        ``(n_atoms, n_pixels)``, zeroed by the caller, added to.
    """
    n_pixels, k = near.shape
    for p in range(n_pixels):
        total = 0.0
        for a in range(k):
            total += weights[p, a]
        total = max(total, 1e-300)
        for a in range(k):
            j = near[p, a]
            if j != skip:
                planes[j, p] += weights[p, a] / total


@_jit
def top_planes(planes, skip, index):  # pragma: no cover - compiled
    """Per pixel the ``count`` planes with the largest values, largest first; ties go to
    the lower plane index.

    Parameters
    ----------
    planes
        ``(n_planes, n_pixels)``, values ``>= 0``.
    skip
        A plane left out.
    index
        ``(n_pixels, count)`` int64, overwritten (``0`` where fewer planes than ``count``).
    """
    n_planes, n_pixels = planes.shape
    count = index.shape[1]
    best = np.empty(count)
    for p in range(n_pixels):
        for c in range(count):
            best[c] = -1.0
            index[p, c] = 0
        for j in range(n_planes):
            if j == skip:
                continue
            v = planes[j, p]
            if not v > best[count - 1]:
                continue
            c = count - 1
            while c > 0 and v > best[c - 1]:
                best[c] = best[c - 1]
                index[p, c] = index[p, c - 1]
                c -= 1
            best[c] = v
            index[p, c] = j


@_jit
def mix_atoms(weights, near, atoms, cube):  # pragma: no cover - compiled
    """``cube[w, p] = sum_a weights[p, a] atoms[near[p, a], w]``: the band-major mixture.

    Parameters
    ----------
    weights, near
        ``(n_pixels, k)`` abundances and their atoms.
    atoms
        ``(n_atoms, n_wavelength)``.
    cube
        ``(n_wavelength, n_pixels)``, overwritten.
    """
    n_pixels, k = near.shape
    n_wavelength = atoms.shape[1]
    block = 64  # pixels mixed pixel-major in a small buffer, written band-major in runs
    s = np.empty((block, n_wavelength))
    for start in range(0, n_pixels, block):
        stop = min(start + block, n_pixels)
        for q in range(stop - start):
            p = start + q
            for w in range(n_wavelength):
                s[q, w] = 0.0
            for a in range(k):
                wa = weights[p, a]
                if wa == 0.0:
                    continue
                row = near[p, a]
                for w in range(n_wavelength):
                    s[q, w] += wa * atoms[row, w]
        for w in range(n_wavelength):
            for q in range(stop - start):
                cube[w, start + q] = s[q, w]


@_jit_inline
def _reflect(i, n):  # pragma: no cover - compiled
    """Index ``i`` reflected into ``[0, n)`` about the half-sample edges (``d c b a | a b c
    d | d c b a``: scipy.ndimage's ``"reflect"``)."""
    i = i % (2 * n)
    return 2 * n - 1 - i if i >= n else i


@_jit
def box_mean_rows(planes, width, out):  # pragma: no cover - compiled
    """Mean over ``width`` (odd) neighbours along the last axis of ``(n, height, width)``
    planes, reflecting borders: a running sum in float64, as scipy.ndimage's
    ``uniform_filter1d(planes, width, axis=-1, mode="reflect")``."""
    n, height, size = planes.shape
    radius = width // 2
    scale = 1.0 / width
    entering = np.empty(size, dtype=np.int64)  # the reflected indices, once per call
    leaving = np.empty(size, dtype=np.int64)
    for x in range(size):
        entering[x] = _reflect(x + radius, size)
        leaving[x] = _reflect(x - radius - 1, size)
    for k in range(n):
        for y in range(height):
            total = 0.0
            for i in range(-radius, radius + 1):
                total += planes[k, y, _reflect(i, size)]
            out[k, y, 0] = total * scale
            for x in range(1, size):
                total += planes[k, y, entering[x]] - planes[k, y, leaving[x]]
                out[k, y, x] = total * scale


@_jit
def box_mean_columns(planes, width, out):  # pragma: no cover - compiled
    """As :func:`box_mean_rows` along the middle axis (``axis=-2``), one row of running
    sums at a time (contiguous reads)."""
    n, height, size = planes.shape
    radius = width // 2
    scale = 1.0 / width
    total = np.empty(size)
    for k in range(n):
        for x in range(size):
            total[x] = 0.0
        for i in range(-radius, radius + 1):
            row = _reflect(i, height)
            for x in range(size):
                total[x] += planes[k, row, x]
        for x in range(size):
            out[k, 0, x] = total[x] * scale
        for y in range(1, height):
            entering = _reflect(y + radius, height)
            leaving = _reflect(y - radius - 1, height)
            for x in range(size):
                total[x] += planes[k, entering, x] - planes[k, leaving, x]
                out[k, y, x] = total[x] * scale


GROUP_SUM_MEMBERS = 8
"""The most columns a group of :func:`group_sums` may have: up to it numpy adds a group's
columns after the first one by one (its pairwise sum starts unrolling at eight)."""


@_jit_exact
def group_sums(x, columns, indptr, target, out):  # pragma: no cover - compiled
    """``out[r, target[j]] = x[r, c_0] + (x[r, c_1] + x[r, c_2] + ...)`` for the columns
    ``c = columns[indptr[j]:indptr[j + 1]]`` of each group ``j``: the sums
    ``numpy.add.reduceat`` gives along a row of at most :data:`GROUP_SUM_MEMBERS` columns
    per group, in its order of additions (the first column, plus the others summed from
    ``-0.0``), so bit for bit the same, in one pass over ``x`` with no reordered copy.

    Parameters
    ----------
    x
        ``(n, n_columns)`` float64.
    columns, indptr
        The groups' columns (``int64``), group ``j``'s at ``indptr[j]:indptr[j + 1]``, each
        group non-empty.
    target
        ``(n_groups,)`` the column of ``out`` each group's sum goes to.
    out
        ``(n, n_targets)`` float64; the targets' columns overwritten, the others kept.
    """
    n = x.shape[0]
    n_groups = target.shape[0]
    for r in range(n):
        for j in range(n_groups):
            first = indptr[j]
            rest = -0.0
            for i in range(first + 1, indptr[j + 1]):
                rest += x[r, columns[i]]
            out[r, target[j]] = x[r, columns[first]] + rest


@_jit_inline
def _row_slot(q, slot, columns, own, other, used):
    """Give column ``q`` a place in the row being assembled if it has none (its sums from
    zero); returns the number of places used."""
    if slot[q] < 0:
        slot[q] = used
        columns[used] = q
        own[used] = 0.0
        other[used] = 0.0
        return used + 1
    return used


@_jit_exact
def laplacian_rows(
    neighbours, ratios, degree, reverse_ptr, reverse_pair, indptr, indices, data
):  # pragma: no cover
    """The neighbour Laplacian ``L = diag(degree) - (W + W^T)`` in CSR, ``W[p, N_p[j]] =
    r_pj``, with scipy's values bit for bit: per entry ``0 - ((0 + sum of W's) + (0 + sum of
    W^T's))`` (``degree - ...`` on the diagonal), each sum in the order scipy's general CSR
    sum adds a row's duplicates, entries equal to 0 left out, columns increasing.

    Two passes over the rows: with ``indices`` of size 0 it only counts each row's entries
    into ``indptr[p + 1]``; then, with ``indptr`` its running sum, it writes them.

    Parameters
    ----------
    neighbours, ratios
        ``(n, k)`` the pairs ``(p, N_p[j])`` and their ``r`` (float64).
    degree
        ``(n,)`` float64, the diagonal before ``W + W^T``.
    reverse_ptr, reverse_pair
        The pairs ending at each pixel, ``p * k + j`` increasing, pixel ``q``'s at
        ``reverse_ptr[q]:reverse_ptr[q + 1]``.
    indptr, indices, data
        ``(n + 1,)``, then ``(nnz,)`` each: the CSR arrays, written.
    """
    n, k = neighbours.shape
    count_only = indices.shape[0] == 0
    slot = np.full(n, -1, dtype=np.int64)
    longest = 1 + k
    for q in range(n):
        longest = max(longest, 1 + k + reverse_ptr[q + 1] - reverse_ptr[q])
    columns = np.empty(longest, dtype=np.int64)
    own = np.empty(longest)
    other = np.empty(longest)
    values = np.empty(longest)
    for p in range(n):
        used = 0
        for j in range(k):  # W's row p, its duplicates summed in order
            q = neighbours[p, j]
            used = _row_slot(q, slot, columns, own, other, used)
            own[slot[q]] += ratios[p, j]
        for i in range(reverse_ptr[p], reverse_ptr[p + 1]):  # W^T's row p
            pair = reverse_pair[i]
            q = pair // k
            used = _row_slot(q, slot, columns, own, other, used)
            other[slot[q]] += ratios[q, pair % k]
        diagonal = slot[p]
        for e in range(used):
            slot[columns[e]] = -1
        kept = 0
        for e in range(used):  # W + W^T, zeros dropped; then the diagonal minus it
            total = own[e] + other[e]
            if total != 0.0:
                columns[kept] = columns[e]
                values[kept] = (degree[p] if e == diagonal else 0.0) - total
                if values[kept] != 0.0:
                    kept += 1
            elif e == diagonal and degree[p] != 0.0:
                columns[kept] = p
                values[kept] = degree[p]
                kept += 1
        if diagonal < 0 and degree[p] != 0.0:
            columns[kept] = p
            values[kept] = degree[p]
            kept += 1
        if count_only:
            indptr[p + 1] = kept
            continue
        start = indptr[p]
        for e in range(kept):  # insertion sort by column (a row holds a few entries)
            column, value = columns[e], values[e]
            at = start + e
            while at > start and indices[at - 1] > column:
                indices[at] = indices[at - 1]
                data[at] = data[at - 1]
                at -= 1
            indices[at] = column
            data[at] = value


@_jit_exact
def dichromatic_costs(atoms_rgb, light_rgb, rgb, variance, cost):  # pragma: no cover - compiled
    """``cost[j, p] += min chi^2`` of the dichromatic fit ``R_mp ~ a E_mj + h L_m`` (``a, h
    >= 0``) summed over the images ``m``: the material ``j``'s line through the texel's RGB.

    Where the unconstrained two-atom fit has a negative weight, the better of the fits on
    one atom (material or highlight, each clipped at zero) is taken: the exact non-negative
    least squares on two atoms.

    Parameters
    ----------
    atoms_rgb
        ``(n_image, n_material, 3)``: each material's RGB through each image's camera.
    light_rgb
        ``(n_image, 3)``: the highlight atom's RGB per image.
    rgb
        ``(n_image, n_texel, 3)``.
    variance
        ``(n_image, n_texel)``: the RGB variance the squared residuals are divided by.
    cost
        ``(n_material, n_texel)``, added to.
    """
    n_image, n_material = atoms_rgb.shape[0], atoms_rgb.shape[1]
    n_texel = rgb.shape[1]
    pair = np.empty((n_material, 4))  # per material: e.e, e.l and the ridged gram's diagonal
    for m in range(n_image):
        l0, l1, l2 = light_rgb[m, 0], light_rgb[m, 1], light_rgb[m, 2]
        ll = l0 * l0 + l1 * l1 + l2 * l2
        for j in range(n_material):
            e0, e1, e2 = atoms_rgb[m, j, 0], atoms_rgb[m, j, 1], atoms_rgb[m, j, 2]
            ee = e0 * e0 + e1 * e1 + e2 * e2
            ridge = 1e-12 * (ee + ll) + 1e-300
            pair[j, 0], pair[j, 1] = ee, e0 * l0 + e1 * l1 + e2 * l2
            pair[j, 2], pair[j, 3] = ee + ridge, ll + ridge
        for p in range(n_texel):
            r0, r1, r2 = rgb[m, p, 0], rgb[m, p, 1], rgb[m, p, 2]
            rl = r0 * l0 + r1 * l1 + r2 * l2
            h = max(rl / max(ll, 1e-300), 0.0)
            d0, d1, d2 = r0 - h * l0, r1 - h * l1, r2 - h * l2
            light_only = d0 * d0 + d1 * d1 + d2 * d2
            v = variance[m, p]
            for j in range(n_material):
                e0, e1, e2 = atoms_rgb[m, j, 0], atoms_rgb[m, j, 1], atoms_rgb[m, j, 2]
                ee, el, g00, g11 = pair[j, 0], pair[j, 1], pair[j, 2], pair[j, 3]
                det = g00 * g11 - el * el
                re = r0 * e0 + r1 * e1 + r2 * e2
                w0 = (g11 * re - el * rl) / det
                w1 = (g00 * rl - el * re) / det
                if w0 >= 0.0 and w1 >= 0.0:
                    d0 = r0 - w0 * e0 - w1 * l0
                    d1 = r1 - w0 * e1 - w1 * l1
                    d2 = r2 - w0 * e2 - w1 * l2
                    best = d0 * d0 + d1 * d1 + d2 * d2
                else:
                    a = max(re / max(ee, 1e-300), 0.0)
                    d0, d1, d2 = r0 - a * e0, r1 - a * e1, r2 - a * e2
                    best = min(d0 * d0 + d1 * d1 + d2 * d2, light_only)
                cost[j, p] += best / v


@_jit_inline
def _solve_small(gram, rhs, size, pivot_row, w):  # pragma: no cover - compiled
    """``w[:size] = gram^-1 rhs`` by Gaussian elimination with partial pivoting; ``gram``
    and ``rhs`` are overwritten."""
    for c in range(size):
        best = c
        for i in range(c + 1, size):
            if abs(gram[i, c]) > abs(gram[best, c]):
                best = i
        pivot_row[c] = best
        if best != c:
            for k in range(size):
                gram[c, k], gram[best, k] = gram[best, k], gram[c, k]
            rhs[c], rhs[best] = rhs[best], rhs[c]
        inverse = 1.0 / gram[c, c]
        for i in range(c + 1, size):
            factor = gram[i, c] * inverse
            for k in range(c + 1, size):
                gram[i, k] -= factor * gram[c, k]
            rhs[i] -= factor * rhs[c]
    for c in range(size - 1, -1, -1):
        total = rhs[c]
        for k in range(c + 1, size):
            total -= gram[c, k] * w[k]
        w[c] = total / gram[c, c]


@_jit_exact
def support_costs_pixels(
    atoms_rgb,
    atoms,
    candidates,
    subsets,
    sizes,
    children,
    rgb,
    variance,
    shots,
    shot_variance,
    shot_band,
    shot_start,
    shot_order,
    band_model_error,
    total,
):  # pragma: no cover - compiled
    """``total[s, p] += rgb_cost + band_cost`` of support ``s`` of texel ``p`` per image: the
    exact non-negative least squares of the image's RGB on the support, the best feasible
    of its sub-supports by RGB cost (each support keeps the best of itself and its
    children, visited by size), and its band shots' chi^2.

    Parameters
    ----------
    atoms_rgb
        ``(n_image, n_atoms, 3)``: every atom's RGB through each image's camera.
    atoms
        ``(n_atoms, n_wavelength)``.
    candidates
        ``(n_texel, n_candidates)`` int64: each texel's candidate atoms.
    subsets, sizes, children
        ``(n_subset, max_size)`` candidate positions of each support, its size, and the
        indices of its supports one smaller (``-1``: the empty support; as many as its
        size), supports ordered by size.
    rgb, variance
        ``(n_image, n_texel, 3)`` and ``(n_image, n_texel)``.
    shots, shot_variance, shot_band
        ``(n_shot, n_texel)`` band shots, their noise variance and band ``(n_shot,)``.
    shot_start, shot_order
        Image ``m``'s shots are ``shot_order[shot_start[m]:shot_start[m + 1]]``.
    band_model_error
        Relative error of the atoms' spectra added to the shots' noise.
    total
        ``(n_subset, n_texel)``, added to.
    """
    n_image, n_texel = variance.shape
    n_subset, max_size = subsets.shape
    rgb_cost = np.empty(n_subset)
    band_cost = np.empty(n_subset)
    gram = np.empty((max_size, max_size))
    rhs = np.empty(max_size)
    w = np.empty(max_size)
    pivot_row = np.empty(max_size, dtype=np.int64)
    index = np.empty(max_size, dtype=np.int64)
    n_candidates = candidates.shape[1]
    candidate_gram = np.empty((n_candidates, n_candidates))
    candidate_rhs = np.empty(n_candidates)
    for m in range(n_image):
        first, stop = shot_start[m], shot_start[m + 1]
        for p in range(n_texel):
            r0, r1, r2 = rgb[m, p, 0], rgb[m, p, 1], rgb[m, p, 2]
            v = variance[m, p]
            empty_rgb = (r0 * r0 + r1 * r1 + r2 * r2) / v
            empty_band = 0.0
            for q in range(first, stop):
                k = shot_order[q]
                empty_band += shots[k, p] ** 2 / shot_variance[k]
            for i in range(n_candidates):
                a = candidates[p, i]
                candidate_rhs[i] = (
                    atoms_rgb[m, a, 0] * r0 + atoms_rgb[m, a, 1] * r1 + atoms_rgb[m, a, 2] * r2
                )
                for k in range(i + 1):
                    b = candidates[p, k]
                    candidate_gram[i, k] = (
                        atoms_rgb[m, a, 0] * atoms_rgb[m, b, 0]
                        + atoms_rgb[m, a, 1] * atoms_rgb[m, b, 1]
                        + atoms_rgb[m, a, 2] * atoms_rgb[m, b, 2]
                    )
                    candidate_gram[k, i] = candidate_gram[i, k]
            for s in range(n_subset):
                size = sizes[s]
                trace = 0.0
                for i in range(size):
                    index[i] = candidates[p, subsets[s, i]]
                    rhs[i] = candidate_rhs[subsets[s, i]]
                    for k in range(size):
                        gram[i, k] = candidate_gram[subsets[s, i], subsets[s, k]]
                    trace += gram[i, i]
                ridge = 1e-12 * trace + 1e-300
                for i in range(size):
                    gram[i, i] += ridge
                _solve_small(gram, rhs, size, pivot_row, w)
                feasible = True
                d0, d1, d2 = r0, r1, r2
                for i in range(size):
                    feasible = feasible and w[i] >= 0.0
                    a = index[i]
                    d0 -= w[i] * atoms_rgb[m, a, 0]
                    d1 -= w[i] * atoms_rgb[m, a, 1]
                    d2 -= w[i] * atoms_rgb[m, a, 2]
                own_rgb = (d0 * d0 + d1 * d1 + d2 * d2) / v if feasible else np.inf
                own_band = 0.0
                for q in range(first, stop):
                    k = shot_order[q]
                    predicted = 0.0
                    for i in range(size):
                        predicted += w[i] * atoms[index[i], shot_band[k]]
                    spread = shot_variance[k] + (band_model_error * predicted) ** 2
                    own_band += (predicted - shots[k, p]) ** 2 / spread
                for c in range(size):
                    child = children[s, c]
                    other_rgb = empty_rgb if child < 0 else rgb_cost[child]
                    if other_rgb < own_rgb:
                        own_rgb = other_rgb
                        own_band = empty_band if child < 0 else band_cost[child]
                rgb_cost[s], band_cost[s] = own_rgb, own_band
                total[s, p] += own_rgb + own_band
