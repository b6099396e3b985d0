"""The evaluate node: its inputs, parameters, choices and place in a graph."""

import pytest
from support.checker import (
    checker_truth,
    raw_spectral_for,
)

from spectralize.engine import Step, check_graph
from spectralize.nodes.evaluation.declarations import EVALUATE
from spectralize.schemas import ParameterError


def test_node_declaration_runs_and_validates_parameters():
    truth = checker_truth(n_image=2)
    result = EVALUATE(
        {"spectra": truth, "truth": truth, "shots": raw_spectral_for([0])},
        {"threshold": 0.02, "sample_quantiles": [0.5, 1.0]},
    )
    assert set(result) == {"evaluation"}
    assert result["evaluation"].sizes["sample"] == 2
    assert result["evaluation"].attrs["threshold"] == 0.02
    assert EVALUATE.inputs == {"spectra": "spectra", "truth": "truth/spectra", "shots": "raw/spectral"}
    with pytest.raises(ParameterError, match="illuminant"):
        EVALUATE.parse_parameters({"illuminant": "D-nonsense"})
    with pytest.raises(ParameterError, match="unknown parameter"):
        EVALUATE.parse_parameters({"colour": 1})
    with pytest.raises(ParameterError, match="ascending"):
        EVALUATE.parse_parameters({"sample_quantiles": [0.9, 0.1]})
    assert "D65" in EVALUATE.parameter_choices()["illuminant"]
    assert "E" in EVALUATE.parameter_choices()["illuminant"]
    assert set(EVALUATE.parameters.model_fields) == {
        "illuminant",
        "threshold",
        "histogram_bins",
        "histogram_max",
        "sample_quantiles",
    }
    planned = check_graph(
        [Step("evaluate")],
        nodes={"evaluate": EVALUATE},
        available={
            "spectra": "spectra",
            "truth/spectra": "truth/spectra",
            "raw/spectral": "raw/spectral",
        },
    )
    assert [p.outputs for p in planned] == [{"evaluation": "evaluation"}]
