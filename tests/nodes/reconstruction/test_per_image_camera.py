"""One camera matrix per image (issue 25): images of several RGB cameras, each through its own C.

Eq. 1's RGB term ``||C_m S(p) - R(p)||^2`` with ``C_m`` the matrix of the camera that took
image ``m``; the 2-D ``C`` is the special case of one camera for every image.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import xarray as xr

from spectralize.nodes.reconstruction import build_problem, inputs_from_xarray, reconstruct
from spectralize.nodes.reconstruction.inputs import camera_blocks
from spectralize.nodes.reconstruction.operators import rgb_adjoint, rgb_forward
from spectralize.nodes.reconstruction.set_reconstruction import _camera_matrix
from spectralize.nodes.reconstruction.solvers import (
    BlockJacobiPreconditioner,
    block_jacobi_pcg,
    paper_cg,
    prior_pcg,
)
from spectralize.schemas.errors import ReconstructionError

from .conftest import smooth_spectra


def other_camera(wavelength: np.ndarray) -> np.ndarray:
    """A camera of another model: narrower channels at other peaks, a second red lobe in
    the blue (as real sensors have), 0.7x the gain."""
    centres = np.array([[625.0, 455.0], [515.0, 0.0], [450.0, 0.0]])
    lobes = np.array([[1.0, 0.25], [1.0, 0.0], [1.0, 0.0]])
    width = np.array([22.0, 25.0, 18.0])
    curves = sum(
        lobes[:, j, None]
        * np.exp(-0.5 * ((wavelength[None] - centres[:, j, None]) / width[:, None]) ** 2)
        for j in range(2)
    )
    return 0.7 * curves


def to_camera(source: np.ndarray, target: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """The least-squares 3 x 3 ``T`` with ``T source s ~ target s`` over ``spectra`` (n, w)."""
    a, b = spectra @ source.T, spectra @ target.T
    return np.linalg.lstsq(a, b, rcond=None)[0].T


@pytest.fixture
def two_cameras(scene_factory):
    """Two images of one scene of five shaded materials: image 0 of the paired camera with
    every band, image 1 of another camera model without bands; image 1's RGB mapped into
    the paired camera's RGB by a 3 x 3 map fitted on other spectra (as the calibration's
    ``rgb_transform``). Returns the scene (its ``rgb`` as the paired camera would have seen
    both), the mapped RGB and the per-image ``C`` that holds for it (``[C, T C_side]``)."""
    scene = scene_factory(
        size=24,
        n_wavelength=10,
        n_images=2,
        n_materials=5,
        shading=True,
        noise=0.01,
        shots={0: list(range(10))},
        seed=3,
    )
    wavelength = scene.camera_matrix["wavelength"].values
    paired = scene.camera_matrix.values
    side = other_camera(wavelength)
    fit = smooth_spectra(np.random.default_rng(11), wavelength, 24)  # not the scene's spectra
    transform = to_camera(side, paired, fit)
    mapped = scene.rgb.values.copy()
    mapped[1] = np.einsum("cw,wyx->yxc", transform @ side, scene.truth[1])
    per_image = np.stack([paired, transform @ side])
    return scene, scene.rgb.copy(data=mapped), per_image


def _nrmse(cube: np.ndarray, truth: np.ndarray) -> float:
    """Median per-pixel ``|S - T| / |T|`` of one image (wavelength, y, x)."""
    return float(np.median(np.linalg.norm(cube - truth, axis=0) / np.linalg.norm(truth, axis=0)))


def test_each_image_through_its_own_camera_beats_the_3x3_map(two_cameras):
    scene, mapped, per_image = two_cameras
    c = scene.camera_matrix
    own = xr.DataArray(
        per_image,
        dims=("image", "channel", "wavelength"),
        coords={"image": [0, 1], "channel": c["channel"].values, "wavelength": c["wavelength"].values},
    )
    # the mixture preset: the default's natural prior (a Wiener estimate, through the same
    # camera matrix) reduces the 3 x 3 map's error, and with it this margin
    method = "mixture-prior-pcg"
    one_c = reconstruct(mapped, scene.bands, c, method=method).values  # the 3 x 3 map taken as exact
    per_image_c = reconstruct(mapped, scene.bands, own, method=method).values
    same_camera = reconstruct(
        scene.rgb, scene.bands, c, method=method
    ).values  # both images of the paired camera
    # the other camera's image: its own C fits its RGB, the 3 x 3 map (1 % off) does not
    shared_error = _nrmse(one_c[1], scene.truth[1])
    own_error = _nrmse(per_image_c[1], scene.truth[1])
    floor = _nrmse(same_camera[1], scene.truth[1])
    assert own_error < 0.6 * shared_error, (own_error, shared_error)
    assert own_error < 1.25 * floor + 1e-3, (own_error, floor)
    # its RGB is reproduced through its own camera's C
    rgb_back = np.einsum("cw,wyx->yxc", per_image[1], per_image_c[1])
    assert np.median(np.abs(rgb_back - mapped.values[1]) / np.abs(mapped.values[1])) < 0.02
    # the paired camera's image is not made worse
    assert _nrmse(per_image_c[0], scene.truth[0]) < 1.1 * _nrmse(one_c[0], scene.truth[0]) + 1e-3


def test_cameras_picked_by_the_rgb_camera_coordinate_and_images_matched_by_label(two_cameras):
    scene, mapped, per_image = two_cameras
    c = scene.camera_matrix
    coords = {"channel": c["channel"].values, "wavelength": c["wavelength"].values}
    by_camera = xr.DataArray(
        per_image[::-1], dims=("camera", "channel", "wavelength"), coords={"camera": [7, 3], **coords}
    )
    rgb = mapped.assign_coords(camera=("image", [3, 7]))
    inputs = inputs_from_xarray(rgb, scene.bands, by_camera)
    np.testing.assert_array_equal(inputs.camera_matrix, per_image)
    by_label = xr.DataArray(
        per_image[::-1].transpose(0, 2, 1),
        dims=("image", "wavelength", "channel"),
        coords={"image": [1, 0], **coords},
    ).transpose("image", "wavelength", "channel")
    np.testing.assert_array_equal(
        inputs_from_xarray(mapped, scene.bands, by_label).camera_matrix, per_image
    )
    # one camera for every image is the 2-D C
    same = xr.DataArray(
        np.stack([c.values, c.values]), dims=("image", "channel", "wavelength"), coords=coords
    )
    assert inputs_from_xarray(mapped, scene.bands, same).camera_matrix.ndim == 2


@pytest.fixture
def problems(scene_factory):
    """The same problem with a 2-D C and with that C once per image (3-D)."""
    scene = scene_factory(
        size=16, n_wavelength=6, n_images=3, shading=True, noise=0.03, shots={0: list(range(6)), 1: [2]}
    )
    flat = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    stacked = dataclasses.replace(flat, camera_matrix=np.stack([flat.camera_matrix] * 3))
    return build_problem(flat, k=3), build_problem(stacked, k=3)


@pytest.mark.parametrize(
    "solve",
    [
        lambda p: block_jacobi_pcg(p, tolerance=1e-6, max_iterations=200),
        lambda p: paper_cg(p, tolerance=1e-12, max_iterations=8),
        lambda p: prior_pcg(p, spectral_prior=0.1, prior_source="mixture", max_iterations=50),
        lambda p: prior_pcg(p, spectral_prior=0.1, prior_source="training", max_iterations=50),
    ],
    ids=["block-jacobi-pcg", "paper-cg", "mixture-prior", "wiener-centred-prior"],
)
def test_one_c_per_image_identical_to_the_2d_c_gives_the_same_result(problems, solve):
    flat, stacked = problems
    assert stacked.extras["camera_scale"] == flat.extras["camera_scale"]
    one, per_image = solve(flat), solve(stacked)
    assert per_image.iterations == one.iterations
    scale = np.abs(one.cube).max()
    np.testing.assert_allclose(per_image.cube, one.cube, rtol=0, atol=1e-5 * scale)


@pytest.mark.parametrize("method", ["pseudo-inverse", "wiener", "mallett2019", "guided-projected"])
def test_baselines_take_one_c_per_image(two_cameras, method):
    scene, mapped, per_image = two_cameras
    c = scene.camera_matrix
    coords = {"channel": c["channel"].values, "wavelength": c["wavelength"].values}
    own = xr.DataArray(per_image, dims=("image", "channel", "wavelength"), coords=coords)
    cube = reconstruct(mapped, scene.bands, own, method=method).values
    if method != "guided-projected":  # per pixel: image 1 as with its C for every image
        alone = reconstruct(mapped, scene.bands, c.copy(data=per_image[1]), method=method).values
        np.testing.assert_allclose(cube[1], alone[1], rtol=1e-4, atol=1e-6)
    # every image reproduces its own RGB through its own C (all but mallett's basis exactly)
    back = np.einsum("mcw,mwyx->myxc", per_image, cube.astype(np.float64))
    assert np.median(np.abs(back - mapped.values) / np.abs(mapped.values)) < 1e-3


def test_forward_and_adjoint_are_per_image_and_adjoint_to_each_other():
    rng = np.random.default_rng(0)
    c = rng.random((2, 3, 5))
    cube = rng.normal(size=(5, 2, 3, 4))
    out = rgb_forward(cube, c).reshape(3, 2, 12)
    for m in range(2):
        np.testing.assert_allclose(out[:, m], c[m] @ cube[:, m].reshape(5, -1))
    r = rng.normal(size=(3, 24))
    lhs = float(np.sum(rgb_forward(cube, c) * r))
    rhs = float(np.sum(cube * rgb_adjoint(r, c, cube.shape)))
    assert lhs == pytest.approx(rhs, rel=1e-12)


def test_normal_operator_and_preconditioner_with_one_c_per_image(scene_factory):
    scene = scene_factory(
        size=14, n_wavelength=5, n_images=3, shading=True, noise=0.05, shots={0: [0, 1, 2, 3, 4]}
    )
    flat = inputs_from_xarray(scene.rgb, scene.bands, scene.camera_matrix)
    rng = np.random.default_rng(4)
    cs = np.stack([flat.camera_matrix, rng.random((3, 5)) + 0.1, flat.camera_matrix])
    problem = build_problem(dataclasses.replace(flat, camera_matrix=cs))
    blocks, index = problem.camera_blocks()
    assert blocks.shape[0] == 2 and index.tolist() == [0, 1, 0]
    cube = rng.normal(size=problem.shape)
    for kind in ("natural", "appearance"):
        order = problem.pixel_order(kind)
        got = order.to_cube(problem.normal_pixels(order.to_pixels(cube), order=order, epsilon=0.1))
        np.testing.assert_allclose(
            got, problem.apply_adjoint(problem.apply(cube)) + 0.1 * cube, rtol=1e-9, atol=1e-9
        )
    # the block-Jacobi preconditioner inverts every pixel's block with its image's C
    order = problem.pixel_order("appearance")
    preconditioner = BlockJacobiPreconditioner(problem, np.float64, ridge=1e-3, order=order)
    w, n_wavelength = problem.weights, problem.shape[0]
    diagonal = w.alpha * problem.filters.normal_diagonal().reshape(n_wavelength, problem.shape[1], -1)
    diagonal += (
        w.gamma * problem.neighbours.degree.reshape(1, problem.shape[1], -1) + preconditioner.ridge
    )
    flat_cube = cube.reshape(n_wavelength, problem.shape[1], -1)
    c = problem.camera_matrix
    applied = diagonal * flat_cube + w.beta * np.einsum("mcw,mcv,vmn->wmn", c, c, flat_cube)
    np.testing.assert_allclose(
        preconditioner(applied.reshape(problem.shape)), cube, rtol=1e-8, atol=1e-8
    )


def test_bad_per_image_camera_matrices_are_refused_naming_camera_matrix(two_cameras):
    scene, mapped, per_image = two_cameras
    c = scene.camera_matrix
    coords = {"channel": c["channel"].values, "wavelength": c["wavelength"].values}
    three = xr.DataArray(
        np.stack([per_image[0]] * 3), dims=("image", "channel", "wavelength"), coords=coords
    )
    with pytest.raises(
        ReconstructionError, match=r"camera_matrix: expected one matrix per rgb image \(2\), found 3"
    ):
        reconstruct(mapped, scene.bands, three)
    by_camera = xr.DataArray(
        per_image, dims=("camera", "channel", "wavelength"), coords={"camera": [0, 1], **coords}
    )
    with pytest.raises(
        ReconstructionError, match=r"camera_matrix: dims \(camera, channel, wavelength\) need rgb's"
    ):
        reconstruct(mapped, scene.bands, by_camera)
    with pytest.raises(ReconstructionError, match=r"found none for camera\(s\) \[5\]"):
        reconstruct(mapped.assign_coords(camera=("image", [0, 5])), scene.bands, by_camera)
    flat_rank = per_image.copy()
    flat_rank[1, 2] = flat_rank[1, 1]
    rank = xr.DataArray(flat_rank, dims=("image", "channel", "wavelength"), coords=coords)
    with pytest.raises(ReconstructionError, match=r"camera_matrix of image 1: expected rank 3"):
        reconstruct(mapped, scene.bands, rank)
    unnamed = xr.DataArray(per_image, dims=("lens", "channel", "wavelength"), coords=coords)
    with pytest.raises(
        ReconstructionError, match=r"camera_matrix: expected dims \('image', 'channel', 'wavelength'\)"
    ):
        reconstruct(mapped, scene.bands, unnamed)
    with pytest.raises(
        ReconstructionError, match=r"camera_matrix: expected \(3, n_wavelength\) or \(n_image=2"
    ):
        camera_blocks(np.zeros((3, 3, 5)), 2)


def _calibration(paired: np.ndarray, side: np.ndarray, transform: np.ndarray, wavelength) -> xr.Dataset:
    coords = {"channel": ["R", "G", "B"], "wavelength": wavelength}
    return xr.Dataset(
        {
            "camera_matrix": (("channel", "wavelength"), paired),
            "camera_matrices": (("camera", "channel", "wavelength"), np.stack([paired, side, paired])),
            "rgb_transform": (
                ("camera", "channel", "channel_in"),
                np.stack([np.eye(3), transform, np.eye(3)]),
            ),
        },
        coords={"camera": [0, 1, 2], "channel_in": ["R", "G", "B"], **coords},
    )


def test_the_run_picks_each_camera_s_matrix_in_the_paired_camera_s_rgb():
    wavelength = np.linspace(450.0, 650.0, 9)
    rng = np.random.default_rng(1)
    paired, side = rng.random((3, 9)) + 0.1, rng.random((3, 9)) + 0.1
    transform = np.array([[1.2, 0.1, 0.0], [0.0, 0.9, 0.05], [0.0, -0.1, 1.1]])
    calibration = _calibration(paired, side, transform, wavelength)
    hdr = xr.Dataset(
        {"radiance": (("image", "channel"), np.ones((3, 3)))}, coords={"camera": ("image", [0, 1, 0])}
    )
    bands = wavelength[::2]
    picked = _camera_matrix(calibration, bands, hdr)
    assert picked.dims == ("camera", "channel", "wavelength") and picked["camera"].values.tolist() == [
        0,
        1,
    ]
    np.testing.assert_allclose(picked.sel(camera=1).values, transform @ side[:, ::2])
    np.testing.assert_allclose(picked.sel(camera=0).values, paired[:, ::2])
    # only the paired camera's images, a C given alone, or no per-image camera: today's one C
    for group, images in [
        (calibration, hdr.isel(image=[0, 2])),
        (calibration[["camera_matrix"]], hdr),
        (calibration, hdr.drop_vars("camera")),
    ]:
        one = _camera_matrix(group, bands, images)
        assert one.dims == ("channel", "wavelength")
        np.testing.assert_allclose(one.values, paired[:, ::2])
    with pytest.raises(
        ReconstructionError, match=r"camera_matrices has no matrix for RGB camera\(s\) \[4\]"
    ):
        _camera_matrix(calibration, bands, hdr.assign_coords(camera=("image", [0, 4, 0])))
