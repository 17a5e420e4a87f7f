"""Versioned files: the fields a reader does not know, and the format it refuses."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

from stereod.files.versioned import known_format, unknown_fields, warn_unknown_fields


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
    for other in ("y.other/1", 1):
        with pytest.raises(ValidationError, match=r"not a x\.thing file \(format x\.thing/1\)"):
            Outer.model_validate({"format": other})
    for older in ("x.thing/0", "x.thing/beta"):
        with pytest.raises(ValidationError, match=r"this stereod reads x\.thing/1 only"):
            Outer.model_validate({"format": older})


def test_a_file_is_warned_about_once_however_often_it_is_read(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A command may read one file twice (a driver and its progress bar), a daemon again at
    each reload: its unknown fields are named once, and again only if the file changed."""
    path = tmp_path / "f.json"
    text = b'{"new": 1}'
    for _ in range(3):
        assert warn_unknown_fields(path, Outer, text) == ["new"]
    warn_unknown_fields(path, Outer, b'{"newer": 2}')
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 2 and "fields this stereod does not know: newer" in warned[1]
