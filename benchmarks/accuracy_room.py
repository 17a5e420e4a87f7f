"""The room table's fused rows of ``benchmarks/accuracy.py``: rooms rendered from several rig
poses (``stereod_fakes.world.rooms``), every rig's views through the pipeline, its tracks fused
as ``stereod fuse`` does, each ball scored (room ids, id switches, extra tracks, and the
position, heading and speed errors of the room's tracks and of each rig alone).
"""

from __future__ import annotations

import itertools
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import numpy as np

from stereod import CanonicalRig, Pipeline, PipelineParams
from stereod.bus.messages import ObjectsMessage, ObjectState, objects_message
from stereod.fusion.clock import ClockWatch
from stereod.fusion.fuser import Fuser
from stereod.fusion.output import room_states
from stereod.fusion.room import RigPose, Room
from stereod.tracking.motion import angle_diff_deg
from stereod.vision.geometry import Geometry
from stereod_fakes.world import Scene as WorldScene
from stereod_fakes.world.rooms import RigPlacement, crossing_room, rig_scene, three_rig_room
from tests import accuracy as acc


def _f(x: float, fmt: str) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


FUSION_GATE_M = 0.35
"""A track within this distance (m) of a ball's true centre in a fused room is that ball's."""


@dataclass
class FusionRow:
    """One object of one room scene fused from its rigs: room ids, id switches, and the
    median errors of the room's tracks (``fused``) and of each rig's alone, against the truth
    (position m, heading deg, speed as a share; NaN where a rig never saw it)."""

    scene: str
    obj: str
    ids: int
    switches: int
    position_m: dict[str, float]
    heading_deg: dict[str, float]
    speed: dict[str, float]
    overlap_m: dict[str, float]
    """The median position error (m) over the instants two rigs or more saw it (and the room
    had it): ``fused`` and each of those rigs."""
    extra: dict[str, int]
    """Tracks (room or a rig's) that came within the gate of it at an instant another track
    of the same was nearer: duplicates or ghosts, per ``fused`` and rig."""


RoomBuilder = Callable[[], tuple[WorldScene, list[RigPlacement]]]


def room_scenes() -> list[tuple[str, RoomBuilder]]:
    """The renderer's room scenes fused for the room table: (name, builder)."""
    return [("three_rigs", three_rig_room), ("crossing_rigs", crossing_room)]


def _room_messages(scene: WorldScene, placements: list[RigPlacement]) -> list[ObjectsMessage]:
    """Every rig's objects messages for a room scene: each rig's view rendered (or read from
    ``STEREOD_WORLD_CACHE``) and run through the pipeline as its daemon would, all stamped
    on the scene's one clock."""
    out = []
    for pl in placements:
        rs = rig_scene(scene, pl)
        r = rs.rig
        params = PipelineParams(CanonicalRig(r.baseline_m, r.hfov_deg, r.width_px, r.height_px))
        tol = int(0.75e9 * rs.clock("left").period_s)
        with Pipeline(params) as pipe:
            for res in pipe.run(acc.world_frames(rs), tol):
                msg = objects_message(
                    res, rig=pl.name, geometry=Geometry.CANONICAL, calibration_id=None,
                    utc_offset_ns=0,
                )  # fmt: skip
                out.append(msg)
    return out


Sighting = tuple[str, int, str, np.ndarray, np.ndarray, bool, bool, int]
"""(who: a rig or ``fused``, stamp ns, object, room position m, room velocity m/s, velocity
valid, heading valid, track id) of one track state near a ball."""


def _errors(scene: WorldScene, ss: list[Sighting]) -> tuple[float, float, float]:
    """Median position (m), heading (deg) and speed (share) errors of sightings of one ball."""
    err_p, err_h, err_s = [], [], []
    for _, t_ns, obj, p, v, vvalid, hvalid, _ in ss:
        tp, tv = scene.truth(t_ns)[obj]
        err_p.append(float(np.linalg.norm(p - tp)))
        true_speed = float(np.linalg.norm(tv))
        if true_speed < acc.STILL_MPS:
            continue
        if hvalid:
            h = math.degrees(math.atan2(v[0], v[2]))
            err_h.append(angle_diff_deg(h, math.degrees(math.atan2(tv[0], tv[2]))))
        if vvalid:
            err_s.append((float(np.linalg.norm(v)) - true_speed) / true_speed)
    return (
        float(np.median(err_p)),
        float(np.median(err_h)) if err_h else math.nan,
        float(np.median(err_s)) if err_s else math.nan,
    )


