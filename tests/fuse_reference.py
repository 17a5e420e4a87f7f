"""The fusion step as it was before the row table: every live rig track predicted to the
step's instant and every room track's estimate computed and gated at each step, with no
restriction. Kept as the reference the restricted step (``stereod.fusion.fuser``) is checked
against (``tests/test_fusion_restrict.py``).

Tracks of several rigs as one set of room tracks with one id per object.

Each rig's latest message gives its live tracks (moved into the room frame at arrival). A
fusion step at a common UTC instant ``T`` predicts every rig track to ``T``, keeps the links
made before (a rig's track id stays with the room id it was first given), and associates the
rig tracks not linked yet to the room tracks, rig by rig: the squared Mahalanobis distance of
a rig track to a room track's estimate at ``T`` (the fusion of its linked members, else its own
prediction) is gated by a chi-square bound, a room track takes at most one track of each rig,
and one minimum-cost assignment (``tracking.assignment.min_cost_assignment``) decides. A
seen rig track left over opens a new room track. The linked members of a room track are then
fused in information form, ``P = (sum P_i^-1)^-1``, ``x = P sum P_i^-1 x_i``, position with
each member's covariance along its viewing ray (``frames.ray_cov``), scaled up by its strain
so far (``rows.strain_scale``: its squared Mahalanobis distance to the fused position, averaged
over a few frames; a lone member as published), velocity with the published one.

Why ids survive: a handover is a new rig track gated onto the room track another rig still
sees (or has seen for less than ``max_coast_s``); a rig that stops talking for ``rig_timeout_s``
(or whose sequence numbers start again: its daemon restarted, its track ids may repeat) loses
its links, and its tracks, when they come back, are associated like any new ones, so they join
the room tracks the other rigs kept alive instead of opening duplicates.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from stereod.bus.messages import ObjectsMessage
from stereod.fusion.frames import ACCEL_SIGMA_MPS2, UNKNOWN_VELOCITY_SIGMA_MPS, ray_cov
from stereod.fusion.params import FuseParams
from stereod.fusion.room import Room
from stereod.fusion.rows import strain_scale, strain_step
from stereod.fusion.wire import CONFIRMED, EXTRA, STATIONARY, TENTATIVE, RigWire, from_message
from stereod.tracking.assignment import min_cost_assignment
from stereod.tracking.types import TrackLifecycle


@dataclass(frozen=True)
class RigBatch:
    """All of one rig message's (not tentative) tracks in the room frame, as arrays: what the
    fusion works on, one numpy operation for every track at once (m, m/s, UTC ns)."""

    rig: str
    ids: list[int]
    stamps_ns: np.ndarray
    """(n,) each track's UTC stamp, ns."""
    position: np.ndarray
    """(n, 3) m."""
    position_cov: np.ndarray
    """(n, 3, 3) m^2."""
    ray_cov: np.ndarray
    """(n, 3, 3) the position's covariance along its viewing ray (``frames.ray_cov``), m^2."""
    velocity: np.ndarray
    """(n, 3) m/s."""
    velocity_cov: np.ndarray
    """(n, 3, 3) (m/s)^2."""
    seen: np.ndarray
    """(n,) measured in this pair (confirmed or stationary)."""
    stationary: np.ndarray
    """(n,) bool."""
    velocity_valid: np.ndarray
    """(n,) bool."""
    heading_valid: np.ndarray
    """(n,) bool."""
    extra: np.ndarray
    """(n, len(wire.EXTRA)) what the room's message repeats of a member (blobs and the like)."""
    keys: list[tuple[str, int]]
    """(rig, track id) of each row, as the fusion keys its links (made once per message)."""


