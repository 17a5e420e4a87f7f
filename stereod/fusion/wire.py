"""A rig's objects message as arrays, one per field: what the fusion works on.

Each field the fusion uses becomes one numpy array over the message's objects, so that moving
them into the room, predicting, gating and fusing are whole-array operations. The fields it only
passes on (the pair's skew, each eye's blob, disparity and size) are the columns of
:data:`EXTRA`, so that the room's message is written from arrays too, with no model per object.
An object whose position or velocity is not finite is left out, as a daemon leaves out a
degenerate one.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Annotated, Any, Literal

import msgspec
import numpy as np

from stereod.bus.messages import OBJECT_SCHEMA, OBJECTS_SCHEMA, ObjectsMessage
from stereod.files.bounds import UTC_NS_MAX
from stereod.tracking.types import TrackLifecycle
from stereod.vision.geometry import Geometry

EXTRA = (
    "skew_ns",
    "left_cx", "left_cy", "left_bx", "left_by", "left_bw", "left_bh", "left_area",
    "right_cx", "right_cy", "right_bx", "right_by", "right_bw", "right_bh", "right_area",
    "disparity_px", "size_m",
)  # fmt: skip
"""The columns of :attr:`RigWire.extra`: what the room's message repeats of its best member."""

STATES = (
    TrackLifecycle.TENTATIVE,
    TrackLifecycle.CONFIRMED,
    TrackLifecycle.COASTING,
    TrackLifecycle.STATIONARY,
)
"""Lifecycle states by their code in :attr:`RigWire.state`."""
TENTATIVE, CONFIRMED, COASTING, STATIONARY = range(4)


@dataclass(frozen=True)
class RigWire:
    """One rig message's objects as arrays, in the rig frame (m, m/s, UTC ns)."""

    rig: str
    seq: int
    stamp_utc_ns: int
    geometry: Geometry
    ids: np.ndarray
    """(n,) track ids (int64)."""
    state: np.ndarray
    """(n,) lifecycle codes, indexes into :data:`STATES`."""
    stamps_ns: np.ndarray
    """(n,) each object's UTC stamp, ns (int64)."""
    position: np.ndarray
    """(n, 3) m."""
    position_sigma: np.ndarray
    """(n, 3) m (NaN where the rig gave none finite)."""
    velocity: np.ndarray
    """(n, 3) m/s."""
    velocity_sigma: np.ndarray
    """(n, 3) m/s (NaN while the rig does not know it)."""
    velocity_valid: np.ndarray
    """(n,) bool."""
    heading_valid: np.ndarray
    """(n,) bool."""
    extra: np.ndarray
    """(n, len(EXTRA)) float64, the columns of :data:`EXTRA`."""

    def select(self, keep: np.ndarray) -> RigWire:
        """The same message with only the objects where ``keep`` (n,) is true."""
        return RigWire(
            self.rig, self.seq, self.stamp_utc_ns, self.geometry, self.ids[keep],
            self.state[keep], self.stamps_ns[keep], self.position[keep],
            self.position_sigma[keep], self.velocity[keep], self.velocity_sigma[keep],
            self.velocity_valid[keep], self.heading_valid[keep], self.extra[keep],
        )  # fmt: skip


_CODE_OF = {s: k for k, s in enumerate(STATES)}
_NAN3 = (float("nan"),) * 3


def from_message(msg: ObjectsMessage) -> RigWire:
    """A validated message's objects as :class:`RigWire` arrays (rig frame): one row of
    numbers per object, made into one array at once (a numpy call per field would cost more
    than the fields)."""
    objs = msg.objects
    n = len(objs)
    rows = [
        (o.track_id, _CODE_OF[o.state], o.stamp_utc_ns, *o.position_m, *o.position_sigma_m,
         *o.velocity_mps, *(o.velocity_sigma_mps or _NAN3), o.velocity_valid, o.heading_valid,
         o.skew_ns, *o.left.centroid_px, *o.left.bbox_px, o.left.area_px,
         *o.right.centroid_px, *o.right.bbox_px, o.right.area_px, o.disparity_px, o.size_m)
        for o in objs
    ]  # fmt: skip
    # Integers (ids, stamps) exactly in their own array; the rest as floats.
    try:
        ints = np.array([r[:3] for r in rows], dtype=np.int64).reshape(n, 3)
    except OverflowError:
        raise ValueError(
            f"rig {msg.rig!r}: an object's track_id or stamp_utc_ns is beyond 64 bits"
        ) from None
    f = np.array([r[3:] for r in rows], dtype=np.float64).reshape(n, 14 + len(EXTRA))
    wire = RigWire(
        rig=msg.rig,
        seq=msg.seq,
        stamp_utc_ns=msg.stamp_utc_ns,
        geometry=msg.geometry,
        ids=ints[:, 0],
        state=ints[:, 1].astype(np.int8),
        stamps_ns=ints[:, 2],
        position=f[:, 0:3],
        position_sigma=f[:, 3:6],
        velocity=f[:, 6:9],
        velocity_sigma=f[:, 9:12],
        velocity_valid=f[:, 12] != 0,
        heading_valid=f[:, 13] != 0,
        extra=f[:, 14:],
    )
    return wire if _plain(f) else usable(wire)


