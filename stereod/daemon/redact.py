"""What the daemon tells the bus about itself, and nothing more.

Anyone who can subscribe to ``stereod/<rig>/status`` or query ``config`` learns what these
carry. They need the figures and the reasons, not the machine's layout: paths are reduced to
their file name (``/etc/stereod/keys/minoru.json`` becomes ``minoru.json``), and the Zenoh
config file, which may name keys and certificates, is given by its name only. The log and
the command's own error line keep the full paths: they stay on the machine.
"""

from __future__ import annotations

import re
from pathlib import PurePath
from typing import Any

from stereod.daemon.config import StereodConfig

_ABSOLUTE = re.compile(r"(?<![\w.:/~-])/(?:[^\s/:;,'\"()\[\]{}]+/)+([^\s/:;,'\"()\[\]{}]*)")
"""An absolute path with at least one folder: what follows its last slash is group 1."""


def public_text(text: str) -> str:
    """``text`` with every absolute path reduced to its last component."""
    return _ABSOLUTE.sub(lambda m: m.group(1) or "/", text)


def _name(value: Any) -> Any:
    if isinstance(value, str) and "/" in value and "://" not in value:
        return PurePath(value).name or value
    return value


def public_config(cfg: StereodConfig) -> dict[str, Any]:
    """The configuration as the ``config`` queryable gives it: every path reduced to its file
    name, the driver's options likewise, the Zenoh endpoints as they are (a consumer needs
    them to connect)."""
    data = cfg.model_dump(mode="json")
    data["rig"]["calibration"] = _name(data["rig"]["calibration"])
    data["zenoh"]["config_file"] = _name(data["zenoh"]["config_file"])
    data["driver"]["options"] = _public_options(data["driver"]["options"])
    return data


def _public_options(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _public_options(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_public_options(v) for v in value]
    return _name(value)
