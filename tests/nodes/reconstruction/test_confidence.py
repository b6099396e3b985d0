"""The per-pixel confidence: estimated on a region (a tile's core) as on the whole window."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.reconstruction.confidence import neighbourhood_spread
from spectralize.nodes.reconstruction.neighbourhoods import appearance_features, appearance_neighbours


@pytest.mark.parametrize("given", [False, True])
def test_a_region_gets_the_estimates_of_the_whole_window(given):
    rng = np.random.default_rng(5)
    n_image, height, width = 3, 12, 10
    rgb = rng.uniform(0.1, 1.0, size=(n_image, height, width, 3))
    cube = rng.uniform(0.0, 1.0, size=(8, n_image, height, width))
    neighbours = None
    if given:
        pixels = np.moveaxis(rgb, -1, 0).reshape(3, -1)
        features = appearance_features(pixels, (n_image, height, width), space="chromaticity-spatial")
        neighbours = appearance_neighbours(features, k=6)
    region = (slice(2, 9), slice(3, 7))
    whole = neighbourhood_spread(cube, rgb, neighbours=neighbours)
    core = neighbourhood_spread(cube, rgb, neighbours=neighbours, region=region)
    np.testing.assert_array_equal(core[:, region[0], region[1]], whole[:, region[0], region[1]])
    outside = np.ones(core.shape, dtype=bool)
    outside[:, region[0], region[1]] = False
    assert np.isnan(core[outside]).all()
