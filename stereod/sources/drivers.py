"""Find frame-source drivers through the ``stereod.drivers`` entry-point group.

The core never imports a driver module by name, so a third party adds a driver by declaring an
entry point ``name = "package.module:DriverClass"``; the class takes the ``[driver.options]``
table as a dict and subclasses :class:`stereod.sources.frames.Driver`.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

from stereod.errors import ConfigError
from stereod.sources.frames import Driver

GROUP = "stereod.drivers"


def available() -> list[str]:
    """Names of the installed drivers, sorted."""
    return sorted(ep.name for ep in entry_points(group=GROUP))


def load_driver(
    name: str,
    options: dict[str, Any],
    origin: Path | str | Callable[[str | None], str] | None = None,
    name_origin: Path | str | None = None,
) -> Driver:
    """Instantiate driver ``name`` with ``options`` (validated by the driver: a bad option is
    a :class:`ConfigError` naming ``origin``, where they came from, when given: the config
    file, the environment; or, given as a function of the option's name (None: the table as
    a whole), where that option came from); an unknown name (said to come from
    ``name_origin``, by default the table's ``origin``) lists what is installed."""
    where_of = origin if callable(origin) else (lambda _key: origin)
    named = name_origin if name_origin is not None else where_of(None)
    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        raise ConfigError(
            f"{f'{named}: ' if named is not None else ''}driver.name = {name!r}: no such "
            "driver; installed: "
            f"{', '.join(available()) or 'none'}"
        )
    try:
        cls = found[0].load()
    except ImportError as exc:
        raise ConfigError(f"driver.name = {name!r}: cannot load its module: {exc}") from exc
    try:
        driver = cls(options)
    except ConfigError as exc:
        key = re.match(r"driver\.options\.([^.\s=:]+)", str(exc))
        where = where_of(key.group(1) if key else None)
        raise ConfigError(f"{where}: {exc}" if where is not None else str(exc)) from exc
    if not isinstance(driver, Driver):
        raise ConfigError(f"driver.name = {name!r}: {cls!r} is not a stereod Driver")
    return driver
