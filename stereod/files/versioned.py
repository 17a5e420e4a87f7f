"""Versioned JSON files (the calibration file, a recording's manifest): within one format
version fields are only ever added, so a reader ignores the fields it does not know and says
which. A change that alters what a known field means gets a new version, which an older
reader refuses by its ``format`` field.
"""

from __future__ import annotations

import json
import logging
import types
import typing
from pathlib import Path

from pydantic import BaseModel

log = logging.getLogger(__name__)

__all__ = ["known_format", "unknown_fields", "warn_unknown_fields"]


def _model_in(annotation: object) -> type[BaseModel] | None:
    """The model a field holds (``Board`` for ``Board | None``), or None for plain values."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        for arg in typing.get_args(annotation):
            found = _model_in(arg)
            if found is not None:
                return found
    return None


def unknown_fields(model: type[BaseModel], data: object, prefix: str = "") -> list[str]:
    """The dotted names of the fields in ``data`` (parsed JSON) that ``model`` does not
    declare, nested models included, in the order they appear."""
    if not isinstance(data, dict):
        return []
    found: list[str] = []
    for key, value in data.items():
        field = model.model_fields.get(key)
        if field is None:
            found.append(f"{prefix}{key}")
            continue
        inner = _model_in(field.annotation)
        if inner is not None:
            found += unknown_fields(inner, value, f"{prefix}{key}.")
    return found


_warned: set[tuple[str, int]] = set()
"""(path, hash of its text) of the files already warned about: a file read again (by a
reload, or by two parts of one command) is not warned about twice."""


def warn_unknown_fields(path: Path, model: type[BaseModel], text: bytes) -> list[str]:
    """Log one warning naming ``path`` and the fields of its JSON ``text`` that ``model`` does
    not know (they are ignored), once per process for that file and text; the names."""
    try:
        data = json.loads(text)
    except ValueError:
        return []
    names = unknown_fields(model, data)
    key = (str(path), hash(text))
    if names and key not in _warned:
        _warned.add(key)
        log.warning(
            "%s: ignoring fields this stereod does not know: %s (written by a newer stereod?)",
            path,
            ", ".join(names),
        )
    return names


def known_format(value: object, expected: str) -> object:
    """``value`` if it is the ``format`` field this stereod reads (``expected``), for a
    pydantic before-validator; otherwise why not: a newer version of the same format, or a
    file of another kind."""
    if value == expected:
        return value
    kind, version = expected.rsplit("/", 1)
    if isinstance(value, str) and value.startswith(f"{kind}/"):
        theirs = value.removeprefix(f"{kind}/")
        if theirs.isdigit() and int(theirs) > int(version):
            raise ValueError(
                f"this stereod reads {expected}; a newer stereod wrote this file: upgrade stereod"
            )
        raise ValueError(f"this stereod reads {expected} only")
    raise ValueError(f"not a {kind} file (format {expected})")
