"""Tests of the material-pooled refinement (one shape per material, pooled band shots)."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction import inputs_from_xarray, reconstruct
from spectralize.nodes.reconstruction.estimators.material_pooled import (
    material_clusters,
    material_pooled_refine,
    rgb_noise_sigma,
)
from spectralize.nodes.reconstruction.estimators.shared_texel import shared_texel_refine
from spectralize.nodes.reconstruction.inputs import ReconstructionInputs
from spectralize.schemas import ReconstructionError

from .conftest import camera_matrix_for, make_scene, smooth_spectra

WAVELENGTH = np.arange(420.0, 701.0, 20.0)
C = camera_matrix_for(WAVELENGTH)
LIGHT = np.exp(-0.5 * ((WAVELENGTH - 560.0) / 60.0) ** 2) + 0.2


def _two_material_set(seed: int = 0, *, size: int = 16, n_image: int = 8, snr: float = 3.0):
    """Two materials scattered over the texels, shaded and lit per texel and image, a
    highlight ``h_m L`` on some; every band shot once (round-robin over the first half of
    the images) with noise ``1 / snr`` of the mean band value. The initial estimate has the
    error a solver shares over a material: each material's spectrum tilted the same way in
    every texel and image, and a little per-texel error."""
    rng = np.random.default_rng(seed)
    n_w, n = WAVELENGTH.size, size * size
    materials = smooth_spectra(rng, WAVELENGTH, 2) * LIGHT  # (2, w) radiance shapes
    label = rng.integers(0, 2, size=n)
    shade = rng.uniform(0.4, 1.4, size=(n_image, n))
    gloss = rng.uniform(0.0, 0.3, size=(n_image, n)) * (rng.random((n_image, n)) < 0.2)
    truth = shade[:, None, :] * materials[label].T[None] + gloss[:, None, :] * LIGHT[None, :, None]
    truth = truth.reshape(n_image, n_w, size, size)
    band = np.arange(n_w)
    image = band % (n_image // 2)
    sigma = np.full(n_w, float(truth.mean()) / snr)
    data = truth[image, band] + sigma[:, None, None] * rng.normal(size=(n_w, size, size))
    inputs = ReconstructionInputs(
        rgb=np.einsum("cw,mwyx->myxc", C, truth),
        band_data=data.astype(np.float32),
        band=band,
        image=image,
        filter_size=np.full(n_w, 1.0),
        camera_matrix=C,
        wavelength=WAVELENGTH,
    )
    tilt = 1.0 + 0.25 * rng.uniform(-1, 1, size=(2, n_w))  # per material, shared by its texels
    texel = 1.0 + 0.03 * rng.normal(size=(n, n_w))
    initial = truth * (tilt[label] * texel).T.reshape(1, n_w, size, size)
    cube = lambda x: np.ascontiguousarray(np.moveaxis(x, 0, 1))  # noqa: E731  (w, m, y, x)
    return inputs, cube(truth), cube(initial), sigma, label.reshape(size, size)


def _two_camera_set(seed: int, *, noise: float, size: int = 16, n_image: int = 8):
    """:func:`_two_material_set`'s scene with a good initial estimate (3 % error per texel,
    none shared by a material) seen by two camera models: the even images through ``C``
    with exact RGB, the odd ones through another ``C`` with Gaussian noise of ``noise``
    times the image's mean RGB per channel (a second camera model mapped onto the paired
    one). Returns the inputs, truth, initial, band sigma, labels and the mean RGB per image
    ``(n_image, 3)``."""
    rng = np.random.default_rng(seed)
    n_w, n = WAVELENGTH.size, size * size
    materials = smooth_spectra(rng, WAVELENGTH, 2) * LIGHT
    label = rng.integers(0, 2, size=n)
    shade = rng.uniform(0.4, 1.4, size=(n_image, n))
    gloss = rng.uniform(0.0, 0.3, size=(n_image, n)) * (rng.random((n_image, n)) < 0.2)
    truth = shade[:, None, :] * materials[label].T[None] + gloss[:, None, :] * LIGHT[None, :, None]
    truth = truth.reshape(n_image, n_w, size, size)
    band = np.arange(n_w)
    image = band % (n_image // 2)
    sigma = np.full(n_w, float(truth.mean()) / 3.0)
    data = truth[image, band] + sigma[:, None, None] * rng.normal(size=(n_w, size, size))
    other = np.exp(-0.5 * ((WAVELENGTH[None, :] - np.array([[615.0], [525.0], [450.0]])) / 30.0) ** 2)
    cams = np.stack([C if m % 2 == 0 else other for m in range(n_image)])
    rgb = np.einsum("mcw,mwyx->myxc", cams, truth)
    mean = rgb.mean(axis=(1, 2))
    relative = np.where(np.arange(n_image) % 2 == 1, noise, 0.0)
    rgb += (relative[:, None] * mean)[:, None, None, :] * rng.normal(size=rgb.shape)
    inputs = ReconstructionInputs(
        rgb=rgb,
        band_data=data.astype(np.float32),
        band=band,
        image=image,
        filter_size=np.full(n_w, 1.0),
        camera_matrix=cams,
        wavelength=WAVELENGTH,
    )
    initial = truth * (1.0 + 0.03 * rng.normal(size=truth.shape))
    cube = lambda x: np.ascontiguousarray(np.moveaxis(x, 0, 1))  # noqa: E731  (w, m, y, x)
    return inputs, cube(truth), cube(initial), sigma, label.reshape(size, size), mean


def _nrmse(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per texel and image, RMSE over wavelengths / the image's mean truth."""
    rmse = np.sqrt(np.mean((estimate - truth) ** 2, axis=0))
    return rmse / truth.mean(axis=(0, 2, 3))[:, None, None]


