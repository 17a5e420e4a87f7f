"""Tracks of several rigs as one set of room tracks with one id per object.

Each rig's latest message gives its live tracks (moved into the room frame at arrival). A
fusion step at a common UTC instant ``T`` predicts every rig track to ``T``, keeps the links
made before (a rig's track id stays with the room id it was first given), and associates the
rig tracks not linked yet to the room tracks, rig by rig: the squared Mahalanobis distance of
a rig track to a room track's estimate at ``T`` (the fusion of its linked members, else its own
prediction) is gated by a chi-square bound, a room track takes at most one track of each rig,
and one minimum-cost assignment (:func:`~stereod.assignment.min_cost_assignment`) decides. A
seen rig track left over opens a new room track. The linked members of a room track are then
fused in information form, ``P = (sum P_i^-1)^-1``, ``x = P sum P_i^-1 x_i``, for position and
velocity alike (the rigs measure independently, so the fused error is no larger than the best
member's).

Why ids survive: a handover is a new rig track gated onto the room track another rig still
sees (or has seen for less than ``max_coast_s``); a rig that stops talking for ``rig_timeout_s``
(or whose sequence numbers start again: its daemon restarted, its track ids may repeat) loses
its links, and its tracks, when they come back, are associated like any new ones, so they join
the room tracks the other rigs kept alive instead of opening duplicates.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..assignment import min_cost_assignment
from ..messages import ObjectsMessage
from ..tracking import TrackLifecycle
from .frames import RigTrack, predict, predicted, to_room
from .room import Room

CHI2_3DOF_999 = 16.27
"""Squared Mahalanobis distance below which 99.9 % of a 3-D Gaussian's samples fall."""
_FORBIDDEN = 1e9


@dataclass(frozen=True)
class FuseParams:
    """How association and track ends are decided (s, dimensionless chi-square bounds)."""

    gate_chi2: float = CHI2_3DOF_999
    """A rig track further than this squared Mahalanobis distance is not that room track."""
    rig_timeout_s: float = 1.0
    """A rig silent this long (by its stamps against the fusion instant) loses its tracks, s."""
    max_coast_s: float = 2.0
    """A room track no rig sees for this long ends, s."""


@dataclass
class RoomTrack:
    """One object in the room: its id, fused state at ``stamp_utc_ns`` and which rig tracks
    make it (m, m/s, UTC ns)."""

    room_id: int
    stamp_utc_ns: int
    first_ns: int
    last_seen_ns: int
    position: np.ndarray
    position_cov: np.ndarray
    velocity: np.ndarray
    velocity_cov: np.ndarray
    state: TrackLifecycle = TrackLifecycle.CONFIRMED
    members: dict[str, int] = field(default_factory=dict)
    """Rig name -> that rig's track id, for the rig tracks linked to this object."""
    best: RigTrack | None = None
    """The member whose position weighed most at the last step (its blobs are reported)."""
    velocity_valid: bool = False
    heading_valid: bool = False


@dataclass(frozen=True)
class FusedFrame:
    """One fusion step's result: the room tracks at ``t_ns`` and the ids that ended."""

    t_ns: int
    tracks: list[RoomTrack]
    ended: list[int]
    observed: dict[int, list[RigTrack]] = field(default_factory=dict)
    """Each room id's rig tracks at ``t_ns`` (room frame), the fused state's inputs."""


