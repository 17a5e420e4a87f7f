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

import numpy as np

from ..geometry import Geometry
from ..messages import Latency, ObjectsMessage, ObjectState
from .fuser import FusedFrame, RoomTrack


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
    src = track.source
    if src is None:
        return None
    speed, speed_sigma, heading, heading_sigma = speed_heading(track.velocity, track.velocity_cov)
    return ObjectState(
        track_id=track.room_id,
        state=track.state,
        t_ns=track.stamp_utc_ns,
        stamp_utc_ns=track.stamp_utc_ns,
        skew_ns=src.skew_ns,
        position_m=_vec(track.position),
        position_sigma_m=_sigmas(track.position_cov),
        velocity_mps=_vec(track.velocity),
        velocity_sigma_mps=_sigmas(track.velocity_cov),
        velocity_valid=track.velocity_valid,
        heading_valid=track.heading_valid,
        speed_mps=speed,
        speed_sigma_mps=speed_sigma,
        heading_deg=heading,
        heading_sigma_deg=heading_sigma,
        raw_velocity_mps=None,
        left=src.left,
        right=src.right,
        disparity_px=src.disparity_px,
        size_m=src.size_m,
        age_s=(track.stamp_utc_ns - track.first_ns) * 1e-9,
    )


def room_message(
    room: str, seq: int, frame: FusedFrame, geometry: Geometry, fuse_ms: float
) -> ObjectsMessage:
    """The objects message of one fusion step of ``room`` (``fuse_ms``: that step's time, ms)."""
    objects = [s for s in map(room_state, frame.tracks) if s is not None]
    return ObjectsMessage(
        rig=room,
        seq=seq,
        t_ns=frame.t_ns,
        stamp_utc_ns=frame.t_ns,
        skew_ns=0,
        left_seq=seq,
        right_seq=seq,
        geometry=geometry,
        calibration_id=None,
        latency=Latency(
            detect_ms=0.0, geometry_ms=0.0, track_ms=fuse_ms, pipeline_ms=fuse_ms, queue_ms=0.0
        ),
        objects=objects,
    )