def test_pooling_a_material_puts_more_texels_under_0_03_than_shared_texel():
    inputs, truth, initial, sigma, _ = _two_material_set(0)
    shared = shared_texel_refine(inputs, initial, LIGHT, misfit=None, band_sigma=sigma)
    pooled = material_pooled_refine(inputs, initial, LIGHT, clusters=2, band_sigma=sigma)
    e_shared, e_pooled = _nrmse(shared, truth), _nrmse(pooled, truth)
    assert pooled.shape == truth.shape and np.all(pooled >= 0)
    fraction_shared, fraction_pooled = np.mean(e_shared < 0.03), np.mean(e_pooled < 0.03)
    assert fraction_pooled > fraction_shared + 0.3, (fraction_shared, fraction_pooled)
    assert np.median(e_pooled) < 0.5 * np.median(e_shared), (np.median(e_shared), np.median(e_pooled))


def test_clusters_find_the_two_materials_despite_shading_and_highlights():
    _, truth, _, _, label = _two_material_set(1, snr=1e6)
    # each texel's spectrum in its least glossy image, at its own scale
    spectra = truth.reshape(truth.shape[0], truth.shape[1], -1)
    shapes = spectra[:, np.argmin(spectra.sum(axis=0), axis=0), np.arange(spectra.shape[2])].T
    found = material_clusters(shapes, clusters=2)
    agree = np.mean(found == label.ravel())
    assert max(agree, 1 - agree) > 0.95, agree


def test_with_noise_free_shots_and_true_labels_it_recovers_the_set():
    inputs, truth, initial, sigma, label = _two_material_set(2, snr=1e6)
    # the shots weighted as if at SNR 20 (far heavier weights leave each image's scale to
    # the shots alone, and the alternation does not move)
    out = material_pooled_refine(inputs, initial, LIGHT, labels=label, band_sigma=sigma * 5e4)
    assert np.median(_nrmse(out, truth)) < 0.01
    before = np.median(_nrmse(initial, truth))
    assert before > 0.05, before


def test_the_rgb_noise_of_each_image_is_what_the_material_model_leaves():
    """Exact RGB keeps the floor; the second camera's noisy RGB is found at its level."""
    from spectralize.nodes.reconstruction.estimators.shared_texel import (
        RGB_RELATIVE_SIGMA,
        fit_terms,
    )

    inputs, _, initial, sigma, label, mean = _two_camera_set(0, noise=0.06)
    terms = fit_terms(inputs, initial, LIGHT, 1.0, sigma)
    shapes = initial.reshape(initial.shape[0], initial.shape[1], -1).mean(axis=1).T
    found = rgb_noise_sigma(shapes, label.ravel(), terms) / mean  # relative, (m, 3)
    np.testing.assert_allclose(found[0::2], RGB_RELATIVE_SIGMA)
    assert np.all((found[1::2] > 0.045) & (found[1::2] < 0.075)), found[1::2]