def fuse_gaussians(
    means: list[np.ndarray], covs: list[np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """The information-form fusion of independent Gaussian estimates of one quantity: the
    covariance ``(sum C_i^-1)^-1`` and mean ``C sum C_i^-1 m_i``."""
    if len(means) == 1:
        return means[0].copy(), covs[0].copy()
    infos = [np.linalg.inv(c) for c in covs]
    cov = np.linalg.inv(np.sum(infos, axis=0))
    mean = cov @ np.sum([i @ m for i, m in zip(infos, means, strict=True)], axis=0)
    return mean, 0.5 * (cov + cov.T)


def mahalanobis2(a: np.ndarray, a_cov: np.ndarray, b: np.ndarray, b_cov: np.ndarray) -> float:
    """Squared Mahalanobis distance between two independent Gaussian positions."""
    d = a - b
    return float(d @ np.linalg.solve(a_cov + b_cov, d))


class Fuser:
    """The fusion of one room's rigs; feed it each rig's objects messages with :meth:`ingest`
    and ask for the room at an instant with :meth:`fuse`. Not thread-safe: one caller."""

    def __init__(self, room: Room, params: FuseParams | None = None) -> None:
        self.room = room
        self.params = params or FuseParams()
        self._poses = {r.name: r for r in room.rigs}
        self._order = [r.name for r in room.rigs]
        self._rig_tracks: dict[str, dict[int, RigTrack]] = {}
        self._rig_last_ns: dict[str, int] = {}
        self._rig_seq: dict[str, int] = {}
        self._links: dict[tuple[str, int], int] = {}
        self._tracks: dict[int, RoomTrack] = {}
        self._next_id = 1
        self.restarts: dict[str, int] = {}
        """Times each rig's sequence numbers started again (its daemon restarted)."""

    def knows(self, rig: str) -> bool:
        """Whether ``rig`` is one of the room's rigs."""
        return rig in self._poses

    def ingest(self, msg: ObjectsMessage) -> bool:
        """Take a rig's objects message (a rig not in the room is ignored: False). Its tracks
        replace that rig's previous ones; a sequence number lower than the last one means the
        daemon restarted, and its old links are forgotten."""
        pose = self._poses.get(msg.rig)
        if pose is None:
            return False
        last = self._rig_seq.get(msg.rig)
        if last is not None and msg.seq < last:
            self._forget_rig(msg.rig)
            self.restarts[msg.rig] = self.restarts.get(msg.rig, 0) + 1
        self._rig_seq[msg.rig] = msg.seq
        self._rig_last_ns[msg.rig] = msg.stamp_utc_ns
        self._rig_tracks[msg.rig] = {
            o.track_id: to_room(pose, o) for o in msg.objects if o.state != TrackLifecycle.TENTATIVE
        }
        return True

    def _forget_rig(self, rig: str) -> None:
        self._rig_tracks.pop(rig, None)
        for key in [k for k in self._links if k[0] == rig]:
            room_id = self._links.pop(key)
            track = self._tracks.get(room_id)
            if track is not None:
                track.members.pop(rig, None)

    def live_rigs(self, t_ns: int) -> list[str]:
        """The rigs heard from within ``rig_timeout_s`` of ``t_ns``, in the room file's order."""
        timeout_ns = int(self.params.rig_timeout_s * 1e9)
        return [
            r
            for r in self._order
            if r in self._rig_last_ns and t_ns - self._rig_last_ns[r] <= timeout_ns
        ]

    def rig_track_count(self, rig: str) -> int:
        """How many (not tentative) tracks ``rig``'s latest message held."""
        return len(self._rig_tracks.get(rig, {}))

    def rig_stamp(self, rig: str) -> int | None:
        """The UTC stamp of ``rig``'s latest message, ns (None before its first)."""
        return self._rig_last_ns.get(rig)

    def latest_ns(self) -> int | None:
        """The newest stamp of any rig's message (UTC ns), or None before the first."""
        return max(self._rig_last_ns.values(), default=None)

    def fuse(self, t_ns: int) -> FusedFrame:
        """The room at the UTC instant ``t_ns`` (ns): every rig track predicted there,
        associated, fused; room tracks no rig has seen for ``max_coast_s`` end."""
        live = self.live_rigs(t_ns)
        for rig in [r for r in self._rig_tracks if r not in live]:
            self._forget_rig(rig)
        current: dict[tuple[str, int], RigTrack] = {
            (rig, tid): predicted(tr, t_ns)
            for rig in live
            for tid, tr in self._rig_tracks.get(rig, {}).items()
        }
        for key in [k for k in self._links if k not in current]:
            track = self._tracks.get(self._links.pop(key))
            if track is not None and track.members.get(key[0]) == key[1]:
                del track.members[key[0]]
        members: dict[int, list[RigTrack]] = {rid: [] for rid in self._tracks}
        for key, room_id in self._links.items():
            members[room_id].append(current[key])
        estimate = {rid: self._estimate(rid, members[rid], t_ns) for rid in self._tracks}
        for rig in live:
            self._associate(rig, current, members, estimate, t_ns)
        ended = self._update(members, t_ns)
        # Copies: the caller may keep a frame while the next steps change the tracks.
        tracks = [replace(tr, members=dict(tr.members)) for _, tr in sorted(self._tracks.items())]
        return FusedFrame(t_ns=t_ns, tracks=tracks, ended=ended, observed=members)

    def _estimate(
        self, room_id: int, linked: list[RigTrack], t_ns: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """A room track's position and covariance at ``t_ns``: its linked members' fusion, or
        its last fused state predicted."""
        if linked:
            return fuse_gaussians([m.position for m in linked], [m.position_cov for m in linked])
        tr = self._tracks[room_id]
        p, pc, _, _ = predict(
            tr.position, tr.position_cov, tr.velocity, tr.velocity_cov,
            (t_ns - tr.stamp_utc_ns) * 1e-9,
        )  # fmt: skip
        return p, pc

    def _associate(
        self,
        rig: str,
        current: dict[tuple[str, int], RigTrack],
        members: dict[int, list[RigTrack]],
        estimate: dict[int, tuple[np.ndarray, np.ndarray]],
        t_ns: int,
    ) -> None:
        """Link ``rig``'s unlinked tracks to room tracks that have no track of ``rig`` yet (one
        gated assignment); a seen track left over opens a room track."""
        free = [tr for (r, tid), tr in current.items() if r == rig and (r, tid) not in self._links]
        if not free:
            return
        taken = {rid for rid, ms in members.items() if any(m.rig == rig for m in ms)}
        candidates = [rid for rid in sorted(members) if rid not in taken]
        cost = np.full((len(free), len(candidates)), _FORBIDDEN)
        for i, tr in enumerate(free):
            for j, rid in enumerate(candidates):
                p, pc = estimate[rid]
                d2 = mahalanobis2(tr.position, tr.position_cov, p, pc)
                if d2 <= self.params.gate_chi2:
                    cost[i, j] = d2
        matched: set[int] = set()
        if candidates:
            for i, j in zip(*min_cost_assignment(cost), strict=True):
                if cost[i, j] < _FORBIDDEN:
                    self._link(free[i], candidates[j], members, estimate)
                    matched.add(int(i))
        for i, tr in enumerate(free):
            if i not in matched and tr.seen:
                rid = self._open(tr, t_ns)
                members[rid] = []
                self._link(tr, rid, members, estimate)

    def _link(
        self,
        tr: RigTrack,
        room_id: int,
        members: dict[int, list[RigTrack]],
        estimate: dict[int, tuple[np.ndarray, np.ndarray]],
    ) -> None:
        self._links[(tr.rig, tr.track_id)] = room_id
        self._tracks[room_id].members[tr.rig] = tr.track_id
        members[room_id].append(tr)
        ms = members[room_id]
        estimate[room_id] = fuse_gaussians([m.position for m in ms], [m.position_cov for m in ms])

    def _open(self, tr: RigTrack, t_ns: int) -> int:
        rid = self._next_id
        self._next_id += 1
        self._tracks[rid] = RoomTrack(
            room_id=rid,
            stamp_utc_ns=t_ns,
            first_ns=t_ns,
            last_seen_ns=t_ns,
            position=tr.position.copy(),
            position_cov=tr.position_cov.copy(),
            velocity=tr.velocity.copy(),
            velocity_cov=tr.velocity_cov.copy(),
        )
        return rid

    def _update(self, members: dict[int, list[RigTrack]], t_ns: int) -> list[int]:
        """Fuse each room track's members at ``t_ns``; coast those with none; end the ones
        unseen for ``max_coast_s``. Returns the ended ids."""
        ended: list[int] = []
        coast_ns = int(self.params.max_coast_s * 1e9)
        for rid, tr in list(self._tracks.items()):
            ms = members.get(rid, [])
            if ms:
                tr.position, tr.position_cov = fuse_gaussians(
                    [m.position for m in ms], [m.position_cov for m in ms]
                )
                tr.velocity, tr.velocity_cov = fuse_gaussians(
                    [m.velocity for m in ms], [m.velocity_cov for m in ms]
                )
                tr.best = min(ms, key=lambda m: float(np.trace(m.position_cov)))
                tr.velocity_valid = any(m.velocity_valid for m in ms)
                tr.heading_valid = any(m.heading_valid for m in ms)
                if any(m.seen for m in ms):
                    tr.last_seen_ns = t_ns
                    stationary = all(m.state == TrackLifecycle.STATIONARY for m in ms if m.seen)
                    tr.state = TrackLifecycle.STATIONARY if stationary else TrackLifecycle.CONFIRMED
                else:
                    tr.state = TrackLifecycle.COASTING
            else:
                tr.position, tr.position_cov, tr.velocity, tr.velocity_cov = predict(
                    tr.position, tr.position_cov, tr.velocity, tr.velocity_cov,
                    (t_ns - tr.stamp_utc_ns) * 1e-9,
                )  # fmt: skip
                tr.state = TrackLifecycle.COASTING
            tr.stamp_utc_ns = t_ns
            if t_ns - tr.last_seen_ns > coast_ns:
                ended.append(rid)
                del self._tracks[rid]
                for rig, tid in tr.members.items():
                    self._links.pop((rig, tid), None)
        return ended
