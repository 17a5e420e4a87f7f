"""Room tracks in the objects message format (``stereod.objects/1``), in the room frame.

The message is the rigs' own, so every program that reads a rig's objects reads a room's:
``rig`` is the room's name, ``seq`` counts fusion steps, ``t_ns`` and ``stamp_utc_ns`` are both
the step's UTC instant (the rigs share no monotonic clock), positions and velocities are in
the room frame. What only a rig can say about an object (its blobs in each eye, disparity,
size) is that of the member rig whose position weighed most; ``latency`` holds the fusion's
own time in ``track_ms`` and ``pipeline_ms``.
"""

from __future__ import annotations

import math
from typing import Any

import msgspec
import numpy as np

from stereod.bus.messages import OBJECT_SCHEMA, OBJECTS_SCHEMA, ObjectsMessage, ObjectState
from stereod.fusion.fuser import FusedFrame, RoomTrack
from stereod.fusion.rows import DIAG, PCOV, VCOV
from stereod.fusion.wire import EXTRA, STATES
from stereod.tracking.types import TrackLifecycle
from stereod.vision.geometry import Geometry


def _vec(a: np.ndarray) -> tuple[float, float, float]:
    x, y, z = a.tolist()
    return (x, y, z)


def _sigmas(cov: np.ndarray) -> tuple[float, float, float]:
    x, y, z = (math.sqrt(max(v, 0.0)) for v in cov.diagonal().tolist())
    return (x, y, z)


def _quad(c: list[list[float]], a: tuple[float, float, float]) -> float:
    """a^T C a for a 3-vector and a (3, 3) covariance given as lists (no numpy call: one
    track's figures cost a few microseconds)."""
    return sum(a[i] * c[i][j] * a[j] for i in range(3) for j in range(3))


def speed_heading(v: np.ndarray, cov: np.ndarray) -> tuple[float, float, float, float | None]:
    """Speed (m/s), its sigma, heading atan2(vx, vz) in [0, 360) deg and its sigma (None when
    standing still), the sigmas to first order through the velocity's covariance."""
    vx, vy, vz = v.tolist()
    c = cov.tolist()
    speed = math.sqrt(vx * vx + vy * vy + vz * vz)
    speed_sigma = math.sqrt(max(_quad(c, (vx, vy, vz)), 0.0)) / speed if speed > 1e-9 else 0.0
    heading = math.degrees(math.atan2(vx, vz)) % 360.0
    ground2 = vx * vx + vz * vz
    if ground2 <= 1e-12:
        return speed, speed_sigma, heading, None
    g = (vz / ground2, 0.0, -vx / ground2)
    return speed, speed_sigma, heading, math.degrees(math.sqrt(max(_quad(c, g), 0.0)))


def room_state(track: RoomTrack) -> ObjectState | None:
    """One room track as an object state; None for one with no member left to describe it."""
    states = room_states([track])
    return states[0] if states else None


class _Blob(msgspec.Struct, gc=False):
    """``messages.EyeBlob``'s fields in its order, for writing."""

    centroid_px: list[float]
    bbox_px: list[int]
    area_px: int


class _Object(msgspec.Struct, gc=False):
    """``messages.ObjectState``'s fields in its order (``schema`` by its wire name), built
    positionally and written by ``msgspec`` (no dict per track)."""

    schema: str
    track_id: int
    state: str
    t_ns: int
    stamp_utc_ns: int
    skew_ns: int
    position_m: list[float]
    position_sigma_m: list[float]
    velocity_mps: list[float]
    velocity_sigma_mps: list[float]
    velocity_valid: bool
    heading_valid: bool
    speed_mps: float
    speed_sigma_mps: float
    heading_deg: float
    heading_sigma_deg: float | None
    raw_velocity_mps: None
    left: _Blob
    right: _Blob
    disparity_px: float
    size_m: float
    age_s: float
    extent_min_m: None
    extent_max_m: None


_ENCODER = msgspec.json.Encoder()
_STATE_NAME = {s: s.value for s in TrackLifecycle}
"""Each lifecycle state's name (a dict lookup; an enum's ``.value`` is a descriptor call)."""
_CODE_NAME = [s.value for s in STATES]
"""Each lifecycle code's name (``wire.STATES``)."""


