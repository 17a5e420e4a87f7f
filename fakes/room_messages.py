"""Rig objects messages made from a room's known 3D truth, with no rendering: what several
rig daemons would publish about objects walking through one room, for the fusion's tests and
its scale benchmark.

Each :class:`RigSim` is one rig at a pose of the room file. An object is visible to it when it
is in front, inside its horizontal field of view and within its range; the rig then reports
it under a track id of its own (a new one each time the object comes into view, as a daemon's
tracker would), at the truth moved into the rig frame plus Gaussian noise whose sigmas it also
reports: about 1 cm across the view and ``depth_sigma_per_m2`` times the squared depth along
it, as a stereo rig's depth error grows. ``seed`` makes the noise repeatable.
"""

from __future__ import annotations

import json
import math
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from stereod.bus.messages import EyeBlob, Latency, ObjectsMessage, ObjectState
from stereod.fusion.room import RigPose
from stereod.tracking.types import TrackLifecycle
from stereod.vision.geometry import Geometry

FOCAL_PX = 554.3
"""Focal length of the canonical 640 px wide, 60 deg rig the blobs are projected with, px."""
BASELINE_M = 0.060


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
        """A room point in this rig's frame: R^T (p - t)."""
        return np.asarray(self._r.T @ (p_room - self._t))

    def sees(self, p_room: np.ndarray) -> bool:
        """Whether a point is in front, inside the field of view and within range."""
        x, _, z = self.in_rig(p_room)
        half = math.radians(self.hfov_deg) / 2
        return bool(0.3 < z <= self.range_m and abs(math.atan2(x, z)) < half)

    def message(self, walkers: list[Walker], t_ns: int) -> ObjectsMessage:
        """This rig's objects message of the true instant ``t_ns`` (UTC ns)."""
        stamp = t_ns + self.clock_offset_ns
        objects: list[ObjectState] = []
        seen: set[int] = set()
        for w in walkers:
            p = w.position(t_ns)
            if not self.sees(p):
                continue
            seen.add(w.truth_id)
            tid = self._ids.get(w.truth_id)
            if tid is None:
                tid = self._ids[w.truth_id] = self._next
                self._next += 1
            objects.append(self._state(tid, self.in_rig(p), self._r.T @ w.velocity_mps, stamp))
        for gone in [k for k in self._ids if k not in seen]:
            del self._ids[gone]
        msg = ObjectsMessage(
            rig=self.pose.name,
            seq=self.seq,
            t_ns=stamp,
            stamp_utc_ns=stamp,
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

    def _state(self, tid: int, p: np.ndarray, v: np.ndarray, stamp: int) -> ObjectState:
        z = float(p[2])
        sig = np.array(
            [self.lateral_sigma_m, self.lateral_sigma_m, self.depth_sigma_per_m2 * z * z]
        )
        pos = p + self._rng.normal(0.0, sig)
        vel = v + self._rng.normal(0.0, self.velocity_sigma_mps, 3)
        speed = float(np.linalg.norm(vel))
        disparity = FOCAL_PX * BASELINE_M / max(z, 0.1)
        u = 320.0 + FOCAL_PX * float(pos[0]) / max(z, 0.1)
        w = 320.0 + FOCAL_PX * float(pos[1]) / max(z, 0.1)
        blob = EyeBlob(centroid_px=(u, w), bbox_px=(int(u) - 10, int(w) - 20, 20, 40), area_px=600)
        right = EyeBlob(
            centroid_px=(u - disparity, w),
            bbox_px=(int(u - disparity) - 10, int(w) - 20, 20, 40),
            area_px=600,
        )
        # Unvalidated: typed values only, and 16 rigs x 30 Hz must cost the benchmark little.
        return ObjectState.model_construct(
            track_id=tid,
            state=TrackLifecycle.CONFIRMED,
            t_ns=stamp,
            stamp_utc_ns=stamp,
            skew_ns=0,
            position_m=(float(pos[0]), float(pos[1]), float(pos[2])),
            position_sigma_m=(float(sig[0]), float(sig[1]), float(sig[2])),
            velocity_mps=(float(vel[0]), float(vel[1]), float(vel[2])),
            velocity_sigma_mps=(self.velocity_sigma_mps,) * 3,
            velocity_valid=True,
            heading_valid=True,
            speed_mps=speed,
            speed_sigma_mps=self.velocity_sigma_mps,
            heading_deg=math.degrees(math.atan2(float(vel[0]), float(vel[2]))) % 360.0,
            heading_sigma_deg=None,
            raw_velocity_mps=None,
            left=blob,
            right=right,
            disparity_px=disparity,
            size_m=0.4,
            age_s=0.0,
        )


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
    real Publisher per rig, until SIGTERM or ``--seconds``. Prints ``up`` once publishing."""
    import argparse
    import contextlib

    from stereod.bus.messages import dump_objects
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
        start = time.monotonic()
        tick = 0
        live: list[set[int]] = [set() for _ in sims]
        while not done.is_set() and time.monotonic() - start < a.seconds:
            for k, (sim, pub) in enumerate(zip(sims, pubs, strict=True)):
                payload, tracks = dump_objects(sim.message(walkers, time.time_ns()))
                ids = {tid for tid, _ in tracks}
                pub.objects(payload, tracks, sorted(live[k] - ids))
                live[k] = ids
            tick += 1
            done.wait(max(0.0, start + tick * period - time.monotonic()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