def _rotated_diag(r: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
    """(n, 3, 3) ``R diag(s^2) R^T`` for (n, 3) sigmas: (R scaled by each row) @ R^T."""
    return (r[None, :, :] * np.square(sigmas)[:, None, :]) @ r.T


def batch_to_room(wire: RigWire, rotation: np.ndarray, translation: np.ndarray) -> RigBatch:
    """:func:`to_room` of every not tentative object of a message at once: p' = R p + t,
    v' = R v, P' = R P R^T (a missing or non-finite sigma as :func:`to_room` takes it)."""
    w = wire if not (wire.state == TENTATIVE).any() else wire.select(wire.state != TENTATIVE)
    psig = np.where(np.isfinite(w.position_sigma), w.position_sigma, 1.0)
    vsig = np.where(np.isfinite(w.velocity_sigma), w.velocity_sigma, UNKNOWN_VELOCITY_SIGMA_MPS)
    r = rotation
    ids = w.ids.tolist()
    return RigBatch(
        rig=w.rig,
        ids=ids,
        stamps_ns=w.stamps_ns,
        position=w.position @ r.T + translation,
        position_cov=_rotated_diag(r, psig),
        ray_cov=r @ ray_cov(w.position, psig) @ r.T,
        velocity=w.velocity @ r.T,
        velocity_cov=_rotated_diag(r, vsig),
        seen=(w.state == CONFIRMED) | (w.state == STATIONARY),
        stationary=w.state == STATIONARY,
        velocity_valid=w.velocity_valid,
        heading_valid=w.heading_valid,
        extra=w.extra,
        keys=[(w.rig, tid) for tid in ids],
    )


def predict_many(
    position: np.ndarray,
    position_cov: np.ndarray,
    velocity: np.ndarray,
    velocity_cov: np.ndarray,
    dt_s: np.ndarray,
    accel_sigma_mps2: float = ACCEL_SIGMA_MPS2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`predict` of n states at once, each by its own ``dt_s`` (n,) seconds."""
    dt = np.asarray(dt_s, dtype=np.float64)
    q = accel_sigma_mps2**2
    eye = np.eye(3)
    p = position + velocity * dt[:, None]
    p_cov = (
        position_cov
        + (dt * dt)[:, None, None] * velocity_cov
        + (q * dt**4 / 4.0)[:, None, None] * eye
    )
    v_cov = velocity_cov + (q * dt * dt)[:, None, None] * eye
    return p, p_cov, velocity.copy(), v_cov


_FORBIDDEN = 1e9


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
    extra: np.ndarray | None = None
    """What the member whose position weighed most at the last step passes on (its skew,
    blobs, disparity and size: the columns of ``wire.EXTRA``); None before any member."""
    velocity_valid: bool = False
    heading_valid: bool = False
    strain: dict[tuple[str, int], float] = field(default_factory=dict)
    """(rig, track id) -> that member's strain (none while the track has one member)."""


@dataclass(frozen=True)
class FusedFrame:
    """One fusion step's result: the room tracks at ``t_ns`` and the ids that ended."""

    t_ns: int
    tracks: list[RoomTrack]
    ended: list[int]
    shared: dict[int, list[tuple[str, int, np.ndarray, np.ndarray]]] = field(default_factory=dict)
    """For each room id fused at this step that more than one rig sees: each rig's name and
    its track's own stamp (UTC ns, as corrected), position (m) and position covariance (m^2)
    there, in the room frame, not predicted (what clock offsets are estimated from: capture
    stamps only)."""


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


def _group_fusion(
    group: np.ndarray, k: int, info: np.ndarray, info_mean: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Information-form fusion of rows into ``k`` groups at once: rows with ``group[i] = g``
    (-1: none) of information matrices ``info`` (n, 3, 3) and ``info_mean`` (n, 3) (``I x``).
    Returns each group's row count (k,), mean (k, 3) and covariance (k, 3, 3), zero where
    the group has no row."""
    ok = group >= 0
    total = np.zeros((k, 3, 3))
    total_mean = np.zeros((k, 3))
    np.add.at(total, group[ok], info[ok])
    np.add.at(total_mean, group[ok], info_mean[ok])
    count = np.bincount(group[ok], minlength=k)
    cov = np.zeros((k, 3, 3))
    mean = np.zeros((k, 3))
    has = count > 0
    if has.any():
        c = np.linalg.inv(total[has])
        cov[has] = 0.5 * (c + np.transpose(c, (0, 2, 1)))
        mean[has] = np.einsum("kij,kj->ki", c, total_mean[has])
    return count, mean, cov


def _snapshot(t: RoomTrack) -> RoomTrack:
    """A shallow copy of ``t`` with its own members (its arrays are replaced at each step,
    never written into, so they are shared)."""
    return RoomTrack(
        t.room_id, t.stamp_utc_ns, t.first_ns, t.last_seen_ns, t.position, t.position_cov,
        t.velocity, t.velocity_cov, t.state, dict(t.members), t.extra, t.velocity_valid,
        t.heading_valid,
    )  # fmt: skip


class _Rows:
    """Every live rig track predicted to one instant, stacked (the step's working set)."""

    def __init__(self, batches: list[RigBatch], t_ns: int) -> None:
        self.batches = batches
        self.t_ns = t_ns
        self.keys: list[tuple[str, int]] = []
        self.span: dict[str, range] = {}
        """Each rig's rows (a batch's rows are consecutive)."""
        for batch in batches:
            self.span[batch.rig] = range(len(self.keys), len(self.keys) + len(batch.ids))
            self.keys += batch.keys
        self.index = {k: i for i, k in enumerate(self.keys)}
        n = len(self.keys)
        if n:
            self.stamps = np.concatenate([b.stamps_ns for b in batches])
            self.raw_position = np.concatenate([b.position for b in batches])
            self.raw_cov = np.concatenate([b.position_cov for b in batches])
            self.ray_cov = np.concatenate([b.ray_cov for b in batches])
            p, pc, v, vc = predict_many(
                self.raw_position,
                self.raw_cov,
                np.concatenate([b.velocity for b in batches]),
                np.concatenate([b.velocity_cov for b in batches]),
                (t_ns - self.stamps) * 1e-9,
            )
        else:
            p, v = np.zeros((0, 3)), np.zeros((0, 3))
            pc, vc = np.zeros((0, 3, 3)), np.zeros((0, 3, 3))
            self.stamps, self.raw_position, self.raw_cov = np.zeros(0, dtype=np.int64), p, pc
            self.ray_cov = pc
        self.position, self.position_cov, self.velocity, self.velocity_cov = p, pc, v, vc

        def stack(name: str, empty: np.ndarray) -> np.ndarray:
            return np.concatenate([getattr(b, name) for b in batches]) if n else empty

        none = np.zeros(0, dtype=bool)
        self.seen = stack("seen", none)
        self.stationary = stack("stationary", none)
        self.velocity_valid = stack("velocity_valid", none)
        self.heading_valid = stack("heading_valid", none)
        self.extra = stack("extra", np.zeros((0, len(EXTRA))))


class Fuser:
    """The fusion of one room's rigs; feed it each rig's objects messages with :meth:`ingest`
    and ask for the room at an instant with :meth:`fuse`. Every track of every rig is handled
    in stacked numpy arrays, so a step costs a few array operations, not a Python loop of
    matrix operations per track. Not thread-safe: one caller."""

    def __init__(self, room: Room, params: FuseParams | None = None) -> None:
        self.room = room
        self.params = params or FuseParams()
        self._poses = {r.name: (r.rotation(), r.translation()) for r in room.rigs}
        self._order = [r.name for r in room.rigs]
        self._batches: dict[str, RigBatch] = {}
        self._rig_last_ns: dict[str, int] = {}
        self._rig_seq: dict[str, int] = {}
        self._links: dict[tuple[str, int], int] = {}
        self._since: dict[tuple[str, int], int] = {}
        """Rig tracks waiting to open a room track (``birth_s``): when first seen waiting, ns."""
        self._tracks: dict[int, RoomTrack] = {}
        self._next_id = 1
        self.restarts: dict[str, int] = {}
        """Times each rig's sequence numbers started again (its daemon restarted)."""
        self.clock_corrections_ns: dict[str, int] = {}
        """Per rig, its clock's offset from the reference rig's, subtracted from its stamps
        at :meth:`ingest` (``clock.ClockWatch.corrections_ns``), ns."""

    def set_room(self, room: Room) -> list[str]:
        """Take a room file read again (the same room, its rigs' poses changed, rigs added or
        gone). A rig whose pose changed or that left loses its tracks and links: at its next
        message its tracks are associated like new ones (gated onto the room tracks the other
        rigs kept, as after a restart), now in the new pose. Returns the rigs that changed."""
        poses = {r.name: (r.rotation(), r.translation()) for r in room.rigs}
        changed = [
            name
            for name, (rot, t) in self._poses.items()
            if name not in poses
            or not (np.array_equal(rot, poses[name][0]) and np.array_equal(t, poses[name][1]))
        ]
        for name in changed:
            self._forget_rig(name)
            if name not in poses:
                self._rig_last_ns.pop(name, None)
                self._rig_seq.pop(name, None)
        self.room = room
        self._poses = poses
        self._order = [r.name for r in room.rigs]
        return changed

    def knows(self, rig: str) -> bool:
        """Whether ``rig`` is one of the room's rigs."""
        return rig in self._poses

    def ingest(self, msg: ObjectsMessage) -> bool:
        """Take a rig's objects message (a rig not in the room is ignored: False). Its tracks
        replace that rig's previous ones; a sequence number lower than the last one means the
        daemon restarted, and its old links are forgotten."""
        return self.ingest_wire(from_message(msg))

    def ingest_wire(self, msg: RigWire) -> bool:
        """:meth:`ingest` of a message read as arrays (``wire.decode``)."""
        pose = self._poses.get(msg.rig)
        if pose is None:
            return False
        last = self._rig_seq.get(msg.rig)
        if last is not None and msg.seq < last:
            self._forget_rig(msg.rig)
            self.restarts[msg.rig] = self.restarts.get(msg.rig, 0) + 1
        self._rig_seq[msg.rig] = msg.seq
        shift = self.clock_corrections_ns.get(msg.rig, 0)
        if shift:
            msg = dataclasses.replace(
                msg, stamp_utc_ns=msg.stamp_utc_ns - shift, stamps_ns=msg.stamps_ns - shift
            )
        self._rig_last_ns[msg.rig] = msg.stamp_utc_ns
        self._batches[msg.rig] = batch_to_room(msg, pose[0], pose[1])
        return True

    def _forget_rig(self, rig: str) -> set[int]:
        """Drop ``rig``'s tracks and links; returns the room tracks that lost a member."""
        self._batches.pop(rig, None)
        lost = set()
        for key in [k for k in self._links if k[0] == rig]:
            room_id = self._links.pop(key)
            track = self._tracks.get(room_id)
            if track is not None:
                track.members.pop(rig, None)
                track.strain.pop(key, None)
                lost.add(room_id)
        return lost

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
        batch = self._batches.get(rig)
        return 0 if batch is None else len(batch.ids)

    def rig_stamp(self, rig: str) -> int | None:
        """The UTC stamp of ``rig``'s latest message, ns (None before its first)."""
        return self._rig_last_ns.get(rig)

    def latest_ns(self) -> int | None:
        """The newest stamp of any rig's message (UTC ns), or None before the first."""
        return max(self._rig_last_ns.values(), default=None)

    def fuse(self, t_ns: int, rigs: list[str] | None = None) -> FusedFrame:
        """The room at the UTC instant ``t_ns`` (ns): every rig track predicted there,
        associated, fused; room tracks no rig has seen for ``max_coast_s`` end.

        With ``rigs`` (event-driven: the rigs whose messages just came in, ``t_ns`` their
        stamp), only those rigs' tracks are associated, and only the room tracks they have a
        member in (or that just lost one, or have none: coasting) are fused at ``t_ns`` and
        returned: the others keep their last state and stamp. A step then costs one message's
        tracks, not the room's."""
        live = self.live_rigs(t_ns)
        lost: set[int] = set()
        for rig in [r for r in self._batches if r not in live]:
            lost |= self._forget_rig(rig)
        rows = _Rows([self._batches[r] for r in live if r in self._batches], t_ns)
        for key in [k for k in self._since if k not in rows.index or k in self._links]:
            del self._since[key]
        for key in [k for k in self._links if k not in rows.index]:
            rid = self._links.pop(key)
            track = self._tracks.get(rid)
            if track is not None and track.members.get(key[0]) == key[1]:
                del track.members[key[0]]
                track.strain.pop(key, None)
                lost.add(rid)
        members: dict[int, list[int]] = {rid: [] for rid in self._tracks}
        for key, rid in self._links.items():
            members[rid].append(rows.index[key])
        assoc = live if rigs is None else [r for r in live if r in rigs]
        if any(rows.keys[i] not in self._links for r in assoc for i in rows.span.get(r, ())):
            estimate = self._estimates(rows, members, t_ns)
            for rig in assoc:
                self._associate(rig, rows, members, estimate, t_ns)
        if rigs is None:
            touched = set(self._tracks)
        else:
            # Those tracks, those that just lost a member, and those with none (coasting: a
            # step predicts them on, as a full step does, so that they gate as they would).
            touched = {rid for rid in lost if rid in self._tracks}
            touched.update(rid for rid, tr in self._tracks.items() if not tr.members)
            for rig in assoc:
                for i in rows.span.get(rig, ()):
                    linked = self._links.get(rows.keys[i])
                    if linked is not None:
                        touched.add(linked)
        ended = self._update(rows, members, t_ns, touched)
        raw = (rows.stamps.tolist(), rows.raw_position, rows.raw_cov)
        shared = {
            rid: [(rows.keys[i][0], raw[0][i], raw[1][i], raw[2][i]) for i in ms]
            for rid in sorted(touched)
            if len(ms := members.get(rid, ())) >= 2 and rid in self._tracks
        }
        # Copies: the caller may keep a frame while the next steps change the tracks (whose
        # arrays are replaced, never written into).
        tracks = [_snapshot(self._tracks[rid]) for rid in sorted(touched) if rid in self._tracks]
        return FusedFrame(t_ns=t_ns, tracks=tracks, ended=ended, shared=shared)

    def tracks(self) -> list[RoomTrack]:
        """Every room track now, each at its own last stamp (copies), by id."""
        return [_snapshot(tr) for _, tr in sorted(self._tracks.items())]

    def _estimates(
        self, rows: _Rows, members: dict[int, list[int]], t_ns: int
    ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Each room track's position and covariance at ``t_ns``: its linked members'
        fusion, or its last fused state predicted."""
        rids = sorted(self._tracks)
        if not rids:
            return {}
        slot = {rid: k for k, rid in enumerate(rids)}
        group = np.full(len(rows.keys), -1, dtype=np.int64)
        for rid, ms in members.items():
            group[ms] = slot[rid]
        info = np.linalg.inv(rows.position_cov) if len(rows.keys) else rows.position_cov
        info_mean = np.einsum("nij,nj->ni", info, rows.position)
        count, mean, cov = _group_fusion(group, len(rids), info, info_mean)
        alone = [rid for rid in rids if count[slot[rid]] == 0]
        if alone:
            trs = [self._tracks[rid] for rid in alone]
            p, pc, _, _ = predict_many(
                np.array([t.position for t in trs]),
                np.array([t.position_cov for t in trs]),
                np.array([t.velocity for t in trs]),
                np.array([t.velocity_cov for t in trs]),
                np.array([(t_ns - t.stamp_utc_ns) * 1e-9 for t in trs]),
            )
            for j, rid in enumerate(alone):
                mean[slot[rid]], cov[slot[rid]] = p[j], pc[j]
        return {rid: (mean[slot[rid]], cov[slot[rid]]) for rid in rids}

    def _associate(
        self,
        rig: str,
        rows: _Rows,
        members: dict[int, list[int]],
        estimate: dict[int, tuple[np.ndarray, np.ndarray]],
        t_ns: int,
    ) -> None:
        """Link ``rig``'s unlinked tracks to room tracks that have no track of ``rig`` yet, or
        only one it no longer sees (coasting: a seen track of that rig there replaces it, so
        that a rig's new track of an object joins its room track instead of opening a second
        id beside it), in one gated assignment; a seen track left over opens a room track."""
        free = [i for i in rows.span.get(rig, ()) if rows.keys[i] not in self._links]
        if not free:
            return
        candidates: list[int] = []
        stale: dict[int, int] = {}
        """Room track -> its member row of ``rig`` that ``rig`` does not see now."""
        for rid in sorted(members):
            mine = [i for i in members[rid] if rows.keys[i][0] == rig]
            if not mine:
                candidates.append(rid)
            elif not rows.seen[mine[0]]:
                candidates.append(rid)
                stale[rid] = mine[0]
        matched: set[int] = set()
        if candidates:
            means, covs = [], []
            for r in candidates:
                others = [i for i in members[r] if i != stale.get(r)]
                if r in stale and others:
                    m, c = fuse_gaussians(
                        [rows.position[i] for i in others], [rows.position_cov[i] for i in others]
                    )
                else:
                    m, c = estimate[r]
                means.append(m)
                covs.append(c)
            d = rows.position[free][:, None, :] - np.array(means)
            s = rows.position_cov[free][:, None] + np.array(covs)
            d2 = np.einsum("nmi,nmi->nm", d, np.linalg.solve(s, d[..., None])[..., 0])
            cost = np.where(d2 <= self.params.gate_chi2, d2, _FORBIDDEN)
            # Only a seen track replaces a coasting one.
            replaceable = np.array([r in stale for r in candidates])
            cost[np.ix_(~rows.seen[free], replaceable)] = _FORBIDDEN
            for i, j in zip(*min_cost_assignment(cost), strict=True):
                if cost[i, j] < _FORBIDDEN:
                    rid = candidates[j]
                    if rid in stale:
                        self._unlink(rows, stale[rid], rid, members)
                    self._link(rows, free[i], rid, members, estimate)
                    matched.add(int(i))
        left = [row for i, row in enumerate(free) if i not in matched and rows.seen[row]]
        for row in self._born(rows, left, estimate, t_ns):
            rid = self._open(rows, row, t_ns)
            members[rid] = []
            self._link(rows, row, rid, members, estimate)

    def _born(
        self,
        rows: _Rows,
        left: list[int],
        estimate: dict[int, tuple[np.ndarray, np.ndarray]],
        t_ns: int,
    ) -> list[int]:
        """Of the seen rig tracks no room track took, those that open one now: any not within
        the gate of a room track, and one within it (it contradicts a room track that has its
        rig's track already: a split blob, a stray) once it has been seen for ``birth_s``, so
        that a short-lived stray opens no second id beside the object's."""
        if not left or not estimate:
            return left
        rids = list(estimate)
        d = rows.position[left][:, None, :] - np.array([estimate[r][0] for r in rids])
        s = rows.position_cov[left][:, None] + np.array([estimate[r][1] for r in rids])
        d2 = np.einsum("nmi,nmi->nm", d, np.linalg.solve(s, d[..., None])[..., 0])
        near = (d2 <= self.params.gate_chi2).any(axis=1)
        born = []
        for row, contradicts in zip(left, near.tolist(), strict=True):
            if not contradicts:
                born.append(row)
                continue
            since = self._since.setdefault(rows.keys[row], t_ns)
            if t_ns - since >= self.params.birth_s * 1e9:
                born.append(row)
        return born

    def _unlink(self, rows: _Rows, row: int, room_id: int, members: dict[int, list[int]]) -> None:
        """Take rig track ``row`` out of room track ``room_id`` (another of its rig replaces
        it); it stays free, and opens nothing while its rig does not see it."""
        rig, _ = key = rows.keys[row]
        self._links.pop(key, None)
        self._tracks[room_id].members.pop(rig, None)
        self._tracks[room_id].strain.pop(key, None)
        members[room_id].remove(row)

    def _link(
        self,
        rows: _Rows,
        row: int,
        room_id: int,
        members: dict[int, list[int]],
        estimate: dict[int, tuple[np.ndarray, np.ndarray]],
    ) -> None:
        rig, tid = rows.keys[row]
        self._links[(rig, tid)] = room_id
        self._tracks[room_id].members[rig] = tid
        members[room_id].append(row)
        ms = members[room_id]
        estimate[room_id] = fuse_gaussians(
            [rows.position[i] for i in ms], [rows.position_cov[i] for i in ms]
        )

    def _open(self, rows: _Rows, row: int, t_ns: int) -> int:
        rid = self._next_id
        self._next_id += 1
        self._tracks[rid] = RoomTrack(
            room_id=rid,
            stamp_utc_ns=t_ns,
            first_ns=t_ns,
            last_seen_ns=t_ns,
            position=rows.position[row].copy(),
            position_cov=rows.position_cov[row].copy(),
            velocity=rows.velocity[row].copy(),
            velocity_cov=rows.velocity_cov[row].copy(),
        )
        return rid

    def _update(
        self, rows: _Rows, members: dict[int, list[int]], t_ns: int, touched: set[int]
    ) -> list[int]:
        """Fuse each ``touched`` room track's members at ``t_ns`` (every track in one array
        operation); coast those with none; end any unseen for ``max_coast_s``. Returns the
        ended ids."""
        rids = sorted(touched)
        slot = {rid: k for k, rid in enumerate(rids)}
        # The member rows of the touched tracks only (a rig's message touches a few).
        idx = np.array([i for rid in rids for i in members[rid]], dtype=np.int64)
        g = np.array([slot[rid] for rid in rids for _ in members[rid]], dtype=np.int64)
        k = len(rids)
        # Position and velocity in one fusion: groups 0..k-1 positions, k..2k-1 velocities.
        covs = np.concatenate([rows.position_cov[idx], rows.velocity_cov[idx]])
        info = np.linalg.inv(covs) if idx.size else np.zeros((0, 3, 3))
        means = np.concatenate([rows.position[idx], rows.velocity[idx]])
        info_mean = np.einsum("nij,nj->ni", info, means)
        count2, both, both_cov = _group_fusion(np.concatenate([g, g + k]), 2 * k, info, info_mean)
        count, pos, pcov, vel, vcov = count2[:k], both[:k], both_cov[:k], both[k:], both_cov[k:]
        # Positions weighed by their covariances along their viewing rays (grown by the
        # prediction as the published ones are), each scaled by its member's strain so far;
        # each member's distance to the fused position then moves its strain on.
        ray = rows.ray_cov[idx] + (rows.position_cov[idx] - rows.raw_cov[idx])
        rinfo = np.linalg.inv(ray) if idx.size else np.zeros((0, 3, 3))
        keys = [rows.keys[i] for i in idx.tolist()]
        before = np.array(
            [self._tracks[rids[j]].strain.get(key, 0.0) for j, key in zip(g.tolist(), keys)]
        )
        winfo = rinfo / strain_scale(before)[:, None, None]
        x = rows.position[idx]
        _, rpos, rpcov = _group_fusion(g, k, winfo, np.einsum("nij,nj->ni", winfo, x))
        d = x - rpos[g]
        nis = np.einsum("ni,nij,nj->n", d, rinfo, d)
        many = count > 1
        pos[many], pcov[many] = rpos[many], rpcov[many]
        alone = count[g] == 1  # a lone member is its own fusion: as published
        pos[g[alone]], pcov[g[alone]] = x[alone], rows.position_cov[idx][alone]
        coasting = [rid for rid in rids if count[slot[rid]] == 0]
        if coasting:
            trs = [self._tracks[rid] for rid in coasting]
            p, pc, v, vc = predict_many(
                np.array([t.position for t in trs]),
                np.array([t.position_cov for t in trs]),
                np.array([t.velocity for t in trs]),
                np.array([t.velocity_cov for t in trs]),
                np.array([(t_ns - t.stamp_utc_ns) * 1e-9 for t in trs]),
            )
            for j, rid in enumerate(coasting):
                s = slot[rid]
                pos[s], pcov[s], vel[s], vcov[s] = p[j], pc[j], v[j], vc[j]

        # Per room track, from its members' rows at once: any seen, all seen ones stationary,
        # any velocity (heading) valid, and the member with the smallest position variance.
        flags = np.stack(
            [rows.seen, rows.seen & ~rows.stationary, rows.velocity_valid, rows.heading_valid],
            axis=1,
        )[idx]
        counts = np.zeros((k, 4), dtype=np.int64)
        np.add.at(counts, g, flags)
        seen, moving, vvalid, hvalid = (counts > 0).T
        best = np.full(k, -1, dtype=np.int64)
        if g.size:
            trace = np.trace(rows.position_cov[idx], axis1=1, axis2=2)
            order = np.lexsort((trace, g))
            first = np.ones(order.size, dtype=bool)
            first[1:] = g[order][1:] != g[order][:-1]
            best[g[order][first]] = idx[order][first]
        ended: list[int] = []
        coast_ns = int(self.params.max_coast_s * 1e9)
        for rid, tr in list(self._tracks.items()):
            if rid not in touched and t_ns - tr.last_seen_ns > coast_ns:
                ended.append(self._end(rid))
        for rid in rids:
            tr, s = self._tracks[rid], slot[rid]
            tr.position, tr.position_cov, tr.velocity, tr.velocity_cov = (
                pos[s], pcov[s], vel[s], vcov[s]
            )  # fmt: skip
            if count[s]:
                tr.strain = {}
                if count[s] > 1:
                    js = np.flatnonzero(g == s).tolist()
                    after = strain_step(
                        before[js].tolist(), nis[js].tolist(), (t_ns - tr.stamp_utc_ns) * 1e-9
                    )
                    tr.strain = dict(zip([keys[j] for j in js], after, strict=True))
                tr.extra = rows.extra[best[s]]
                tr.velocity_valid, tr.heading_valid = bool(vvalid[s]), bool(hvalid[s])
                if seen[s]:
                    tr.last_seen_ns = t_ns
                    tr.state = TrackLifecycle.CONFIRMED if moving[s] else TrackLifecycle.STATIONARY
                else:
                    tr.state = TrackLifecycle.COASTING
            else:
                tr.state = TrackLifecycle.COASTING
            tr.stamp_utc_ns = t_ns
            if t_ns - tr.last_seen_ns > coast_ns:
                ended.append(self._end(rid))
        return ended

    def _end(self, rid: int) -> int:
        """End room track ``rid`` and drop its links; returns ``rid``."""
        tr = self._tracks.pop(rid)
        for rig, tid in tr.members.items():
            self._links.pop((rig, tid), None)
        return rid