def test_a_noisy_second_camera_does_not_pull_the_materials_from_a_good_start():
    """The RGB of a second camera model, noisier than the HDR floor, trusted at that floor
    pulls the pooled shapes to where the two cameras' matrices differ (the set's spectra
    many times worse than the initial estimate); trusted as far as the set shows, the
    refinement stays at or below the initial estimate's error."""
    inputs, truth, initial, sigma, _, mean = _two_camera_set(1, noise=0.06)
    before = np.median(_nrmse(initial, truth))
    out = material_pooled_refine(inputs, initial, LIGHT, clusters=2, band_sigma=sigma)
    assert np.median(_nrmse(out, truth)) < before, (np.median(_nrmse(out, truth)), before)
    from spectralize.nodes.reconstruction.estimators.shared_texel import RGB_RELATIVE_SIGMA

    floor = RGB_RELATIVE_SIGMA * mean
    trusted = material_pooled_refine(
        inputs, initial, LIGHT, clusters=2, band_sigma=sigma, rgb_sigma=floor
    )
    assert np.median(_nrmse(trusted, truth)) > 2 * before, (np.median(_nrmse(trusted, truth)), before)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("initial", r"initial: expected shape"),
        ("highlight", r"highlight: expected shape"),
        ("clusters", r"clusters: expected >= 1, found 0"),
        ("labels", r"labels: expected \(16, 16\) ints >= 0"),
        ("rgb_sigma", r"rgb_sigma: expected \(8, 3\) finite values > 0, found shape \(8, 2\)"),
    ],
)
def test_bad_input_is_named(change, message):
    inputs, _, initial, sigma, label = _two_material_set(3)
    kwargs = {"band_sigma": sigma}
    light = LIGHT
    if change == "initial":
        initial = initial[:, :2]
    elif change == "highlight":
        light = LIGHT[:3]
    elif change == "clusters":
        kwargs["clusters"] = 0
    elif change == "rgb_sigma":
        kwargs["rgb_sigma"] = np.ones((8, 2))
    else:
        kwargs["labels"] = label[:4]
    with pytest.raises(ReconstructionError, match=message):
        material_pooled_refine(inputs, initial, light, **kwargs)


def test_the_set_model_is_the_solve_then_the_refinement():
    scene = make_scene(size=14, n_wavelength=6, n_images=3, shading=True, noise=0.1, seed=3)
    args = (scene.rgb, scene.bands, scene.camera_matrix)
    wavelength = np.asarray(scene.camera_matrix["wavelength"].values, dtype=float)
    light = np.exp(-0.5 * ((wavelength - 560.0) / 70.0) ** 2) + 0.2
    plain = reconstruct(
        *args, illuminant=light, set_model="independent", full_output=True, confidence=False
    )
    pooled = reconstruct(
        *args, illuminant=light, set_model="material-pooled", full_output=True, confidence=False
    )
    assert pooled.spectra.attrs["set_model"] == "material-pooled"
    assert pooled.spectra.attrs["set_model_time_s"] >= 0
    inputs = inputs_from_xarray(*args, illuminant=light)
    direct = material_pooled_refine(inputs, np.moveaxis(plain.spectra.values, 0, 1), light)
    np.testing.assert_allclose(
        pooled.spectra.values, np.moveaxis(direct, 0, 1).astype(np.float32), rtol=1e-5, atol=1e-6
    )
    with pytest.raises(ReconstructionError, match="'material-pooled'.*needs the illuminant.*found none"):
        reconstruct(*args, set_model="material-pooled")