def _figures(tracks: list[RoomTrack], rows: np.ndarray | None = None) -> list[_Object]:
    """Each room track that has a member to describe it as its object state's fields
    (:func:`_columns_figures` of their figures gathered into columns). ``rows``: the tracks'
    states already stacked (``FusedFrame.rows``), else they are stacked here."""
    described = [k for k, t in enumerate(tracks) if t.extra is not None]
    if not described:
        return []
    if len(described) < len(tracks):
        tracks = [tracks[k] for k in described]
        rows = None if rows is None else rows[described]
    if rows is None:
        rows = np.array(
            [np.concatenate([t.position, t.velocity, t.position_cov.ravel(),
                             t.velocity_cov.ravel()]) for t in tracks]
        )  # fmt: skip
    return _columns_figures(
        [t.room_id for t in tracks], [_STATE_NAME[t.state] for t in tracks],
        [t.stamp_utc_ns for t in tracks], [t.first_ns for t in tracks],
        [t.velocity_valid for t in tracks], [t.heading_valid for t in tracks],
        np.array([t.extra for t in tracks]), rows,
    )  # fmt: skip


def _frame_figures(frame: FusedFrame) -> list[_Object]:
    """:func:`_figures` of a frame's tracks, from its columns (no track object)."""
    c, rows = frame.columns, frame.rows
    if c is None or rows is None or not len(rows):
        return []
    if not np.logical_and.reduce(c.described):
        keep = np.flatnonzero(c.described)
        if not keep.size:
            return []
        return _columns_figures(
            [c.ids[k] for k in keep.tolist()], [_CODE_NAME[k] for k in c.life[keep].tolist()],
            c.stamp[keep].tolist(), c.first[keep].tolist(), c.vvalid[keep].tolist(),
            c.hvalid[keep].tolist(), c.extra[keep], rows[keep],
        )  # fmt: skip
    return _columns_figures(
        c.ids, [_CODE_NAME[k] for k in c.life.tolist()], c.stamp.tolist(), c.first.tolist(),
        c.vvalid.tolist(), c.hvalid.tolist(), c.extra, rows,
    )  # fmt: skip


def _columns_figures(
    ids: list[int], states: list[str], stamps: list[int], firsts: list[int],
    vvalid: list[bool], hvalid: list[bool], ex: np.ndarray, rows: np.ndarray,
) -> list[_Object]:  # fmt: skip
    """Room tracks as their object states' fields (plain Python values in the model's
    order, a struct ``msgspec`` writes) from columns: ids, lifecycle names, state stamps and
    first sightings (UTC ns), the validity flags, what each best member passes on (n,
    len(EXTRA)) and state rows (n, WIDTH). Sigmas, speed and heading with their sigmas (to
    first order through the velocity's covariance, as :func:`speed_heading`), blobs from
    the best member's ``extra``."""
    # Plain float math a track: some forty numbers each, where a numpy call apiece would
    # cost more than the arithmetic (the same formulas as :func:`speed_heading`; a root of
    # a negative variance is 0, of a NaN NaN).
    floats = ex[:, _FLOAT_COLUMNS].tolist()
    ints = np.rint(ex[:, _INT_COLUMNS]).astype(np.int64).tolist()
    sigmas = np.sqrt(np.maximum(rows[:, _SIGMA_COLUMNS], 0.0)).tolist()
    sqrt, atan2 = math.sqrt, math.atan2
    out = []
    for rid, name, stamp, first, vv, hv, r, sg, fl, ni in zip(
        ids, states, stamps, firsts, vvalid, hvalid, rows.tolist(), sigmas, floats, ints,
        strict=True,
    ):  # fmt: skip
        vx, vy, vz = r[3], r[4], r[5]
        c0, c1, c2, c3, c4, c5, c6, c7, c8 = r[VCOV]
        speed = sqrt(vx * vx + vy * vy + vz * vz)
        if speed > 1e-9:
            var_along = (
                vx * (c0 * vx + c1 * vy + c2 * vz)
                + vy * (c3 * vx + c4 * vy + c5 * vz)
                + vz * (c6 * vx + c7 * vy + c8 * vz)
            )
            speed_sigma = (0.0 if var_along < 0.0 else sqrt(var_along)) / speed
        else:
            speed_sigma = 0.0
        ground2 = vx * vx + vz * vz
        heading_sigma = None
        if ground2 > 1e-12:
            # g^T C g for g = (vz, 0, -vx) / ground2, the heading's gradient.
            var_heading = (vz * vz * c0 - vx * vz * (c2 + c6) + vx * vx * c8) / (ground2 * ground2)
            heading_sigma = math.degrees(0.0 if var_heading < 0.0 else sqrt(var_heading))
        out.append(
            _Object(
                OBJECT_SCHEMA, rid, name, stamp, stamp,
                ni[0], r[0:3],
                sg[0:3], [vx, vy, vz], sg[3:6],
                vv, hv, speed, speed_sigma,
                math.degrees(atan2(vx, vz)) % 360.0, heading_sigma, None,
                _Blob(fl[0:2], ni[1:5], ni[5]), _Blob(fl[2:4], ni[6:10], ni[10]),
                fl[4], fl[5], (stamp - first) * 1e-9, None, None,
            )
        )  # fmt: skip
    return out