MAX_POSITION_M = 1e4
"""The largest coordinate (m, rig frame) of an object the room takes: no rig sees 10 km, and
squared in a covariance a much larger number overflows to an infinity."""
MAX_VELOCITY_MPS = 1e4
"""The largest velocity component (m/s) of an object the room takes."""
SIGMA_RANGE = (1e-6, 1e3)
"""A published sigma (m, or m/s for a velocity) outside this is no measure of an error: a zero
claims a certainty no triangulation has, and 1e200 squared is an infinity. It is taken as
missing (the room's default sigma), as a non-finite one is."""


_LO = np.array([0.0] * 3 + [SIGMA_RANGE[0]] * 3 + [0.0] * 3 + [SIGMA_RANGE[0]] * 3)
_HI = np.array(
    [MAX_POSITION_M] * 3 + [SIGMA_RANGE[1]] * 3 + [MAX_VELOCITY_MPS] * 3 + [SIGMA_RANGE[1]] * 3
)


def _plain(f: np.ndarray) -> bool:
    """Whether every object's position, velocity and sigmas (a row's first 12 floats) are
    within bounds, so that :func:`usable` would change nothing (a few calls for a message)."""
    a = np.abs(f[:, :12])
    return bool(np.logical_and.reduce((a >= _LO) & (a <= _HI), axis=None))


def usable(wire: RigWire) -> RigWire:
    """``wire`` without the objects the room cannot fuse (a position or velocity not finite or
    beyond :data:`MAX_POSITION_M` or :data:`MAX_VELOCITY_MPS`), and with each sigma outside
    :data:`SIGMA_RANGE` made missing (NaN): a rig's finite but absurd numbers would otherwise
    make its room tracks NaN. Both readers take what they pass through here."""
    lo, hi = SIGMA_RANGE
    ps, vs = wire.position_sigma, wire.velocity_sigma
    with np.errstate(invalid="ignore"):
        keep = (np.abs(wire.position) <= MAX_POSITION_M).all(axis=1)
        keep &= (np.abs(wire.velocity) <= MAX_VELOCITY_MPS).all(axis=1)
        odd_p, odd_v = ~((ps >= lo) & (ps <= hi)), (vs < lo) | (vs > hi)
    if odd_p.any() or odd_v.any():
        wire = dataclasses.replace(
            wire,
            position_sigma=np.where(odd_p, np.nan, ps),
            velocity_sigma=np.where(odd_v, np.nan, vs),
        )
    return wire if keep.all() else wire.select(keep)


def decode(payload: bytes) -> RigWire:
    """A rig's objects payload as :class:`RigWire` arrays, as
    ``from_message(ObjectsMessage.model_validate_json(payload))`` gives them, without a model
    per object: ``msgspec`` reads it into typed structs that mirror the wire schema (every
    field's type, every number finite and every integer within 64 bits checked in C), then
    one row per object. Anything that is not plainly such a message (a field missing or of
    another type, a number not finite or beyond 64 bits, ...) is left to the model, whose
    verdict and error (``pydantic.ValidationError``, a ``ValueError``) stand, so the two accept
    and refuse the same payloads. Either way, a message stamped (or with an object stamped)
    outside 0..:data:`~stereod.files.bounds.UTC_NS_MAX` is refused (``ValueError``): the room's
    clock arithmetic would pass 64 bits."""
    try:
        wire = _fast(payload)
    except Exception:  # anything unusual: the model decides, with its own error
        wire = None
    if wire is not None:  # its stamps were checked as it was read
        return wire
    wire = from_message(ObjectsMessage.model_validate_json(payload))
    if not 0 <= wire.stamp_utc_ns <= UTC_NS_MAX or (
        len(wire.stamps_ns)
        and not 0 <= int(wire.stamps_ns.min()) <= int(wire.stamps_ns.max()) <= UTC_NS_MAX
    ):
        raise ValueError(
            f"rig {wire.rig!r}: a stamp outside 1970..2116 (0..{UTC_NS_MAX} ns): its clock is wrong"
        )
    return wire


_FLOAT = float
"""A finite number (an integer is taken as a float, as the model takes it): ``msgspec`` reads
no JSON number as an infinity (``Number out of range``), and JSON has no NaN, so no bound is
checked here (one a number costs the reader some tenth of its time)."""
_INT = Annotated[int, msgspec.Meta(ge=-(2**63), le=2**63 - 1)]
"""An integer within 64 bits."""
_STAMP = Annotated[int, msgspec.Meta(ge=0, le=UTC_NS_MAX)]
"""A UTC stamp (ns) the room takes (see :func:`decode`): checked in C, where a message out of
range leaves the fast reader for the model's, and :func:`decode` refuses it there."""
_VEC3 = tuple[_FLOAT, _FLOAT, _FLOAT]


