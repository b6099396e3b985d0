"""Tests of spectralize.nodes.calibration.oecf.weighting: the weighting table and dispatcher."""

from __future__ import annotations

import numpy as np
import pytest

from spectralize.nodes.calibration import oecf
from spectralize.schemas import CalibrationError


def test_weighting_functions() -> None:
    codes = np.arange(0, 101)
    for kind in ("gaussian", "hat", "uniform"):
        w = oecf.weighting_function(codes, black_level=10, saturation=90, kind=kind)
        assert w[:11].max() == 0 and w[90:].max() == 0
        assert w[50] == pytest.approx(1.0)
        assert np.all((w >= 0) & (w <= 1))
    w = oecf.weighting_function(codes, black_level=0, saturation=100)
    np.testing.assert_allclose(w[:50], w[100:50:-1])


def test_unknown_weighting_names_the_known_ones() -> None:
    with pytest.raises(CalibrationError, match="weighting 'box' is unknown"):
        oecf.weighting_function(np.arange(3), black_level=0, saturation=2, kind="box")