_INTS = ("skew_ns", "left_bx", "left_by", "left_bw", "left_bh", "left_area", "right_bx",
         "right_by", "right_bw", "right_bh", "right_area")  # fmt: skip
_INT_COLUMNS = [EXTRA.index(c) for c in _INTS]
_FLOATS = ("left_cx", "left_cy", "right_cx", "right_cy", "disparity_px", "size_m")
_FLOAT_COLUMNS = [EXTRA.index(c) for c in _FLOATS]
_SIGMA_COLUMNS = np.concatenate([DIAG + PCOV.start, DIAG + VCOV.start])
"""The diagonals of a state row's position and velocity covariances (``rows.PCOV``,
``rows.VCOV``)."""


def room_states(tracks: list[RoomTrack]) -> list[ObjectState]:
    """The room tracks that have a member to describe them, as (validated) object states."""
    return [ObjectState.model_validate(msgspec.to_builtins(f)) for f in _figures(tracks)]


def _head(room: str, seq: int, t_ns: int, geometry: Geometry, fuse_ms: float) -> dict[str, Any]:
    """The room message's fields other than its objects."""
    return {
        "schema": OBJECTS_SCHEMA,
        "rig": room,
        "seq": seq,
        "t_ns": t_ns,
        "stamp_utc_ns": t_ns,
        "skew_ns": 0,
        "left_seq": seq,
        "right_seq": seq,
        "geometry": geometry.value,
        "calibration_id": None,
        "latency": {
            "detect_ms": 0.0, "geometry_ms": 0.0, "track_ms": fuse_ms, "pipeline_ms": fuse_ms,
            "queue_ms": 0.0,
        },
    }  # fmt: skip


def room_message(
    room: str, seq: int, frame: FusedFrame, geometry: Geometry, fuse_ms: float
) -> ObjectsMessage:
    """The objects message of one fusion step of ``room`` (``fuse_ms``: that step's time, ms)."""
    objects = msgspec.to_builtins(_frame_figures(frame))
    return ObjectsMessage.model_validate(
        {**_head(room, seq, frame.t_ns, geometry, fuse_ms), "objects": objects}
    )


def room_payload(
    room: str, seq: int, frame: FusedFrame, geometry: Geometry, fuse_ms: float
) -> tuple[bytes, list[tuple[int, bytes]]]:
    """:func:`room_message` as its JSON payload and each object's own (track id, payload), as
    ``bus.messages.dump_objects`` gives them, written from the step's arrays without building
    a model (:func:`room_message` parses to the same message)."""
    tracks = frame_payloads(frame)
    return join_room(room, seq, frame.t_ns, geometry, fuse_ms, [b for _, b in tracks]), tracks


def object_payloads(
    tracks: list[RoomTrack], rows: np.ndarray | None = None
) -> list[tuple[int, bytes]]:
    """Each room track that has a member to describe it as (its id, its object state's JSON),
    written from arrays by ``msgspec``, one struct per track (neither a dict nor a model).
    The fusion node keeps these per id and rewrites only the tracks a rig's message
    changed."""
    encode = _ENCODER.encode
    return [(f.track_id, encode(f)) for f in _figures(tracks, rows)]


def frame_payloads(frame: FusedFrame) -> list[tuple[int, bytes]]:
    """:func:`object_payloads` of a fusion step's tracks, written from its columns (no track
    object): what the fusion node publishes after each step."""
    encode = _ENCODER.encode
    return [(f.track_id, encode(f)) for f in _frame_figures(frame)]


def join_room(
    room: str, seq: int, t_ns: int, geometry: Geometry, fuse_ms: float, states: list[bytes]
) -> bytes:
    """The room's objects message from its objects' JSON (:func:`object_payloads`), stamped
    ``t_ns`` (UTC ns; each object keeps its own stamp)."""
    head = _ENCODER.encode(_head(room, seq, t_ns, geometry, fuse_ms))[:-1] + b',"objects":['
    if not states:
        return head + b"]}"
    # One join makes the whole payload (some 100 kB with 160 tracks): the head goes onto the
    # first object and the tail onto the last, so the big buffer is allocated and copied once.
    if len(states) == 1:
        return head + states[0] + b"]}"
    return b",".join([head + states[0], *states[1:-1], states[-1] + b"]}"])
