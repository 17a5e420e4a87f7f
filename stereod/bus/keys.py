"""Zenoh key expressions of one rig (design sec. 4), built in one place.

Everything a daemon says lives under ``<prefix>/<rig>/``::

    objects             one message per processed pair
    objects/<track_id>  one track's state; a DELETE sample when the track ends
    status              health, at 1 Hz and on change
    alive               liveliness token of the running daemon
    config, calibration, stats   queryables
    image/<name>        JPEG images (left, right, overlay, mask) while someone subscribes

``rig`` may be ``*`` in a subscriber's key to hear every rig under the prefix.
"""

from __future__ import annotations

import re

DEFAULT_PREFIX = "stereod"
"""Key prefix unless configured otherwise."""
DEFAULT_RIG = "minoru"
"""Rig name unless configured otherwise."""

RIG_PATTERN = r"^[A-Za-z0-9_\-]+$"
"""What a rig name may contain (one key chunk, no wildcards)."""
PREFIX_PATTERN = r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$"
"""What a prefix may contain (one or more key chunks, no wildcards)."""

IMAGES = ("left", "right", "overlay", "mask")
"""The image keys under ``image/``."""


def base(rig: str = DEFAULT_RIG, *, prefix: str = DEFAULT_PREFIX) -> str:
    """``<prefix>/<rig>``; ``rig`` may be ``*``."""
    if rig != "*" and not re.match(RIG_PATTERN, rig):
        raise ValueError(f"rig name {rig!r}: use letters, digits, '_' and '-' only")
    if not re.match(PREFIX_PATTERN, prefix):
        raise ValueError(f"key prefix {prefix!r}: use chunks of letters, digits, '_', '-' and '/'")
    return f"{prefix}/{rig}"


def objects(rig: str = DEFAULT_RIG, *, prefix: str = DEFAULT_PREFIX) -> str:
    """The ``objects`` key: one message per processed pair."""
    return f"{base(rig, prefix=prefix)}/objects"


def track(rig: str, track_id: int | str, *, prefix: str = DEFAULT_PREFIX) -> str:
    """One track's key (``track_id`` may be ``*`` for all of them)."""
    return f"{objects(rig, prefix=prefix)}/{track_id}"


def status(rig: str = DEFAULT_RIG, *, prefix: str = DEFAULT_PREFIX) -> str:
    return f"{base(rig, prefix=prefix)}/status"


def alive(rig: str = DEFAULT_RIG, *, prefix: str = DEFAULT_PREFIX) -> str:
    """The liveliness token, declared last by a daemon once everything else is up."""
    return f"{base(rig, prefix=prefix)}/alive"


def queryable(name: str, rig: str = DEFAULT_RIG, *, prefix: str = DEFAULT_PREFIX) -> str:
    """``config``, ``calibration`` or ``stats``."""
    if name not in ("config", "calibration", "stats"):
        raise ValueError(f"no queryable {name!r}: config, calibration or stats")
    return f"{base(rig, prefix=prefix)}/{name}"


def image(name: str, rig: str = DEFAULT_RIG, *, prefix: str = DEFAULT_PREFIX) -> str:
    """An image key: ``left``, ``right``, ``overlay`` or ``mask``."""
    if name not in IMAGES and name != "*":
        raise ValueError(f"no image {name!r}: {', '.join(IMAGES)}")
    return f"{base(rig, prefix=prefix)}/image/{name}"


def parse(key: str, *, prefix: str = DEFAULT_PREFIX) -> tuple[str, str] | None:
    """(rig, rest) of a key under ``prefix``, e.g. ``('minoru', 'objects/3')``; None if the key
    is not under the prefix."""
    head = prefix + "/"
    if not key.startswith(head):
        return None
    rig, _, rest = key[len(head) :].partition("/")
    return (rig, rest) if rig and rest else None
