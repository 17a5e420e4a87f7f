"""What every section of the daemon's configuration shares: the base of its pydantic models
(unknown keys refused, no inf or NaN, no true/false for a number), and the defaults of the
pipeline's own settings, stated once in :class:`stereod.pipeline.PipelineParams`."""

from __future__ import annotations

import typing
from typing import Any

from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    ValidationInfo,
    field_validator,
    model_validator,
)

from stereod.files.bounds import not_bool


class Section(BaseModel):
    """One TOML table of the configuration."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _numbers_are_not_bools(cls, v: Any, info: ValidationInfo) -> Any:
        """A number field refuses true/false, which pydantic's lax mode reads as 1/0."""
        kind = cls.model_fields[info.field_name or ""].annotation
        if kind in (int, float) or typing.get_origin(kind) is tuple:
            return not_bool(v)
        return v

    @model_validator(mode="before")
    @classmethod
    def _one_name_each(cls, data: Any) -> Any:
        """A field given under two of its names (``hold_still_s`` and its older ``freeze_s``)
        is refused as such, not as an unknown key."""
        if isinstance(data, dict):
            for name, names in field_names(cls).items():
                given = [n for n in names if n in data]
                if len(given) > 1:
                    raise ValueError(
                        f"{' and '.join(given)} are one setting ({given[1]} is the older name "
                        f"of {name}): give it once"
                    )
        return data


def field_names(model: type[BaseModel]) -> dict[str, list[str]]:
    """Each field of ``model`` that has other names it is read by: its name, then those."""
    out: dict[str, list[str]] = {}
    for name, info in model.model_fields.items():
        alias = info.validation_alias
        if isinstance(alias, AliasChoices):
            others = [a for a in alias.choices if isinstance(a, str) and a != name]
            if others:
                out[name] = [name, *others]
    return out


def pipeline_default(name: str) -> Any:
    """The default of one :class:`PipelineParams` field (the pipeline is loaded by the sections
    that state its defaults, not by every section)."""
    from stereod.pipeline import PipelineParams

    return PipelineParams.__dataclass_fields__[name].default
