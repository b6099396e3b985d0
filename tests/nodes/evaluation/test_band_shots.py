"""Which images have band shots."""

import pytest
import xarray as xr
from support.checker import (
    shots_for,
)

from spectralize.nodes.evaluation.band_shots import band_shot_images
from spectralize.schemas import SchemaError


def test_band_shot_images():
    has = band_shot_images(shots_for([0, 0, 2]), 4)
    assert has.dims == ("image",) and has.values.tolist() == [True, False, True, False]
    with pytest.raises(SchemaError, match="shots:image"):
        band_shot_images(xr.Dataset(coords={"wavelength": ("shot", [500.0])}), 4)
