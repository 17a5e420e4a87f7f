"""The room file: the room's name and each rig's pose in the room frame (TOML).

::

    [room]
    name = "lab"
    [[room.rigs]]
    name = "a"
    translation_m = [0.0, 0.0, 0.0]   # the rig's origin (its baseline's midpoint) in the room, m
    rotation_deg = [0.0, 0.0, 0.0]    # about X, Y, Z of the rig frame, deg

A point ``p`` in a rig's frame (X right, Y down, Z forward, m) is ``R p + t`` in the room, with
``R = Rz(rz) Ry(ry) Rx(rx)``: the rig's frame is turned about its own Z first, then about its
(new) Y, then about its (new) X (intrinsic Z, Y, X; the same matrix as turning a vector about
the fixed axes X, then Y, then Z). Each turn is right-handed::

          Z (forward)               ry = +90 deg: the rig looks along the room's +X
         /                              room Z
        o----- X (right)                 ^
        |                                |     rig Z
        Y (down)                         o---->  (= room X)

A rig at zero translation and rotation defines the room frame; the other rigs' poses are given
in it. Every number is finite and bounded, names are unique key chunks, and the file is read
with the same size, nesting and number-length checks as the daemon's configuration.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from stereod.bus import keys
from stereod.errors import ConfigError, MissingInputError, describe_error
from stereod.files.bounds import Bound, not_bool
from stereod.files.nesting import check_data_depth, check_depth
from stereod.files.paths import read_input_file, shown

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

ROOM_TRANSLATION_M = Bound(
    ("room.rigs.translation_m",),
    -1000.0,
    1000.0,
    "m",
    "rigs in one room (a hall, a yard) are within a kilometre of its origin; lengths are metres",
)
ROOM_ROTATION_DEG = Bound(
    ("room.rigs.rotation_deg",),
    -360.0,
    360.0,
    "deg",
    "one full turn either way describes every orientation; angles are degrees",
)
MAX_RIGS = 64
"""Most rigs one room file may list (a room beyond that is split between fusion nodes: see
docs/bench/fuse_scale.md, "Splitting a room")."""


def _each(bound: Bound) -> AfterValidator:
    """A validator of a 3-vector whose every component is within ``bound``."""

    def check(v: tuple[float, float, float]) -> tuple[float, float, float]:
        for c in v:
            bound.check(c)
        return v

    return AfterValidator(check)


Vec3 = tuple[float, float, float]


class RigPose(BaseModel):
    """One rig's name (its Zenoh key chunk) and pose in the room frame."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)

    name: str = Field(pattern=keys.RIG_PATTERN, description="The rig's name, as its daemon's")
    translation_m: Annotated[Vec3, _each(ROOM_TRANSLATION_M)] = Field(
        (0.0, 0.0, 0.0), description="The rig frame's origin in the room frame, m"
    )
    rotation_deg: Annotated[Vec3, _each(ROOM_ROTATION_DEG)] = Field(
        (0.0, 0.0, 0.0),
        description="Turns about the rig's X, Y, Z, applied Z, then Y, then X (intrinsic), deg",
    )

    @field_validator("translation_m", "rotation_deg", mode="before")
    @classmethod
    def _numbers(cls, v: Any) -> Any:
        """Three numbers: a TOML ``true`` is not the number 1, nor a string ``"1"`` (a
        quoted number is refused as a boolean is), and a list of another length is said so
        (not as a missing or extra item)."""
        if isinstance(v, (list, tuple)) and len(v) != 3:
            raise ValueError(f"needs three numbers (X, Y, Z), not {len(v)}")
        if isinstance(v, (list, tuple)) and any(isinstance(c, str) for c in v):
            raise ValueError('needs three numbers (X, Y, Z), not quoted text: write 1.0, not "1.0"')
        return not_bool(v)

    def rotation(self) -> np.ndarray:
        """R (3, 3) taking rig coordinates into the room's: ``Rz(rz) @ Ry(ry) @ Rx(rx)``."""
        return rotation_matrix(*self.rotation_deg)

    def translation(self) -> np.ndarray:
        """t (3,), the rig's origin in the room frame, m."""
        return np.array(self.translation_m, dtype=np.float64)


def rotation_matrix(rx_deg: float, ry_deg: float, rz_deg: float) -> np.ndarray:
    """``Rz(rz) @ Ry(ry) @ Rx(rx)`` (3, 3), each a right-handed turn by the angle in deg."""
    ax, ay, az = (math.radians(a) for a in (rx_deg, ry_deg, rz_deg))
    cx, sx, cy, sy, cz, sz = (
        math.cos(ax),
        math.sin(ax),
        math.cos(ay),
        math.sin(ay),
        math.cos(az),
        math.sin(az),
    )
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


class Room(BaseModel):
    """A room: its name (a key chunk: ``stereod/rooms/<name>/objects``) and its rigs."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=keys.RIG_PATTERN, description="The room's name")
    rigs: list[RigPose] = Field(min_length=1, max_length=MAX_RIGS)

    @model_validator(mode="after")
    def _unique(self) -> Room:
        seen: set[str] = set()
        for rig in self.rigs:
            if rig.name in seen:
                raise ValueError(f"rig {rig.name!r} is listed twice; give each rig one entry")
            seen.add(rig.name)
        return self

    def rig(self, name: str) -> RigPose | None:
        """The pose of the rig called ``name``, or None when the room has no such rig."""
        return next((r for r in self.rigs if r.name == name), None)


class RoomFile(BaseModel):
    """The whole file: one ``[room]`` table."""

    model_config = ConfigDict(extra="forbid")

    room: Room


def load_room(path: Path) -> Room:
    """Read and validate a room file; a problem is one :class:`ConfigError` (78) line naming
    the file and field, a missing or unreadable file a :class:`MissingInputError` (66)."""
    where = shown(path)
    try:
        text = read_input_file(path, "a room file", too_large=ConfigError).decode("utf-8-sig")
    except FileNotFoundError as exc:
        raise MissingInputError(
            f"{where}: no such room file: check the path given to --room"
        ) from exc
    except OSError as exc:
        raise MissingInputError(f"{where}: cannot read the room file: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{where}: not a text file (byte {exc.start} is not UTF-8); a room file is UTF-8 TOML"
        ) from exc
    check_depth(text, "toml", where, ConfigError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{where}: invalid TOML: {exc}") from exc
    check_data_depth(data, where, ConfigError)
    try:
        return RoomFile.model_validate(data).room
    except ValidationError as exc:
        parts = [describe_error(e, model=RoomFile) for e in exc.errors(include_url=False)]
        raise ConfigError(f"{where}: invalid room file: {'; '.join(parts[:3])}") from exc
