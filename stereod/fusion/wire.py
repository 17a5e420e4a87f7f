"""A rig's objects message as arrays, one per field: what the fusion works on.

Each field the fusion uses becomes one numpy array over the message's objects, so that moving
them into the room, predicting, gating and fusing are whole-array operations. The fields it only
passes on (the pair's skew, each eye's blob, disparity and size) are the columns of
:data:`EXTRA`, so that the room's message is written from arrays too, with no model per object.
An object whose position or velocity is not finite is left out, as a daemon leaves out a
degenerate one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson

from stereod.bus.messages import OBJECT_SCHEMA, OBJECTS_SCHEMA, ObjectsMessage
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
    finite = np.isfinite(wire.position).all(axis=1) & np.isfinite(wire.velocity).all(axis=1)
    return wire if finite.all() else wire.select(finite)


def decode(payload: bytes) -> RigWire:
    """A rig's objects payload as :class:`RigWire` arrays, as
    ``from_message(ObjectsMessage.model_validate_json(payload))`` gives them, without a model
    per object: ``orjson`` into one row per object, each field's type checked as the model's
    strict form would. Anything that is not plainly such a message (a field missing or of
    another type, a number not finite or beyond 64 bits, ...) is left to the model, whose
    verdict and error (``pydantic.ValidationError``, a ``ValueError``) stand, so the two accept
    and refuse the same payloads."""
    try:
        wire = _fast(orjson.loads(payload))
    except Exception:  # anything unusual: the model decides, with its own error
        wire = None
    return wire if wire is not None else from_message(ObjectsMessage.model_validate_json(payload))


_GEOMETRY = {g.value: g for g in Geometry}
_STATE = {s.value: k for k, s in enumerate(STATES)}
_LATENCY = ("detect_ms", "geometry_ms", "track_ms", "pipeline_ms", "queue_ms")


_NUMBER = frozenset((int, float))
_INT = frozenset((int,))
_BOOL = frozenset((bool,))


def _fast(d: Any) -> RigWire | None:
    """:func:`decode`'s plain case; raises (or returns None) for anything else. Each field is
    read by unpacking (a list of another length raises), and the types of all of a kind are
    checked at once: numbers int or float (not bool), integers int, flags bool."""
    # "schema_" is the model's own name for "schema": the model reads it too.
    if d.get("schema", OBJECTS_SCHEMA) != OBJECTS_SCHEMA or "schema_" in d:
        return None
    rig, cal, lat, objs = d["rig"], d.get("calibration_id"), d["latency"], d["objects"]
    if type(rig) is not str or (cal is not None and type(cal) is not str):
        return None
    if type(lat) is not dict or type(objs) is not list:
        return None
    rig.encode("utf-8")  # no lone surrogate
    geometry = _GEOMETRY[d["geometry"]]
    head = [d[k] for k in ("seq", "t_ns", "stamp_utc_ns", "skew_ns", "left_seq", "right_seq")]
    nums: list[Any] = [lat[k] for k in _LATENCY]
    ints: list[Any] = list(head)
    flags: list[Any] = []
    rows, keys = [], []
    has_vs = []
    for o in objs:
        if o.get("schema", OBJECT_SCHEMA) != OBJECT_SCHEMA or "schema_" in o:
            return None
        left, right = o["left"], o["right"]
        lcx, lcy = left["centroid_px"]
        lbx, lby, lbw, lbh = left["bbox_px"]
        rcx, rcy = right["centroid_px"]
        rbx, rby, rbw, rbh = right["bbox_px"]
        la, ra = left["area_px"], right["area_px"]
        px, py, pz = o["position_m"]
        qx, qy, qz = o["position_sigma_m"]
        vx, vy, vz = o["velocity_mps"]
        vs = o["velocity_sigma_mps"]
        sx, sy, sz = _NAN3 if vs is None else vs
        has_vs.append(vs is not None)
        vv, hv, skew = o["velocity_valid"], o.get("heading_valid", False), o["skew_ns"]
        disparity, size = o["disparity_px"], o["size_m"]
        tid, stamp = o["track_id"], o["stamp_utc_ns"]
        keys.append((tid, _STATE[o["state"]], stamp))
        rows.append((
            px, py, pz, qx, qy, qz, vx, vy, vz, sx, sy, sz, vv, hv,
            skew, lcx, lcy, lbx, lby, lbw, lbh, la, rcx, rcy, rbx, rby, rbw, rbh, ra,
            disparity, size,
        ))  # fmt: skip
        ints += (tid, stamp, o["t_ns"], skew, lbx, lby, lbw, lbh, la, rbx, rby, rbw, rbh, ra)
        nums += (px, py, pz, qx, qy, qz, vx, vy, vz, lcx, lcy, rcx, rcy, disparity, size,
                 o["speed_mps"], o["heading_deg"], o["age_s"])  # fmt: skip
        if vs is not None:
            nums += (sx, sy, sz)
        flags += (vv, hv)
        for v in (o["speed_sigma_mps"], o["heading_sigma_deg"]):
            if v is not None:
                nums.append(v)
        for v in (o["raw_velocity_mps"], o.get("extent_min_m"), o.get("extent_max_m")):
            if v is not None:
                ax, ay, az = v
                nums += (ax, ay, az)
    if not (
        set(map(type, nums)) <= _NUMBER
        and set(map(type, ints)) <= _INT
        and set(map(type, flags)) <= _BOOL
    ):
        return None
    np.array(ints, dtype=np.int64)  # beyond 64 bits raises: the model's to judge
    # A number not finite (1e400 reads as inf) is the model's to judge too.
    if not np.isfinite(np.array(nums, dtype=np.float64)).all():
        return None
    n = len(rows)
    f = np.array(rows, dtype=np.float64).reshape(n, 14 + len(EXTRA))
    i = np.array(keys, dtype=np.int64).reshape(n, 3)
    return RigWire(
        rig=rig, seq=head[0], stamp_utc_ns=head[2], geometry=geometry, ids=i[:, 0],
        state=i[:, 1].astype(np.int8), stamps_ns=i[:, 2], position=f[:, 0:3],
        position_sigma=f[:, 3:6], velocity=f[:, 6:9], velocity_sigma=f[:, 9:12],
        velocity_valid=f[:, 12] != 0, heading_valid=f[:, 13] != 0, extra=f[:, 14:],
    )  # fmt: skip
