"""Versioned files: the fields a reader does not know, and the format it refuses."""

from __future__ import annotations

import pytest
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from stereod.versioned import known_format, unknown_fields


class Inner(BaseModel):
    model_config = ConfigDict(extra="ignore")
    a: int = 0


class Outer(BaseModel):
    model_config = ConfigDict(extra="ignore")
    format: str = "x.thing/1"
    inner: Inner | None = None
    items: list[int] = []

    @field_validator("format", mode="before")
    @classmethod
    def _known(cls, v: object) -> object:
        return known_format(v, "x.thing/1")


def test_unknown_fields_are_found_at_every_level_in_file_order() -> None:
    data = {"new": 1, "inner": {"a": 2, "b": 3}, "items": [4], "later": None}
    assert unknown_fields(Outer, data) == ["new", "inner.b", "later"]
    assert unknown_fields(Outer, {"inner": None}) == [] and unknown_fields(Outer, [1]) == []
    assert Outer.model_validate(data) == Outer(inner=Inner(a=2), items=[4])


def test_a_newer_version_and_another_kind_of_file_are_told_apart() -> None:
    with pytest.raises(ValidationError, match=r"this stereod reads x\.thing/1; a newer stereod"):
        Outer.model_validate({"format": "x.thing/2"})
    with pytest.raises(ValidationError, match=r"not a x\.thing file \(format x\.thing/1\)"):
        Outer.model_validate({"format": "y.other/1"})