def fusion_rows(name: str, build: RoomBuilder) -> list[FusionRow]:
    """Fuse one room scene (every rig's messages of one capture instant, then a fusion step
    there, as the fusion node does when they arrive together) and score each ball."""
    scene, placements = build()
    poses = {p.name: p for p in placements}
    room = Room(
        name=name,
        rigs=[
            RigPose(name=p.name, translation_m=p.translation_m, rotation_deg=p.rotation_deg)
            for p in placements
        ],
    )
    msgs = sorted(_room_messages(scene, placements), key=lambda m: m.stamp_utc_ns)
    fuser = Fuser(room)
    clock = ClockWatch([r.name for r in room.rigs])
    seen: list[Sighting] = []
    extra: dict[tuple[str, str], set[int]] = {}

    def score(
        who: str, t_ns: int, states: list[ObjectState], rot: np.ndarray, t: np.ndarray
    ) -> None:
        """The nearest confirmed track to each ball (within the gate) is its sighting; any
        other within the gate is an extra track of ``who`` on it."""
        truth = scene.truth(t_ns)
        best: dict[str, tuple[float, Sighting]] = {}
        for o in states:
            if o.state.value not in ("confirmed", "stationary"):
                continue
            p = rot @ np.array(o.position_m) + t
            d = {n: float(np.linalg.norm(p - tp)) for n, (tp, _) in truth.items()}
            near = min(d, key=d.__getitem__) if d else None
            if near is None or d[near] > FUSION_GATE_M:
                continue
            v = rot @ np.array(o.velocity_mps)
            got = (who, t_ns, near, p, v, o.velocity_valid, o.heading_valid, o.track_id)
            if near in best:
                worse = got if d[near] >= best[near][0] else best[near][1]
                extra.setdefault((who, near), set()).add(worse[7])
            if near not in best or d[near] < best[near][0]:
                best[near] = (d[near], got)
        seen.extend(s for _, s in best.values())

    for k, m in enumerate(msgs):
        pl = poses[m.rig]
        score(m.rig, m.stamp_utc_ns, m.objects, pl.rotation(), np.array(pl.translation_m))
        fuser.ingest(m)
        if k + 1 < len(msgs) and msgs[k + 1].stamp_utc_ns == m.stamp_utc_ns:
            continue
        frame = fuser.fuse(m.stamp_utc_ns)
        clock.observe(frame)  # and a trusted clock offset corrected, as the node does
        fuser.clock_corrections_ns = dict(clock.corrections_ns)
        score("fused", frame.t_ns, room_states(frame.tracks), np.eye(3), np.zeros(3))
    rows = []
    for obj in (o.name for o in scene.objects):
        mine = [s for s in seen if s[2] == obj]
        room_ids = [s[7] for s in mine if s[0] == "fused"]
        row = FusionRow(
            name, obj, len(set(room_ids)), sum(a != b for a, b in itertools.pairwise(room_ids)),
            {}, {}, {}, {}, {},
        )  # fmt: skip
        for who in ["fused", *poses]:
            ss = [s for s in mine if s[0] == who]
            if ss:
                row.position_m[who], row.heading_deg[who], row.speed[who] = _errors(scene, ss)
        rigs_at: dict[int, set[str]] = {}
        for s in mine:
            rigs_at.setdefault(s[1], set()).add(s[0])
        shared = {t for t, who in rigs_at.items() if "fused" in who and len(who) >= 3}
        overlap: dict[str, list[float]] = {}
        for s in mine:
            if s[1] in shared:
                err = float(np.linalg.norm(s[3] - scene.truth(s[1])[obj][0]))
                overlap.setdefault(s[0], []).append(err)
        row.overlap_m = {k: float(np.median(v)) for k, v in overlap.items()}
        row.extra = {who: len(extra.get((who, obj), ())) for who in ["fused", *poses]}
        rows.append(row)
    return rows


def fusion_table(rows: list[FusionRow]) -> str:
    """The fused rooms: per object, room ids and id switches of its nearest room track, extra
    tracks on it, and the median position (cm), heading (deg) and speed (%) errors of the
    room's tracks and of each rig alone."""
    lines = [
        "| scene | object | room ids | id switches | extra tracks: room; per rig "
        "| position err (cm): fused; per rig "
        "| in an overlap (cm): fused; per rig | heading err (deg): fused; per rig "
        "| speed err (%): fused; per rig |",
        "|---|---|---|---|---|---|---|---|---|",
    ]

    def cols(d: dict[str, float], scale: float, fmt: str) -> str:
        rigs = "; ".join(f"{k} {_f(v * scale, fmt)}" for k, v in d.items() if k != "fused")
        return f"**{_f(d.get('fused', math.nan) * scale, fmt)}**; {rigs or '-'}"

    for r in rows:
        lines.append(
            f"| {r.scene} | {r.obj} | {r.ids} | {r.switches} | {r.extra.get('fused', 0)}; "
            + "; ".join(f"{k} {v}" for k, v in r.extra.items() if k != "fused")
            + f" | {cols(r.position_m, 100, '.2f')} "
            f"| {cols(r.overlap_m, 100, '.2f') if r.overlap_m else '-'} "
            f"| {cols(r.heading_deg, 1, '+.2f')} | {cols(r.speed, 100, '+.1f')} |"
        )
    return "\n".join(lines)


def fusion_section() -> str:
    """The room table's fused part: every room scene rendered, run per rig and fused."""
    rows = [row for name, build in room_scenes() for row in fusion_rows(name, build)]
    return (
        "Rigs fused into one room (`stereod fuse`'s core, every rig's views through the "
        "pipeline, each rig's tracks moved into the room by its pose). Per instant the track "
        f"nearest a ball within {FUSION_GATE_M:g} m is its own (its ids and switches, its "
        "errors: medians over those instants); another one within that distance is an extra "
        "track (a duplicate in the room, a ghost in a rig):\n\n" + fusion_table(rows)
    )
