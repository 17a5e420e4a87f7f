"""Rig objects messages made from a room's known 3D truth, with no rendering: what several
rig daemons would publish about objects walking through one room, for the fusion's tests and
its scale benchmark.

Each :class:`RigSim` is one rig at a pose of the room file. An object is visible to it when it
is in front, inside its horizontal field of view and within its range; the rig then reports
it under a track id of its own (a new one each time the object comes into view, as a daemon's
tracker would), at the truth moved into the rig frame plus Gaussian noise whose sigmas it also
reports: about 1 cm across the view and ``depth_sigma_per_m2`` times the squared depth along
it, as a stereo rig's depth error grows. ``seed`` makes the noise repeatable.

A rig's figures are worked out for all the walkers at once (numpy, :class:`Crowd`); its message
is then either the wire model (:meth:`RigSim.message`, for tests that read it) or its payload
written directly by ``msgspec`` (:meth:`RigSim.payload`, what the generator processes
publish): the same bytes as :func:`~stereod.bus.messages.dump_objects` of the model, at about
a twelfth of the cost, so that 16 generated rigs leave the host's cores to the node measured.
"""

from __future__ import annotations

import json
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import msgspec
import numpy as np

from stereod.bus.messages import (
    OBJECT_SCHEMA,
    OBJECTS_SCHEMA,
    EyeBlob,
    Latency,
    ObjectsMessage,
    ObjectState,
)
from stereod.fusion.room import RigPose
from stereod.tracking.types import TrackLifecycle
from stereod.vision.geometry import Geometry

FOCAL_PX = 554.3
"""Focal length of the canonical 640 px wide, 60 deg rig the blobs are projected with, px."""
BASELINE_M = 0.060
SIZE_M = 0.4
"""Every object's reported size, m."""
BLOB_AREA_PX = 600


@dataclass(frozen=True)
class Walker:
    """An object on a straight line in the room frame: at ``t0_ns`` (UTC) at ``start_m``,
    moving at ``velocity_mps`` (m, m/s)."""

    truth_id: int
    start_m: tuple[float, float, float]
    velocity_mps: tuple[float, float, float]
    t0_ns: int = 0

    def position(self, t_ns: int) -> np.ndarray:
        """Where it is at the UTC instant ``t_ns``, room frame, m."""
        dt = (t_ns - self.t0_ns) * 1e-9
        return np.asarray(self.start_m) + np.asarray(self.velocity_mps) * dt


class Crowd:
    """Walkers as arrays, so that where they all are is one numpy expression, not one call a
    walker and rig."""

    def __init__(self, walkers: list[Walker]) -> None:
        self.ids = [w.truth_id for w in walkers]
        self.start_m = np.array([w.start_m for w in walkers], dtype=np.float64).reshape(-1, 3)
        self.velocity_mps = np.array([w.velocity_mps for w in walkers], dtype=np.float64)
        self.velocity_mps = self.velocity_mps.reshape(-1, 3)
        self.t0_ns = np.array([w.t0_ns for w in walkers], dtype=np.int64)

    def positions(self, t_ns: int) -> np.ndarray:
        """Every walker's place at the UTC instant ``t_ns``, (n, 3), room frame, m (row k is
        ``Walker.position`` of walker k, to the bit)."""
        dt = (t_ns - self.t0_ns) * 1e-9
        return self.start_m + self.velocity_mps * dt[:, None]


@dataclass(frozen=True)
class _Seen:
    """What one rig reports at one instant: a row per object in view, rig frame, SI and px."""

    stamp: int
    track_ids: list[int]
    position_m: np.ndarray
    position_sigma_m: np.ndarray
    velocity_mps: np.ndarray
    speed_mps: np.ndarray
    heading_deg: np.ndarray
    disparity_px: np.ndarray
    centroid_px: np.ndarray
    """(n, 3): the left blob's u and v, the right blob's u, px."""

    def rows(
        self,
    ) -> Iterator[
        tuple[int, list[float], list[float], list[float], float, float, float, list[float]]
    ]:
        """Each object's figures as Python values: track id, position, its sigmas, velocity,
        speed, heading, disparity and the blobs' (u, v, right u)."""
        return zip(
            self.track_ids,
            self.position_m.tolist(),
            self.position_sigma_m.tolist(),
            self.velocity_mps.tolist(),
            self.speed_mps.tolist(),
            self.heading_deg.tolist(),
            self.disparity_px.tolist(),
            self.centroid_px.tolist(),
            strict=True,
        )


class _Blob(msgspec.Struct):
    """:class:`~stereod.bus.messages.EyeBlob`'s fields, in its order."""

    centroid_px: list[float]
    bbox_px: tuple[int, int, int, int]
    area_px: int


