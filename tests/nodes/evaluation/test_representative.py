"""Representative spectra are the pixels at the asked quantiles of the nRMSE map."""

import numpy as np
import pytest
from support.checker import (
    checker_truth,
)

from spectralize.nodes.evaluation.pixel_metrics import normalised_rmse
from spectralize.nodes.evaluation.representative import representative_spectra


def test_representative_spectra_are_picked_at_low_and_high_error():
    truth = checker_truth(n_image=2)
    rng = np.random.default_rng(1)
    noise = rng.standard_normal(truth.radiance.shape).astype(np.float32)
    spectra = truth.copy(deep=True)
    spectra["radiance"] = truth.radiance * (1 + 0.03 * noise)
    nrmse = normalised_rmse(spectra, truth)
    picks = representative_spectra(nrmse, spectra, truth, quantiles=(0.0, 0.5, 1.0)).compute()
    for image in range(2):
        errors = nrmse[image].values
        y, x = int(picks.sample_y[image, 2]), int(picks.sample_x[image, 2])
        assert errors[y, x] == errors.max()  # worst pixel
        y0, x0 = int(picks.sample_y[image, 0]), int(picks.sample_x[image, 0])
        assert errors[y0, x0] == errors.min()  # best pixel
        np.testing.assert_array_equal(picks.sample_truth[image, 2], truth.radiance[image, :, y, x])
        np.testing.assert_array_equal(
            picks.sample_reconstruction[image, 2], spectra.radiance[image, :, y, x]
        )
        assert float(picks.sample_nrmse[image, 1]) == pytest.approx(
            float(np.quantile(errors, 0.5)), abs=float(np.ptp(errors)) / 20
        )
    assert picks.sample_quantile.values.tolist() == [0.0, 0.5, 1.0]
    with pytest.raises(ValueError, match="ascending"):
        representative_spectra(nrmse, spectra, truth, quantiles=(0.9, 0.1))
