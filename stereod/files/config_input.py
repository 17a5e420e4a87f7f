"""A configuration's sources: the TOML file (read with the depth and number bounds checked
before any parser sees it), the ``STEREOD_*`` variables' names, and how file, environment and
flags are layered and told apart in an error."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

from stereod.errors import ConfigError, MissingInputError
from stereod.files.nesting import check_data_depth, check_depth
from stereod.files.paths import read_input_file

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

DEFAULT_CONFIG_PATH = Path("/etc/stereod/stereod.toml")


def read_toml(path: Path) -> dict[str, Any]:
    """Parse a TOML config file; errors name the file and what to do."""
    try:
        text = read_input_file(path, "a config file", too_large=ConfigError).decode("utf-8-sig")
        check_depth(text, "toml", str(path), ConfigError)
        data = tomllib.loads(text)
        check_data_depth(data, str(path), ConfigError)
        return data
    except FileNotFoundError as exc:
        raise MissingInputError(
            f"{path}: no such config file (give an existing one with --config FILE; "
            f"`stereod install-service` writes {DEFAULT_CONFIG_PATH})"
        ) from exc
    except OSError as exc:
        raise MissingInputError(f"{path}: cannot read config file: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not a text file (byte {exc.start} is not UTF-8); a config is UTF-8 TOML"
        ) from exc


ENV_PREFIX = "STEREOD_"
ENV_OTHER = ("STEREOD_LOG_LEVEL", "STEREOD_CRASH_DIR")
"""Variables with the prefix that are not configuration fields."""


def merge(base: dict[str, Any], top: dict[str, Any]) -> dict[str, Any]:
    """``top`` over ``base``, table by table."""
    out = dict(base)
    for k, v in top.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def origin(
    loc: tuple[Any, ...],
    path: Path | None,
    overrides: dict[str, Any],
    tables: tuple[dict[str, Any], dict[str, Any]] = ({}, {}),
) -> str:
    """Where the value at ``loc`` (``("driver", "name")``) came from: a flag, the environment
    (its variable, or one for a part of it), the file, or defaults. An error of a section as a
    whole (between its fields) names every source that gave that section fields: the file and
    the environment's as read (``tables``), and the flags."""
    if len(loc) == 1:
        section = str(loc[0])
        sources = [
            name
            for name, given in (
                (str(path), section in tables[0]),
                (f"environment {ENV_PREFIX}{section.upper()}__*", section in tables[1]),
                ("command line", overrides.get(section) is not None),
            )
            if given
        ]
        return " and ".join(sources) or "defaults"
    node: Any = overrides
    for part in loc:
        if isinstance(node, dict):
            node = node.get(part)
        elif isinstance(node, list) and isinstance(part, int) and 0 <= part < len(node):
            node = node[part]
        else:
            node = None
    if node is not None:
        return "command line"
    names = {k.upper() for k in os.environ}
    for n in range(len(loc), 1, -1):
        env = ENV_PREFIX + "__".join(str(p) for p in loc[:n]).upper()
        # the variable of this table or of one holding it, or (for the whole of ``loc``)
        # one of its parts
        if env in names or (n == len(loc) and any(k.startswith(env + "__") for k in names)):
            return f"environment {env}"
    return str(path) if path is not None else "defaults"


def prune(d: dict[str, Any]) -> dict[str, Any]:
    """``d`` without its ``None`` values and the tables they leave empty (flags not given)."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            sub = prune(v)
            if sub:
                out[k] = sub
        elif v is not None:
            out[k] = v
    return out
