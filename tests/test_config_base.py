"""Shared schema machinery: the commented YAML of ``starnav init`` (``config_base.commented_yaml``).

The written text is checked exactly on a small model (every layout case: a nested section, a
list of sections, a tagged union, an unused optional section, a free mapping), and on the real
scenario through YAML's own parser: every key's comment block is its field's description.
"""

from __future__ import annotations

from typing import Annotated, Literal

import pytest
import yaml
from pydantic import Field

from starnav.config import Scenario, scenario_to_dict
from starnav.config_base import StrictModel, commented_yaml, field_comment, field_models


class _Inner(StrictModel):
    gain: Annotated[float, Field(gt=0, le=1)] = Field(0.5, description="a gain [-]")


class _Item(StrictModel):
    row: Annotated[int, Field(ge=0)] = Field(description="a row [px]")
    tag: str = Field("a", description="a label")


class _TagA(StrictModel):
    kind: Literal["a"] = Field("a", description="tag a")


class _TagB(StrictModel):
    kind: Literal["b"] = Field("b", description="tag b")
    size_m: float = Field(2.0, description="a size [m]")


class _Top(StrictModel):
    mode: Literal["x", "y"] = Field("x", description="a mode")
    inner: _Inner = Field(default_factory=_Inner, description="a section")
    items: tuple[_Item, ...] = Field((), description="some items")
    opt: _Inner | None = Field(None, description="an optional section")
    body: Annotated[_TagA | _TagB, Field(discriminator="kind")] = Field(
        default_factory=_TagA, description="a tagged union")
    table: dict[str, float] = Field(default_factory=dict, description="a free mapping")
    seed: Annotated[int, Field(ge=0)] | None = Field(None, description="a seed")


def test_the_commented_text_of_a_small_model_is_exact():
    data = _Top(items=({"row": 3}, {"row": 4, "tag": "b"}), body={"kind": "b"},
                table={"k": 1.5}).model_dump(mode="json")
    assert commented_yaml(_Top, data) == (
        "# a mode; one of: x, y\n"
        "mode: x\n"
        "\n"
        "# a section\n"
        "inner:\n"
        "  # a gain [-]; range (0, 1]\n"
        "  gain: 0.5\n"
        "\n"
        "# some items\n"
        "items:\n"
        "  # a row [px]; >= 0\n"
        "  - row: 3\n"
        "    # a label\n"
        "    tag: a\n"
        "  # a row [px]; >= 0\n"
        "  - row: 4\n"
        "    # a label\n"
        "    tag: b\n"
        "\n"
        "# an optional section\n"
        "opt: null\n"
        "# opt:  (example: _Inner at its defaults)\n"
        "#   # a gain [-]; range (0, 1]\n"
        "#   gain: 0.5\n"
        "\n"
        "# a tagged union\n"
        "body:\n"
        "  # tag b; one of: b\n"
        "  kind: b\n"
        "  # a size [m]\n"
        "  size_m: 2.0\n"
        "\n"
        "# a free mapping\n"
        "table: {k: 1.5}\n"
        "\n"
        "# a seed; >= 0\n"
        "seed: null\n")
    assert yaml.safe_load(commented_yaml(_Top, data)) == data


@pytest.mark.parametrize("annotation, expected", [
    (Annotated[float, Field(gt=0)], "d; > 0"),
    (Annotated[float, Field(ge=0, lt=360)], "d; range [0, 360)"),
    (Annotated[int, Field(le=17)] | None, "d; <= 17"),
    (Literal["a", "b"] | None, "d; one of: a, b, null"),
    (float, "d"),
])
def test_field_comment_states_the_choices_or_the_range(annotation, expected):
    class M(StrictModel):
        x: annotation = Field(None, description="d")  # type: ignore[valid-type]

    assert field_comment(M.model_fields["x"]) == expected


def _models(model, seen):
    for f in model.model_fields.values():
        for m in field_models(f.annotation):
            if m not in seen:
                seen.append(m)
                _models(m, seen)
    return seen


def test_every_scenario_key_has_a_description():
    """Every field of every section (and of future ones) documents itself: `starnav init`
    writes this description above the key."""
    missing = [f"{m.__name__}.{name}" for m in _models(Scenario, [Scenario])
               for name, f in m.model_fields.items() if not (f.description or "").strip()]
    assert missing == []


def _check_comments(node, model, lines, path, checked):
    """Every key of a YAML mapping node has, right above it, the comment block of its field."""
    for key, value in node.value:
        field = model.model_fields[key.value]
        row = key.start_mark.line
        block = []
        while row > 0 and lines[row - 1].lstrip().startswith("#"):
            row -= 1
            block.insert(0, lines[row].strip().removeprefix("#").strip())
        where = f"{path}{key.value} (line {key.start_mark.line + 1})"
        assert " ".join(block) == field_comment(field), where
        checked.append(where)
        models = field_models(field.annotation)
        if isinstance(value, yaml.MappingNode) and models:
            kind = {k.value: v.value for k, v in value.value}.get("kind")
            sub = next(m for m in models if kind is None
                       or m.model_fields["kind"].default == kind)
            _check_comments(value, sub, lines, f"{path}{key.value}.", checked)
        elif isinstance(value, yaml.SequenceNode) and models:
            for item in value.value:
                if isinstance(item, yaml.MappingNode):
                    _check_comments(item, models[0], lines, f"{path}{key.value}[].", checked)


def test_every_key_of_the_scenario_carries_its_description():
    sc = Scenario.model_validate({"detector": {"readout": {"windows": [
        {"row0": 1, "col0": 2, "height": 5, "width": 5}]}}})
    text = commented_yaml(Scenario, scenario_to_dict(sc))
    checked: list[str] = []
    _check_comments(yaml.compose(text), Scenario, text.splitlines(), "", checked)
    assert "detector.readout.windows[].width (line" in " ".join(checked)
    assert len(checked) > 250  # the whole scenario, not a section of it
    assert Scenario.model_validate(yaml.safe_load(text)) == sc
