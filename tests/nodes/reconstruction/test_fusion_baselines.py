"""The fusion baselines "hysure" and "cnmf": the filtered bands fused with the RGB."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from spectralize.nodes.filter_size import FILTER_TRUNCATE, filter_sigma
from spectralize.nodes.reconstruction import BASELINE_METHODS, inputs_from_xarray, reconstruct
from spectralize.nodes.reconstruction.baselines import cnmf, filtered_bands, fusion_data, hysure
from spectralize.nodes.reconstruction.baselines.cnmf import coupled_endmembers
from spectralize.nodes.reconstruction.baselines.fusion import (
    adjoint_differences,
    blur_spectrum,
    dct2,
    difference_spectrum,
    forward_differences,
    idct2,
    leading_subspace,
)
from spectralize.nodes.reconstruction.baselines.hysure import (
    hysure_admm,
    hysure_objective,
    hysure_problem,
)
from spectralize.nodes.reconstruction.inputs import ReconstructionInputs
from spectralize.schemas.errors import ReconstructionError


def _low_rank(scene_factory, **options):
    """Noise-free stripes of 3 materials under smooth shading: every spectrum is a
    nonnegative mixture of 3 endmembers, with sharp edges the filter blurs away."""
    scene = scene_factory(
        size=24, n_wavelength=8, n_materials=3, shading=True, filter_size=6.0, **options
    )
    inputs = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    return inputs, np.moveaxis(scene.truth, 1, 0)  # truth (wavelength, image, y, x)


def _relative_rms(cube, truth):
    return float(np.sqrt(np.mean((cube - truth) ** 2)) / truth.mean())


SET_SHOTS = {0: list(range(8)), 1: [0, 3, 5]}


@pytest.mark.parametrize("shots", [None, SET_SHOTS], ids=["single", "set"])
def test_hysure_recovers_a_three_endmember_mixture(scene_factory, shots):
    options = {} if shots is None else {"n_images": 2, "shots": shots}
    inputs, truth = _low_rank(scene_factory, **options)
    cube = hysure(inputs, subspace=3)
    assert cube.shape == truth.shape
    # in the set, E is learnt from the filtered bands with image 1's missing bands predicted
    # from its RGB, which leaves the truth's subspace a little
    assert _relative_rms(cube, truth) < (2e-3 if shots is None else 1.5e-2)
    # the filtered bands alone miss the edges by far: the RGB put them back
    assert _relative_rms(filtered_bands(inputs), truth) > 5 * _relative_rms(cube, truth)


@pytest.mark.parametrize("shots", [None, SET_SHOTS], ids=["single", "set"])
def test_cnmf_recovers_a_three_endmember_mixture(scene_factory, shots):
    options = {} if shots is None else {"n_images": 2, "shots": shots}
    inputs, truth = _low_rank(scene_factory, **options)
    cube = cnmf(inputs, n_endmembers=3)
    assert cube.shape == truth.shape
    assert cube.min() >= 0
    assert _relative_rms(cube, truth) < 1e-2
    assert _relative_rms(filtered_bands(inputs), truth) > 5 * _relative_rms(cube, truth)


def test_hysure_objective_decreases_to_the_truths(scene_factory):
    inputs, truth = _low_rank(scene_factory)
    data = fusion_data(inputs, "hysure")
    basis = leading_subspace(data.start.reshape(data.n_wavelength, -1), 3)
    problem = hysure_problem(data, 0, basis)
    settings = {"lambda_m": 100.0, "lambda_phi": 0.01}
    _, history = hysure_admm(problem, mu=0.5, iterations=60, record_objective=True, **settings)
    assert len(history) == 61
    checkpoints = np.array(history)[[0, 5, 10, 20, 40, 60]]
    assert np.all(np.diff(checkpoints) < 0), checkpoints
    coefficients = (basis.T @ truth[:, 0].reshape(8, -1)).reshape(3, 24, 24) / data.scale
    at_truth = hysure_objective(problem, coefficients, **settings)
    assert history[-1] <= at_truth * 1.001


def test_the_dct_domain_operators_are_the_filters_and_differences():
    rng = np.random.default_rng(3)
    plane = rng.normal(size=(17, 22))
    for size in (3.0, 8.0):
        sigma = filter_sigma(size)
        expected = ndimage.gaussian_filter(plane, sigma, mode="reflect", truncate=FILTER_TRUNCATE)
        np.testing.assert_allclose(
            idct2(blur_spectrum(size, 17, 22) * dct2(plane)), expected, atol=1e-12
        )
    horizontal, vertical = forward_differences(plane)
    laplacian = adjoint_differences(horizontal, vertical)
    np.testing.assert_allclose(idct2(difference_spectrum(17, 22) * dct2(plane)), laplacian, atol=1e-12)
    other = rng.normal(size=(2, 17, 22))
    assert np.isclose(
        np.sum(horizontal * other[0] + vertical * other[1]),
        np.sum(plane * adjoint_differences(other[0], other[1])),
    )


def test_cnmf_coupled_step_blurs_the_abundances_shot_by_shot(scene_factory):
    scene = scene_factory(size=16, n_wavelength=4, noise=0.05, shots={0: [0, 1, 2, 3, 1]})
    bands = scene.bands.assign_coords(filter_size=("shot", [2.0, 3.0, 5.0, 4.0, 6.0]))
    data = fusion_data(inputs_from_xarray(scene.rgb, bands, scene.camera_matrix), "cnmf")
    rng = np.random.default_rng(1)
    w_h, h_m = rng.uniform(0.5, 1.0, (4, 2)), rng.uniform(0.0, 1.0, (2, 1, 256))
    # one update by hand, in image space: w_b <- w_b * sum_i <Y_i, B_i H> / (w_b sum_i G_i G_i^T)
    numerator, gram = np.zeros((4, 2)), np.zeros((4, 2, 2))
    for i, (band, size) in enumerate(zip(data.band, bands["filter_size"].values, strict=True)):
        blurred = np.stack(
            [
                ndimage.gaussian_filter(
                    h.reshape(16, 16), filter_sigma(size), mode="reflect", truncate=FILTER_TRUNCATE
                ).ravel()
                for h in h_m[:, 0]
            ]
        )
        numerator[band] += blurred @ data.shots[i].ravel()
        gram[band] += blurred @ blurred.T
    expected = w_h * np.maximum(numerator, 0) / np.einsum("bk,bkl->bl", w_h, gram)
    np.testing.assert_allclose(coupled_endmembers(data, w_h, h_m, 1), expected, rtol=1e-9)


@pytest.mark.parametrize("method", ["hysure", "cnmf"])
def test_fusion_baselines_through_reconstruct_on_a_set(scene_factory, method):
    scene = scene_factory(
        size=20, n_wavelength=6, n_images=3, noise=0.05, shots={0: [0, 1, 2, 3], 1: [4, 5]}
    )
    result = reconstruct(scene.rgb, scene.bands, scene.camera_matrix, method=method, full_output=True)
    out = result.spectra
    assert out.dims == ("image", "wavelength", "y", "x")
    assert out.shape == (3, 6, 20, 20)  # image 2 has no band shot: from its RGB
    assert out.attrs["method"] == method and result.iterations == 0
    assert np.isfinite(out.values).all()
    record = BASELINE_METHODS[method]
    for name, value in record.settings.items():
        assert out.attrs[name] == value
    # the RGB is reproduced closely (RGB term weighted high / abundances fitted to it)
    rgb = np.einsum("cw,mwyx->myxc", scene.camera_matrix.values, out.values)
    error = np.abs(rgb - scene.rgb.values).mean() / scene.rgb.values.mean()
    assert error < 0.05


def _inputs_without(shots: list[int], n_wavelength: int = 4) -> ReconstructionInputs:
    rng = np.random.default_rng(0)
    wavelength = np.linspace(450.0, 650.0, n_wavelength)
    camera = np.exp(-0.5 * ((wavelength[None] - np.array([[600.0], [540.0], [460.0]])) / 40.0) ** 2)
    return ReconstructionInputs(
        rgb=rng.uniform(0.1, 1.0, (1, 12, 12, 3)),
        band_data=rng.uniform(0.1, 1.0, (len(shots), 12, 12)),
        band=np.asarray(shots, dtype=np.intp),
        image=np.zeros(len(shots), dtype=np.intp),
        filter_size=np.full(len(shots), 3.0),
        camera_matrix=camera,
        wavelength=wavelength,
    )


@pytest.mark.parametrize("function", [hysure, cnmf])
def test_missing_band_shots_raise_naming_the_bands(function):
    with pytest.raises(
        ReconstructionError, match=r"bands: .*expected at least one band shot, found none"
    ):
        function(_inputs_without([]))
    with pytest.raises(ReconstructionError, match=r"bands: .*found none of \[516\.6"):
        function(_inputs_without([0, 2, 3]))


def test_settings_out_of_range_raise_naming_the_setting(scene_factory):
    inputs, _ = _low_rank(scene_factory)
    with pytest.raises(ReconstructionError, match="subspace: expected an integer >= 1, found 0"):
        hysure(inputs, subspace=0)
    with pytest.raises(ReconstructionError, match="mu: expected a finite number > 0"):
        hysure(inputs, mu=0.0)
    with pytest.raises(ReconstructionError, match="n_endmembers: expected an integer >= 1"):
        cnmf(inputs, n_endmembers=0)
