"""The text of `--set KEY=VALUE`: values parse as JSON or Python literals, formatted values
read back, and a parameter's type is shown without its constraint metadata."""

import pytest

from spectralize.engine import registry
from spectralize.flows.assignments import (
    UsageError,
    format_value,
    parse_assignments,
    parse_value,
    type_text,
)


@pytest.mark.parametrize(
    "text, value",
    [
        ("null", None),
        ("None", None),
        ("[0.5,0.0]", [0.5, 0.0]),
        ("(0.5, 0.0)", (0.5, 0.0)),
        ('"block-jacobi-pcg"', "block-jacobi-pcg"),
        ("block-jacobi-pcg", "block-jacobi-pcg"),
        ("'D65'", "D65"),
        ("true", True),
        ("1e-06", 1e-06),
        ('{"misregistration":[0.5,0.0]}', {"misregistration": [0.5, 0.0]}),
        ("ISO 7589 Photoflood", "ISO 7589 Photoflood"),
        ('"None"', "None"),
    ],
)
def test_set_values(text, value):
    assert parse_value(text) == value


@pytest.mark.parametrize(
    "value", [None, "demo", "None", "null", "1", "", " x", 0.001, (0.05, 1.0), {"a": [1]}]
)
def test_formatted_values_read_back(value):
    back = parse_value(format_value(value))
    assert back == (list(value) if isinstance(value, tuple) else value)


def test_none_is_accepted_for_an_optional_parameter():
    node = registry()["hdr_merge"].node
    (value,) = parse_assignments(["hdr_merge.saturation=None"]).values()
    assert node.parse_parameters({"saturation": value}).saturation is None


def test_an_item_without_equals_sign_is_refused():
    with pytest.raises(UsageError, match="KEY=VALUE"):
        parse_assignments(["dark_average.frames_per_chunk"])


@pytest.mark.parametrize(
    "annotation, shown",
    [
        ("float", "float"),
        ("Annotated[float, FieldInfo(metadata=[Gt(gt=0)])]", "float"),
        (
            "tuple[Annotated[float, FieldInfo(metadata=[Ge(ge=0), Le(le=1)])], ...]",
            "tuple[float, ...]",
        ),
        ("Annotated[str, Choices(['a', 'b'])] | None", "str | None"),
    ],
)
def test_type_text_drops_constraint_metadata(annotation, shown):
    assert type_text(annotation) == shown