def test_the_rank_1_texel_steps_are_shared_texels():
    """The per-texel fit's steps are shared-texel's (rank 1), written for one shape."""
    from spectralize.nodes.reconstruction.estimators import material_pooled as mp
    from spectralize.nodes.reconstruction.estimators import shared_texel as st

    inputs, _, initial, sigma, _ = _two_material_set(4, size=6)
    rng = np.random.default_rng(5)
    n_w, n_m = initial.shape[:2]
    n = initial.shape[2] * initial.shape[3]
    x0 = np.ascontiguousarray(initial.reshape(n_w, n_m, n).transpose(2, 1, 0))
    rgb = inputs.rgb.reshape(n_m, n, 3).transpose(1, 0, 2)
    cams = np.stack([inputs.camera_of(m) for m in range(n_m)])
    rgb_weight = rng.uniform(1.0, 3.0, size=(n_m, 3))
    prior_weight = rng.uniform(0.5, 2.0, size=n_m)
    data = inputs.band_data.reshape(n_w, n).T.astype(float)
    shot = (inputs.image, inputs.band, 1.0 / sigma**2)
    shapes = x0.mean(axis=1) * rng.uniform(0.8, 1.2, size=(n, n_w))
    terms = (cams, rgb_weight, rgb, x0, prior_weight, data, *shot)
    lean = mp.texel_weights(shapes, LIGHT / np.linalg.norm(LIGHT), *terms)
    ell = LIGHT / np.linalg.norm(LIGHT)
    full = st._weights_step(shapes[:, None], ell, *terms)
    np.testing.assert_allclose(lean, full, rtol=1e-8, atol=1e-12)
    ctc = np.matmul(np.swapaxes(cams, 1, 2) * rgb_weight[:, None, :], cams)
    ctr = np.matmul((rgb * rgb_weight)[:, :, None, :], cams[None])[:, :, 0, :]
    rest = (x0, prior_weight, data, *shot)
    lean_shapes = mp.texel_shapes(shapes, full, ell, ctc, (rgb * rgb_weight, cams), *rest)
    full_shapes = st._shapes_step(shapes[:, None], full, ell, ctc, ctr, *rest)[:, 0]
    np.testing.assert_allclose(lean_shapes, full_shapes, rtol=1e-8, atol=1e-12)
    top = st._top_shapes(x0, 1, 4)[:, 0]
    top *= np.where(top.sum(axis=1) < 0, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(mp._top_shape(x0, 4), top, rtol=1e-8, atol=1e-12)


def test_texel_shapes_in_blocks_are_the_one_block_shapes_in_less_memory(monkeypatch):
    """The shapes step solves its ``W x W`` systems a block of texels at a time: the shapes
    of all texels at once (BLAS may round a block's products in another order: to 1e-12),
    without ever holding every texel's system."""
    import tracemalloc

    from spectralize.nodes.reconstruction.estimators import material_pooled as mp

    inputs, _, initial, sigma, _ = _two_material_set(6, size=48, n_image=4)
    n_w, n_m = initial.shape[:2]
    n = initial.shape[2] * initial.shape[3]
    rng = np.random.default_rng(7)
    x0 = np.ascontiguousarray(initial.reshape(n_w, n_m, n).transpose(2, 1, 0))
    rgb = inputs.rgb.reshape(n_m, n, 3).transpose(1, 0, 2)
    cams = np.stack([inputs.camera_of(m) for m in range(n_m)])
    rgb_weight = rng.uniform(1.0, 3.0, size=(n_m, 3))
    ctc = np.matmul(np.swapaxes(cams, 1, 2) * rgb_weight[:, None, :], cams)
    data = inputs.band_data.reshape(n_w, n).T.astype(float)
    shapes = x0.mean(axis=1) * rng.uniform(0.8, 1.2, size=(n, n_w))
    weights = rng.uniform(0.2, 1.0, size=(n, n_m, 2))
    ell = LIGHT / np.linalg.norm(LIGHT)
    rest = (x0, rng.uniform(0.5, 2.0, size=n_m), data, inputs.image, inputs.band, 1.0 / sigma**2)
    args = (shapes, weights, ell, ctc, (rgb * rgb_weight, cams), *rest)
    monkeypatch.setattr(mp, "TEXEL_BLOCK", n)
    whole = mp.texel_shapes(*args)
    monkeypatch.setattr(mp, "TEXEL_BLOCK", 256)
    tracemalloc.start()
    try:
        blocked = mp.texel_shapes(*args)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_allclose(blocked, whole, rtol=1e-12, atol=1e-15 * np.abs(whole).max())
    systems = n * n_w * n_w * 8  # every texel's W x W system in float64
    assert peak < systems / 2, (peak, systems)


def _reduceat_group_sum(x, group, size):
    """The shots' columns summed by group as numpy's ``add.reduceat`` sums them."""
    order = np.argsort(group, kind="stable")
    g = np.asarray(group)[order]
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    out = np.zeros((x.shape[0], size))
    out[:, g[starts]] = np.add.reduceat(x[:, order], starts, axis=1)
    return out


@pytest.mark.parametrize("members", [1, 2, 3, 4, 8, 9, 13])
def test_group_sums_are_numpys_reduceat_sums_bit_for_bit(members):
    """A band's or an image's shots summed in one compiled pass: the same sums, bit for bit,
    as numpy's ``add.reduceat`` over the reordered columns (the set model's results do not
    change), for groups of any size (larger than the kernel's: numpy's own), any layout."""
    from spectralize.nodes.reconstruction.estimators.material_pooled import _group_sum
    from spectralize.nodes.reconstruction.kernels import GROUP_SUM_MEMBERS, group_sums

    rng = np.random.default_rng(members)
    size = 5
    group = rng.permutation(np.repeat(np.arange(size - 1), members))  # the last group: empty
    x = rng.normal(size=(300, group.size)) * rng.uniform(1e-3, 1e3, size=group.size)
    x[rng.random(x.shape) < 0.1] = 0.0
    expected = _reduceat_group_sum(x, group, size)
    for layout in (x, np.asfortranarray(x)):
        assert np.array_equal(_group_sum(layout, group, size), expected)
    if members <= GROUP_SUM_MEMBERS:
        order = np.argsort(group, kind="stable").astype(np.int64)
        indptr = np.arange(0, group.size + 1, members, dtype=np.int64)
        out = np.full((x.shape[0], size), 7.0)
        group_sums(x, order, indptr, np.arange(size - 1, dtype=np.int64), out)
        assert np.array_equal(out[:, :-1], expected[:, :-1])
        assert np.all(out[:, -1] == 7.0)  # a column no group goes to is kept


def test_fit_terms_of_every_texel_are_those_of_all_texels_named():
    """The set models' texel-major start ``x0`` of every texel (the cube transposed in one
    copy) is the one of all texels given by index."""
    from spectralize.nodes.reconstruction.estimators.shared_texel import fit_terms

    inputs, _, initial, sigma, _ = _two_material_set(3)
    n = initial.shape[2] * initial.shape[3]
    every = fit_terms(inputs, initial, LIGHT, 1.0, sigma)
    named = fit_terms(inputs, initial, LIGHT, 1.0, sigma, np.arange(n))
    assert every.x0.flags["C_CONTIGUOUS"]
    for name, value in every._asdict().items():
        assert np.array_equal(value, getattr(named, name)), name


def test_a_float32_start_is_cast_once_into_the_fit():
    """The solver's float32 cube becomes the fit's texel-major float64 ``x0`` in one cast
    copy (no float64 copy of the whole cube beside it), and every fixed term, the prior's
    per-image means included, is the float64 cube's bit for bit: so is the refit."""
    import tracemalloc

    from spectralize.nodes.reconstruction.estimators.shared_texel import fit_terms

    inputs, _, initial, sigma, _ = _two_material_set(5, size=24, n_image=12)
    start = initial.astype(np.float32)
    wide = fit_terms(inputs, start.astype(np.float64), LIGHT, 1.0, sigma)
    tracemalloc.start()
    try:
        cast = fit_terms(inputs, start, LIGHT, 1.0, sigma)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert cast.x0.dtype == np.float64 and cast.x0.flags["C_CONTIGUOUS"]
    for name, value in wide._asdict().items():
        assert np.array_equal(value, getattr(cast, name)), name
    assert peak < 1.75 * cast.x0.nbytes, (peak, cast.x0.nbytes)  # a float64 copy: over 2
    refit = material_pooled_refine(inputs, start, LIGHT, band_sigma=sigma)
    assert np.array_equal(
        refit, material_pooled_refine(inputs, start.astype(np.float64), LIGHT, band_sigma=sigma)
    )


@pytest.mark.parametrize("shape", [(32, 20, 30, 26), (5, 3, 7, 9), (3, 2, 1, 1), (8, 3, 100, 3)])
def test_image_means_of_a_float32_cube_are_the_float64_cubes_bit_for_bit(shape):
    """Summed band by band, each band cast on its own, the per-image means are numpy's
    means of the float64 copy bit for bit (C-contiguous or not)."""
    from spectralize.nodes.reconstruction.estimators.shared_texel import image_means

    rng = np.random.default_rng(sum(shape))
    cube = (rng.random(shape) * rng.uniform(0.1, 100.0, size=shape[1])[:, None, None]).astype(np.float32)
    for layout in (cube, np.asfortranarray(cube), cube.astype(np.float64)):
        expected = layout.astype(np.float64).mean(axis=(0, 2, 3))
        assert np.array_equal(image_means(layout), expected)