class _Object(msgspec.Struct):
    """:class:`~stereod.bus.messages.ObjectState`'s fields as its JSON has them, in its
    order (the wire's, field for field: the test holds them to the model's bytes)."""

    schema: str
    track_id: int
    state: str
    t_ns: int
    stamp_utc_ns: int
    skew_ns: int
    position_m: list[float]
    position_sigma_m: list[float]
    velocity_mps: list[float]
    velocity_sigma_mps: tuple[float, float, float]
    velocity_valid: bool
    heading_valid: bool
    speed_mps: float
    speed_sigma_mps: float
    heading_deg: float
    heading_sigma_deg: None
    raw_velocity_mps: None
    left: _Blob
    right: _Blob
    disparity_px: float
    size_m: float
    age_s: float
    extent_min_m: None
    extent_max_m: None


class _Latency(msgspec.Struct):
    detect_ms: float
    geometry_ms: float
    track_ms: float
    pipeline_ms: float
    queue_ms: float


class _Message(msgspec.Struct):
    """:class:`~stereod.bus.messages.ObjectsMessage`'s fields, in its order; the objects are
    their own payloads, written once and embedded as they are."""

    schema: str
    rig: str
    seq: int
    t_ns: int
    stamp_utc_ns: int
    skew_ns: int
    left_seq: int
    right_seq: int
    geometry: str
    calibration_id: None
    latency: _Latency
    objects: list[msgspec.Raw]


_ENCODE = msgspec.json.Encoder().encode
_NO_LATENCY = _Latency(0.0, 0.0, 0.0, 0.0, 0.0)
_CONFIRMED = TrackLifecycle.CONFIRMED.value
_CANONICAL = Geometry.CANONICAL.value


def _turned(d: np.ndarray, r: np.ndarray) -> np.ndarray:
    """R^T d for each row d of (n, 3), summed x, y, z in that order: the bits of ``r.T @ d``
    one row at a time, which a matrix product of all the rows at once does not keep."""
    return np.asarray(d[:, :1] * r[0] + d[:, 1:2] * r[1] + d[:, 2:] * r[2])