class _Blob(msgspec.Struct, gc=False):
    """``messages.EyeBlob`` as the fast reader takes it."""

    centroid_px: tuple[_FLOAT, _FLOAT]
    bbox_px: tuple[_INT, _INT, _INT, _INT]
    area_px: _INT


class _Object(msgspec.Struct, gc=False):
    """``messages.ObjectState`` as the fast reader takes it (unknown fields ignored, as the
    model ignores them; ``schema_``, the model's own name for ``schema``, is left to it)."""

    track_id: _INT
    state: Literal["tentative", "confirmed", "coasting", "stationary"]
    t_ns: _INT
    stamp_utc_ns: _STAMP
    skew_ns: _INT
    position_m: _VEC3
    position_sigma_m: _VEC3
    velocity_mps: _VEC3
    velocity_sigma_mps: _VEC3 | None
    velocity_valid: bool
    speed_mps: _FLOAT
    speed_sigma_mps: _FLOAT | None
    heading_deg: _FLOAT
    heading_sigma_deg: _FLOAT | None
    raw_velocity_mps: _VEC3 | None
    left: _Blob
    right: _Blob
    disparity_px: _FLOAT
    size_m: _FLOAT
    age_s: _FLOAT
    heading_valid: bool = False
    extent_min_m: _VEC3 | None = None
    extent_max_m: _VEC3 | None = None
    schema: Literal["stereod.object/1"] = OBJECT_SCHEMA
    alias: Any = msgspec.field(default=msgspec.UNSET, name="schema_")


class _Latency(msgspec.Struct, gc=False):
    """``messages.Latency`` as the fast reader takes it."""

    detect_ms: _FLOAT
    geometry_ms: _FLOAT
    track_ms: _FLOAT
    pipeline_ms: _FLOAT
    queue_ms: _FLOAT


class _Message(msgspec.Struct, gc=False):
    """``messages.ObjectsMessage`` as the fast reader takes it."""

    rig: str
    seq: _INT
    t_ns: _INT
    stamp_utc_ns: _STAMP
    skew_ns: _INT
    left_seq: _INT
    right_seq: _INT
    geometry: Literal["canonical", "calibrated"]
    latency: _Latency
    objects: list[_Object]
    calibration_id: str | None = None
    schema: Literal["stereod.objects/1"] = OBJECTS_SCHEMA
    alias: Any = msgspec.field(default=msgspec.UNSET, name="schema_")


_DECODER = msgspec.json.Decoder(_Message)
_GEOMETRY = {g.value: g for g in Geometry}
_STATE = {s.value: k for k, s in enumerate(STATES)}


def _fast(payload: bytes) -> RigWire | None:
    """:func:`decode`'s plain case; raises (or returns None) for anything else: the structs
    check every field, so what is left is a row of numbers per object."""
    m = _DECODER.decode(payload)
    if m.alias is not msgspec.UNSET:
        return None
    m.rig.encode("utf-8")  # no lone surrogate
    vals: list[Any] = []
    keys: list[int] = []
    put, key = vals.extend, keys.extend
    for o in m.objects:
        if o.alias is not msgspec.UNSET:
            return None
        left, right = o.left, o.right
        key((o.track_id, _STATE[o.state], o.stamp_utc_ns))
        # One tuple an object, one extend: the row in :data:`EXTRA`'s order after the vectors.
        put((*o.position_m, *o.position_sigma_m, *o.velocity_mps,
             *(o.velocity_sigma_mps or _NAN3), o.velocity_valid, o.heading_valid, o.skew_ns,
             *left.centroid_px, *left.bbox_px, left.area_px, *right.centroid_px,
             *right.bbox_px, right.area_px, o.disparity_px, o.size_m))  # fmt: skip
    # One flat list into one array (numpy reads a flat list faster than a list of rows).
    f = np.fromiter(vals, np.float64, len(vals)).reshape(-1, 14 + len(EXTRA))
    i = np.fromiter(keys, np.int64, len(keys)).reshape(-1, 3)
    wire = RigWire(
        rig=m.rig, seq=m.seq, stamp_utc_ns=m.stamp_utc_ns, geometry=_GEOMETRY[m.geometry],
        ids=i[:, 0], state=i[:, 1].astype(np.int8), stamps_ns=i[:, 2], position=f[:, 0:3],
        position_sigma=f[:, 3:6], velocity=f[:, 6:9], velocity_sigma=f[:, 9:12],
        velocity_valid=f[:, 12] != 0, heading_valid=f[:, 13] != 0, extra=f[:, 14:],
    )  # fmt: skip
    return wire if _plain(f) else usable(wire)
