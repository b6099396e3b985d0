"""Robertson's fit over pooled images, one image at a time (issue 27, item 4).

``recover_spectral_oecf`` pools the 4 longest unsaturated exposures of each of 32 bands, each
band one "image" (G, E, P) of ``robertson_response``. Its bins (intp) and per-pixel
denominators (float64) for every image at once were 6.4 GB at 2048^2; the fit now builds
``C``, the samples per code and the denominators image by image. Checked here: pooling
images gives what one image holding all their pixels gives (same samples, the same response
to float rounding), pixels without a weighted sample in one image included, and the fit's
traced allocations stay below the bins of all images together (no timing involved).
"""

from __future__ import annotations

import tracemalloc

import numpy as np

from spectralize.nodes.calibration import oecf

BIT_DEPTH = 12  # 4096 codes in 1024 bins: the bins are an intp array, as for the band camera


def _pooled_series(exposure_series, images: int, pixels: int) -> np.ndarray:
    """(image, exposure, pixel) uint16 codes: ``images`` series of one camera (own seeds);
    the first image's last 500 pixels saturated in every exposure (no weighted sample)."""
    codes = np.stack(
        [
            exposure_series("s_curve", bit_depth=BIT_DEPTH, pixels=pixels, seed=g)[0]
            for g in range(images)
        ]
    ).astype(np.uint16)
    codes[0, :, -500:] = 2**BIT_DEPTH - 1
    return codes


def test_pooled_images_equal_one_image_of_all_their_pixels(TIMES, exposure_series) -> None:
    codes = _pooled_series(exposure_series, images=6, pixels=20_000)
    weights = oecf.weighting_function(
        np.arange(2**BIT_DEPTH), black_level=100, saturation=2**BIT_DEPTH - 1
    )
    pooled = oecf.robertson_response(
        codes, TIMES, n_codes=2**BIT_DEPTH, weights=weights, tolerance=1e-10
    )
    one = np.moveaxis(codes, 0, 1).reshape(1, codes.shape[1], -1)  # (1, E, G * P)
    joined = oecf.robertson_response(one, TIMES, n_codes=2**BIT_DEPTH, weights=weights, tolerance=1e-10)
    assert pooled.converged and joined.converged
    np.testing.assert_array_equal(pooled.samples, joined.samples)
    assert pooled.samples.sum() <= codes.size - codes.shape[1] * 500  # the saturated left out
    np.testing.assert_allclose(pooled.response, joined.response, rtol=1e-9, atol=1e-12)


def test_pooled_images_are_folded_one_at_a_time(TIMES, exposure_series) -> None:
    images, pixels = 16, 100_000
    codes = _pooled_series(exposure_series, images=images, pixels=pixels)
    weights = oecf.weighting_function(
        np.arange(2**BIT_DEPTH), black_level=100, saturation=2**BIT_DEPTH - 1
    )
    all_bins = codes.size * np.dtype(np.intp).itemsize  # every image's bins at once: 64 MB
    tracemalloc.start()
    try:
        result = oecf.robertson_response(codes, TIMES, n_codes=2**BIT_DEPTH, weights=weights)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert result.converged
    # one image's bins, denominators and pairs of exposures, and C: well below all the bins
    assert peak < all_bins, (peak, all_bins)