class RigSim:
    """One rig's daemon, as far as its objects messages go."""

    def __init__(
        self,
        pose: RigPose,
        *,
        hfov_deg: float = 60.0,
        range_m: float = 8.0,
        lateral_sigma_m: float = 0.01,
        depth_sigma_per_m2: float = 0.02,
        velocity_sigma_mps: float = 0.05,
        clock_offset_ns: int = 0,
        seed: int = 0,
    ) -> None:
        self.pose = pose
        self.hfov_deg = hfov_deg
        self.range_m = range_m
        self.lateral_sigma_m = lateral_sigma_m
        self.depth_sigma_per_m2 = depth_sigma_per_m2
        self.velocity_sigma_mps = velocity_sigma_mps
        self.clock_offset_ns = clock_offset_ns
        """What this rig's clock says minus the true UTC instant, ns."""
        self._rng = np.random.default_rng(seed)
        self._r = pose.rotation()
        self._t = pose.translation()
        self._ids: dict[int, int] = {}
        self._next = 1
        self.seq = 0

    def in_rig(self, p_room: np.ndarray) -> np.ndarray:
        """Room points, (n, 3), in this rig's frame: R^T (p - t) each."""
        return _turned(p_room - self._t, self._r)

    def visible(self, p_rig: np.ndarray) -> np.ndarray:
        """Which of (n, 3) rig-frame points are in front, inside the field of view and within
        range, (n,) bool."""
        x, z = p_rig[:, 0], p_rig[:, 2]
        half = math.radians(self.hfov_deg) / 2
        return np.asarray((z > 0.3) & (z <= self.range_m) & (np.abs(np.arctan2(x, z)) < half))

    def sees(self, p_room: np.ndarray) -> bool:
        """Whether a room point is in front, inside the field of view and within range."""
        return bool(
            self.visible(self.in_rig(np.asarray(p_room, dtype=np.float64).reshape(1, 3)))[0]
        )

    def _observe(self, crowd: Crowd, t_ns: int) -> _Seen:
        """The rig's view of ``crowd`` at the true instant ``t_ns`` (UTC ns): which walkers it
        sees, under which of its track ids, and what it measures of them, noise drawn in walker
        order (three for the position, three for the velocity, each)."""
        stamp = t_ns + self.clock_offset_ns
        p_rig = self.in_rig(crowd.positions(t_ns))
        rows = np.flatnonzero(self.visible(p_rig))
        ids: dict[int, int] = {}
        track_ids = []
        for k in rows.tolist():
            truth = crowd.ids[k]
            tid = ids.get(truth, self._ids.get(truth))
            if tid is None:
                tid = self._next
                self._next += 1
            ids[truth] = tid
            track_ids.append(tid)
        self._ids = ids
        p = p_rig[rows]
        v = _turned(crowd.velocity_mps[rows], self._r)
        z = p[:, 2]
        sig = np.empty_like(p)
        sig[:, :2] = self.lateral_sigma_m
        sig[:, 2] = self.depth_sigma_per_m2 * z * z
        noise = self._rng.standard_normal((len(rows), 6))
        pos = p + (0.0 + sig * noise[:, :3])
        vel = v + (0.0 + self.velocity_sigma_mps * noise[:, 3:])
        zc = np.maximum(z, 0.1)
        disparity = FOCAL_PX * BASELINE_M / zc
        u = 320.0 + FOCAL_PX * pos[:, 0] / zc
        centroid = np.stack([u, 320.0 + FOCAL_PX * pos[:, 1] / zc, u - disparity], axis=1)
        return _Seen(
            stamp=stamp,
            track_ids=track_ids,
            position_m=pos,
            position_sigma_m=sig,
            velocity_mps=vel,
            speed_mps=np.linalg.norm(vel, axis=1),
            heading_deg=np.degrees(np.arctan2(vel[:, 0], vel[:, 2])) % 360.0,
            disparity_px=disparity,
            centroid_px=centroid,
        )

    def message(self, walkers: list[Walker] | Crowd, t_ns: int) -> ObjectsMessage:
        """This rig's objects message of the true instant ``t_ns`` (UTC ns), as the wire
        model."""
        seen = self._observe(walkers if isinstance(walkers, Crowd) else Crowd(walkers), t_ns)
        vs = self.velocity_sigma_mps
        objects = [
            # Unvalidated: typed values only, as the payload writer's.
            ObjectState.model_construct(
                track_id=tid,
                state=TrackLifecycle.CONFIRMED,
                t_ns=seen.stamp,
                stamp_utc_ns=seen.stamp,
                skew_ns=0,
                position_m=(pos[0], pos[1], pos[2]),
                position_sigma_m=(sig[0], sig[1], sig[2]),
                velocity_mps=(vel[0], vel[1], vel[2]),
                velocity_sigma_mps=(vs, vs, vs),
                velocity_valid=True,
                heading_valid=True,
                speed_mps=speed,
                speed_sigma_mps=vs,
                heading_deg=heading,
                heading_sigma_deg=None,
                raw_velocity_mps=None,
                left=EyeBlob(
                    centroid_px=(u, w),
                    bbox_px=(int(u) - 10, int(w) - 20, 20, 40),
                    area_px=BLOB_AREA_PX,
                ),
                right=EyeBlob(
                    centroid_px=(ur, w),
                    bbox_px=(int(ur) - 10, int(w) - 20, 20, 40),
                    area_px=BLOB_AREA_PX,
                ),
                disparity_px=disparity,
                size_m=SIZE_M,
                age_s=0.0,
            )
            for tid, pos, sig, vel, speed, heading, disparity, (u, w, ur) in seen.rows()
        ]
        msg = ObjectsMessage(
            rig=self.pose.name,
            seq=self.seq,
            t_ns=seen.stamp,
            stamp_utc_ns=seen.stamp,
            skew_ns=0,
            left_seq=self.seq,
            right_seq=self.seq,
            geometry=Geometry.CANONICAL,
            latency=Latency(
                detect_ms=0.0, geometry_ms=0.0, track_ms=0.0, pipeline_ms=0.0, queue_ms=0.0
            ),
            objects=objects,
        )
        self.seq += 1
        return msg

    def payload(self, crowd: Crowd, t_ns: int) -> tuple[bytes, list[tuple[int, bytes]]]:
        """This rig's objects payload of the true instant ``t_ns`` (UTC ns) and each object's
        own (track id, payload): ``dump_objects(self.message(crowd, t_ns))`` to the byte,
        written by ``msgspec`` with no model in between."""
        seen = self._observe(crowd, t_ns)
        stamp, vs = seen.stamp, self.velocity_sigma_mps
        vsig = (vs, vs, vs)
        states = []
        for tid, pos, sig, vel, speed, heading, disparity, (u, w, ur) in seen.rows():
            left = _Blob([u, w], (int(u) - 10, int(w) - 20, 20, 40), BLOB_AREA_PX)
            right = _Blob([ur, w], (int(ur) - 10, int(w) - 20, 20, 40), BLOB_AREA_PX)
            obj = _Object(
                OBJECT_SCHEMA, tid, _CONFIRMED, stamp, stamp, 0, pos, sig, vel, vsig, True, True,
                speed, vs, heading, None, None, left, right, disparity, SIZE_M, 0.0, None, None,
            )  # fmt: skip
            states.append(_ENCODE(obj))
        head = _Message(
            OBJECTS_SCHEMA, self.pose.name, self.seq, stamp, stamp, 0, self.seq, self.seq,
            _CANONICAL, None, _NO_LATENCY, [msgspec.Raw(s) for s in states],
        )  # fmt: skip
        self.seq += 1
        return _ENCODE(head), list(zip(seen.track_ids, states, strict=True))


def walkers_from_json(text: str) -> list[Walker]:
    """Walkers from JSON: ``[{"id": 1, "start_m": [x, y, z], "velocity_mps": [...],
    "t0_ns": T}, ...]`` (room frame, UTC ns)."""
    return [
        Walker(
            int(w["id"]),
            tuple(w["start_m"]),
            tuple(w["velocity_mps"]),
            int(w.get("t0_ns", 0)),
        )
        for w in json.loads(text)
    ]


def main(argv: list[str] | None = None) -> int:
    """Rig daemons, as message generators: ``python -m stereod_fakes.room_messages ROOM RIG
    [RIG ...] --connect EP --walkers JSON`` publishes each rig's objects of the walkers at
    ``--fps`` (stamped with this machine's UTC clock, plus ``--clock-offset-ms``) through a
    real Publisher per rig, until SIGTERM or ``--seconds``. Prints ``up`` once publishing;
    with ``--report``, at the end one JSON line of what it sent and where its main thread's
    CPU went (``messages`` in ``seconds``; ``build_s``: writing them, ``publish_s``: the
    Publisher's calls, s)."""
    import argparse
    import contextlib

    from stereod.bus.publish import Publisher
    from stereod.daemon.config import ZenohConfig
    from stereod.fusion.room import load_room

    p = argparse.ArgumentParser(prog="room_messages")
    p.add_argument("room", type=Path)
    p.add_argument("rigs", nargs="+")
    p.add_argument("--connect", action="append", default=[])
    p.add_argument("--mode", default="peer")
    p.add_argument("--walkers", required=True)
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--seconds", type=float, default=3600.0)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--clock-offset-ms", type=float, default=0.0)
    p.add_argument(
        "--depth-sigma-per-m2", type=float, default=0.02, help="depth sigma per squared depth"
    )
    p.add_argument(
        "--t0-from-stdin",
        action="store_true",
        help="after 'up', read one line: the walkers' t0_ns (UTC ns), so that processes "
        "started one after another share one truth",
    )
    p.add_argument(
        "--report", action="store_true", help="print the messages sent and their CPU at the end"
    )
    p.add_argument(
        "--stagger",
        type=float,
        default=None,
        help="publish rig k of this process's n at (k + STAGGER) / n of each frame period, "
        "as rigs on hosts of their own are not in phase (default: all at the frame's start)",
    )
    a = p.parse_args(argv)
    room = load_room(a.room)
    sims = []
    for i, name in enumerate(a.rigs):
        pose = room.rig(name)
        if pose is None:
            p.error(f"{a.room} has no rig {name!r}")
        offset = int(a.clock_offset_ms * 1e6)
        sims.append(
            RigSim(
                pose,
                seed=a.seed + i,
                clock_offset_ns=offset,
                depth_sigma_per_m2=a.depth_sigma_per_m2,
            )
        )
    walkers = walkers_from_json(a.walkers)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    signal.signal(signal.SIGINT, lambda *_: done.set())
    cfg = ZenohConfig(connect=a.connect, mode=a.mode)
    period = 1.0 / a.fps
    with contextlib.ExitStack() as stack:
        pubs = [stack.enter_context(Publisher(cfg, s.pose.name, {})) for s in sims]
        print("up", flush=True)
        if a.t0_from_stdin:
            t0 = int(sys.stdin.readline())
            walkers = [Walker(w.truth_id, w.start_m, w.velocity_mps, t0) for w in walkers]
        crowd = Crowd(walkers)
        start = time.monotonic()
        tick = 0
        live: list[set[int]] = [set() for _ in sims]
        build_s = publish_s = 0.0
        n = len(sims)
        phases = [0.0 if a.stagger is None else (k + a.stagger) / n * period for k in range(n)]
        while not done.is_set() and time.monotonic() - start < a.seconds:
            frame = start + tick * period
            for k, (sim, pub) in enumerate(zip(sims, pubs, strict=True)):
                if phases[k] and done.wait(max(0.0, frame + phases[k] - time.monotonic())):
                    break
                c0 = time.thread_time()
                payload, tracks = sim.payload(crowd, time.time_ns())
                ids = {tid for tid, _ in tracks}
                c1 = time.thread_time()
                pub.objects(payload, tracks, sorted(live[k] - ids))
                build_s += c1 - c0
                publish_s += time.thread_time() - c1
                live[k] = ids
            tick += 1
            done.wait(max(0.0, start + tick * period - time.monotonic()))
        if a.report:
            sent = sum(pub.published for pub in pubs)
            report = {"messages": sent, "seconds": time.monotonic() - start}
            print(json.dumps(report | {"build_s": build_s, "publish_s": publish_s}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
