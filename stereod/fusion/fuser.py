"""Tracks of several rigs as one set of room tracks with one id per object.

Each rig's latest message gives its live tracks (moved into the room frame at arrival). A
fusion step at a common UTC instant ``T`` predicts every rig track to ``T``, keeps the links
made before (a rig's track id stays with the room id it was first given), and associates the
rig tracks not linked yet to the room tracks, rig by rig: the squared Mahalanobis distance of
a rig track to a room track's estimate at ``T`` (the fusion of its linked members, else its own
prediction) is gated by a chi-square bound, a room track takes at most one track of each rig,
and one minimum-cost assignment (``tracking.assignment.min_cost_assignment``) decides. A
seen rig track left over opens a new room track. The linked members of a room track are then
fused in information form, ``P = (sum P_i^-1)^-1``, ``x = P sum P_i^-1 x_i``, position with
each member's covariance along its viewing ray (``rows.fuse_ray``), scaled up while that
member's strain runs high (``rows.strain_scale``: its squared Mahalanobis distance to the
fused position, averaged over a few frames; a rig off along its ray, or a merged blob, fades
out of the room track without leaving it), velocity with the published one.

Why ids survive: a handover is a new rig track gated onto the room track another rig still
sees (or has seen for less than ``max_coast_s``); a rig that stops talking for ``rig_timeout_s``
(or whose sequence numbers start again: its daemon restarted, its track ids may repeat) loses
its links, and its tracks, when they come back, are associated like any new ones, so they join
the room tracks the other rigs kept alive instead of opening duplicates.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from stereod.bus.messages import ObjectsMessage
from stereod.fusion import rows as tab
from stereod.fusion.params import CHI2_3DOF_999 as CHI2_3DOF_999
from stereod.fusion.params import FuseParams as FuseParams
from stereod.fusion.room import Room
from stereod.fusion.rows import (
    DIAG,
    DIAG_P,
    HVALID,
    MOVING,
    PCOV,
    POS,
    SEEN,
    VVALID,
    Estimates,
    Table,
)
from stereod.fusion.rows import fuse_gaussians as fuse_gaussians
from stereod.fusion.rows import mahalanobis2 as mahalanobis2
from stereod.fusion.stacked import Columns, FusedFrame, Links, RoomState
from stereod.fusion.stacked import RoomTrack as RoomTrack
from stereod.fusion.wire import COASTING, CONFIRMED, STATIONARY, RigWire, from_message
from stereod.tracking.assignment import min_cost_assignment

_FORBIDDEN = 1e9


_Shared = dict[int, list[tuple[str, int, list[float]]]]
_MEASURED = np.r_[POS, PCOV]
"""A table row's position and position covariance columns: what ``FusedFrame.shared``
holds of each member (twelve floats)."""


def _less(members: dict[str, int], rig: str) -> dict[str, int]:
    """``members`` less ``rig``'s (a new dict: a room track's members are replaced, never
    written into, so that a frame keeps them as they were at its step)."""
    return {r: t for r, t in members.items() if r != rig}


class Fuser:
    """The fusion of one room's rigs; feed it each rig's objects messages with :meth:`ingest`
    and ask for the room at an instant with :meth:`fuse`.

    A message's tracks are moved into the room frame once, into a :class:`rows.Table` that
    holds every rig's latest rows; a step gathers the rows it needs from it. With ``rigs``
    (event-driven) a step predicts and fuses only the room tracks those rigs touch, from their
    members' rows: no pass over the room's other tracks but the coast check. Association, when
    those rigs have a track not linked yet, gates it against every room track's estimate, the
    pairs first bounded by distance (``rows.reach``) so that only those within reach are
    solved: it gives what gating against all of them would. Not thread-safe: one caller."""

    def __init__(self, room: Room, params: FuseParams | None = None) -> None:
        self.room = room
        self.params = params or FuseParams()
        self._poses = {r.name: (r.rotation(), r.translation()) for r in room.rigs}
        self._order = [r.name for r in room.rigs]
        self._table = Table()
        self._dirty: set[str] = set()
        """Rigs whose rows changed since the last step (their links are checked there)."""
        self._rig_last_ns: dict[str, int] = {}
        self._rig_seq: dict[str, int] = {}
        self._links: dict[str, dict[int, int]] = {}
        """Rig name -> its track id -> the room track it is linked to."""
        self._since: dict[tuple[str, int], int] = {}
        """Rig tracks waiting to open a room track (``birth_s``): when first seen waiting, ns."""
        self._tracks: dict[int, Links] = {}
        """Room id -> its members and their strains (its state is in :attr:`_state`)."""
        self._state = RoomState()
        self._next_id = 1
        self._bare: set[int] = set()
        """Room tracks with no member (coasting on their own state)."""
        self._kept_slots: np.ndarray | None = None
        """The slots of the tracks :meth:`_update` returned, when it had them."""
        self._seen_floor = 0
        """No room track was last seen before this (UTC ns): a lower bound, raised when the
        tracks are looked over for their coast."""
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
        self._table.put(msg, pose[0], pose[1])
        self._dirty.add(msg.rig)
        return True

    def _forget_rig(self, rig: str) -> set[int]:
        """Drop ``rig``'s tracks and links; returns the room tracks that lost a member."""
        self._table.drop(rig)
        lost = set()
        for room_id in self._links.pop(rig, {}).values():
            track = self._tracks.get(room_id)
            if track is not None:
                track.members = _less(track.members, rig)
                track.strain = tab.without_rig(track.strain, rig)
                lost.add(room_id)
                if not track.members:
                    self._bare.add(room_id)
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
        return self._table.count.get(rig, 0)

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
        live_set = set(live)
        for rig in [r for r in self._table.count if r not in live_set]:
            lost |= self._forget_rig(rig)
        index = self._table.index
        for key in [
            k
            for k in self._since
            if k[1] not in index.get(k[0], ()) or k[1] in self._links.get(k[0], ())
        ]:
            del self._since[key]
        # Links to tracks gone from their rig's newest message (only a rig whose rows changed
        # can have any).
        for rig in self._dirty:
            links = self._links.get(rig)
            ids = index.get(rig, {})
            for tid in [k for k in links or () if k not in ids]:
                rid = links.pop(tid)  # type: ignore[union-attr]
                track = self._tracks.get(rid)
                if track is not None and track.members.get(rig) == tid:
                    track.members = _less(track.members, rig)
                    track.strain = tab.without_rig(track.strain, rig)
                    lost.add(rid)
                    if not track.members:
                        self._bare.add(rid)
        self._dirty.clear()
        assoc = live if rigs is None else [r for r in live if r in rigs]
        # Every link of a rig is to a track in its message now, so it has a track not linked
        # yet exactly when it has more tracks than links.
        if any(len(index.get(r, ())) > len(self._links.get(r, ())) for r in assoc):
            estimate = self._estimates(t_ns)
            for rig in assoc:
                self._associate(rig, estimate, t_ns)
        if rigs is None:
            touched = set(self._tracks)
        else:
            # Those tracks, those that just lost a member, and those with none (coasting: a
            # step predicts them on, as a full step does, so that they gate as they would).
            touched = {rid for rid in lost if rid in self._tracks}
            touched.update(self._bare)
            for rig in assoc:
                touched.update(self._links.get(rig, {}).values())
        self._kept_slots = None
        ended, shared, kept = self._update(t_ns, touched)
        if kept is None:
            return FusedFrame(t_ns, ended, shared)
        return self._frame(t_ns, ended, shared, kept, self._kept_slots)

    def _frame(
        self,
        t_ns: int,
        ended: list[int],
        shared: _Shared,
        rids: list[int],
        slots: np.ndarray | None = None,
    ) -> FusedFrame:
        """A frame of room tracks ``rids`` (``slots``: theirs, when the step has them) as they
        are now: their columns gathered (copies: the caller may keep a frame while the next
        steps change the tracks)."""
        st = self._state
        k = st.slots(rids) if slots is None else slots
        links = [self._tracks[rid] for rid in rids]
        return FusedFrame(t_ns, ended, shared, st.f[k], Columns(st, k, rids), links)

    def tracks(self) -> list[RoomTrack]:
        """Every room track now, each at its own last stamp (copies), by id."""
        return self._frame(0, [], {}, sorted(self._tracks)).tracks

    def _member_rows(self, rids: list[int]) -> tuple[list[int], list[int], list[int]]:
        """The table rows of the members of room tracks ``rids`` (in that order, each track's
        in its members' order), the start of each track's run, and which of ``rids`` have
        members (a run each)."""
        index = self._table.index
        idx: list[int] = []
        starts: list[int] = []
        with_members: list[int] = []
        for rid in rids:
            members = self._tracks[rid].members
            if members:
                starts.append(len(idx))
                with_members.append(rid)
                idx += [index[rig][tid] for rig, tid in members.items()]
        return idx, starts, with_members

    def _predicted(self, idx: list[int], t_ns: int) -> np.ndarray:
        """Table rows ``idx`` predicted to ``t_ns``, (n, WIDTH)."""
        table = self._table
        return tab.predict_rows(table.f[idx], (t_ns - table.stamps[idx]) * 1e-9)

    def _estimates(self, t_ns: int) -> Estimates:
        """Each room track's position and covariance at ``t_ns``: its linked members'
        fusion, or its last fused state predicted."""
        rids = sorted(self._tracks)
        mean, cov = np.zeros((len(rids), 3)), np.zeros((len(rids), 9))
        est = Estimates(rids, mean, cov)
        idx, starts, with_members = self._member_rows(rids)
        if with_members:
            f = self._predicted(idx, t_ns)
            m, c = tab.fuse_groups(f[:, POS], f[:, PCOV], np.array(starts))
            k = [est.slot[rid] for rid in with_members]
            mean[k], cov[k] = m, c
        alone = [rid for rid in rids if not self._tracks[rid].members]
        if alone:
            f = self._state.coast(alone, t_ns)
            k = [est.slot[rid] for rid in alone]
            mean[k], cov[k] = f[:, POS], f[:, PCOV]
        return est

    def _fuse_members(self, rows: list[int], t_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The fusion of table rows ``rows`` predicted to ``t_ns``: position (3,) and its
        covariance (9,) (one row: that row's)."""
        f = self._predicted(rows, t_ns)
        if len(rows) == 1:
            return f[0, POS], f[0, PCOV]
        m, c = tab.fuse_groups(f[:, POS], f[:, PCOV], np.zeros(1, dtype=np.int64))
        return m[0], c[0]

    def _associate(self, rig: str, est: Estimates, t_ns: int) -> None:
        """Link ``rig``'s unlinked tracks to room tracks that have no track of ``rig`` yet, or
        only one it no longer sees (coasting: a seen track of that rig there replaces it, so
        that a rig's new track of an object joins its room track instead of opening a second
        id beside it), in one gated assignment; a seen track left over opens a room track.
        Only the room tracks within reach of one of the tracks (``rows.reach``) enter the
        assignment: the others' columns would all be out of the gate."""
        links = self._links.setdefault(rig, {})
        index = self._table.index.get(rig, {})
        free = [row for tid, row in index.items() if tid not in links]
        if not free:
            return
        flags = self._table.flags
        seen_free = flags[free, SEEN]
        stale: dict[int, int] = {}
        """Room track -> its member row of ``rig`` that ``rig`` does not see now."""
        mine = np.ones(len(est.rids), dtype=bool)
        for tid, rid in links.items():
            row = index[tid]
            if flags[row, SEEN]:
                mine[est.slot[rid]] = False
            else:
                stale[rid] = row
        cols = np.flatnonzero(mine)
        means, covs = est.mean[cols], est.cov[cols]
        for rid in stale:
            others = [
                self._table.index[r][tid]
                for r, tid in self._tracks[rid].members.items()
                if r != rig
            ]
            if others:
                j = int(np.searchsorted(cols, est.slot[rid]))
                means[j], covs[j] = self._fuse_members(others, t_ns)
        x = self._predicted(free, t_ns)
        gate = self.params.gate_chi2
        near = tab.reach(
            x[:, POS], x[:, DIAG_P].sum(axis=1), means, covs[:, DIAG].sum(axis=1), gate
        )
        keep = np.flatnonzero(near.any(axis=0))
        matched: set[int] = set()
        if keep.size:
            n, m = len(free), keep.size
            ii, jj = np.repeat(np.arange(n), m), np.tile(keep, n)
            d2 = tab.gate_d2(x[ii, POS], x[ii, PCOV], means[jj], covs[jj]).reshape(n, m)
            cost = np.where(d2 <= gate, d2, _FORBIDDEN)
            candidates = [est.rids[k] for k in cols[keep].tolist()]
            # Only a seen track replaces a coasting one.
            replaceable = np.array([r in stale for r in candidates])
            cost[np.ix_(~seen_free, replaceable)] = _FORBIDDEN
            for i, j in zip(*min_cost_assignment(cost), strict=True):
                if cost[i, j] < _FORBIDDEN:
                    rid = candidates[j]
                    if rid in stale:
                        self._unlink(rig, rid)
                    self._link(rig, free[i], rid, est, t_ns)
                    matched.add(int(i))
        left = [row for i, row in enumerate(free) if i not in matched and seen_free[i]]
        for row in self._born(rig, left, est, t_ns):
            rid = self._open(self._predicted([row], t_ns)[0], t_ns)
            self._link(rig, row, rid, est, t_ns)

    def _born(self, rig: str, left: list[int], est: Estimates, t_ns: int) -> list[int]:
        """Of the seen rig tracks no room track took, those that open one now: any not within
        the gate of a room track, and one within it (it contradicts a room track that has its
        rig's track already: a split blob, a stray) once it has been seen for ``birth_s``, so
        that a short-lived stray opens no second id beside the object's."""
        if not left or not est.rids:
            return left
        gate = self.params.gate_chi2
        x = self._predicted(left, t_ns)
        near = tab.reach(
            x[:, POS], x[:, DIAG_P].sum(axis=1), est.mean, est.cov[:, DIAG].sum(axis=1), gate
        )
        ii, jj = np.nonzero(near)
        inside = np.zeros(len(left), dtype=bool)
        if ii.size:
            d2 = tab.gate_d2(x[ii, POS], x[ii, PCOV], est.mean[jj], est.cov[jj])
            inside[ii[d2 <= gate]] = True
        ids = self._table.ids[rig]
        base = self._table.rows(rig).start
        born = []
        for row, contradicts in zip(left, inside.tolist(), strict=True):
            if not contradicts:
                born.append(row)
                continue
            since = self._since.setdefault((rig, ids[row - base]), t_ns)
            if t_ns - since >= self.params.birth_s * 1e9:
                born.append(row)
        return born

    def _unlink(self, rig: str, room_id: int) -> None:
        """Take ``rig``'s track out of room track ``room_id`` (another of its rig replaces
        it); it stays free, and opens nothing while its rig does not see it."""
        track = self._tracks[room_id]
        tid = track.members[rig]
        track.members = _less(track.members, rig)
        track.strain = tab.without_rig(track.strain, rig)
        self._links[rig].pop(tid, None)
        if not track.members:
            self._bare.add(room_id)

    def _link(self, rig: str, row: int, room_id: int, est: Estimates, t_ns: int) -> None:
        """Link ``rig``'s track at table row ``row`` to room track ``room_id``; its estimate
        becomes its members' fusion."""
        tid = self._table.ids[rig][row - self._table.rows(rig).start]
        self._links[rig][tid] = room_id
        track = self._tracks[room_id]
        members = track.members = {**track.members, rig: tid}
        self._bare.discard(room_id)
        index = self._table.index
        est.set(room_id, *self._fuse_members([index[r][t] for r, t in members.items()], t_ns))

    def _open(self, f: np.ndarray, t_ns: int) -> int:
        """A new room track at ``t_ns`` from one predicted row ``f`` (WIDTH,); its id."""
        rid = self._next_id
        self._next_id += 1
        self._tracks[rid] = Links()
        self._state.open(rid, f, t_ns)
        self._bare.add(rid)
        self._seen_floor = min(self._seen_floor, t_ns)
        return rid

    def _update(self, t_ns: int, touched: set[int]) -> tuple[list[int], _Shared, list[int] | None]:
        """Fuse each ``touched`` room track's members at ``t_ns`` (all of them in one array
        operation) and write them into the stacked state (one assignment per column); coast
        those with none; end any unseen for ``max_coast_s``. Returns the ended ids, for each
        track fused here that more than one rig sees its members' own (unpredicted)
        measurements, and the touched tracks left, by id (None when none was touched)."""
        rids = sorted(touched)
        st = self._state
        shared: _Shared = {}
        fused_at: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        coast_at: tuple[np.ndarray, np.ndarray] | None = None
        # Each track's members' table rows, names and strains so far, in one pass.
        index = self._table.index
        idx: list[int] = []
        starts: list[int] = []
        with_members: list[int] = []
        coasting: list[int] = []
        links: list[Links] = []
        names: list[tuple[str, int]] = []
        before: list[float] = []
        sizes: list[int] = []
        for rid in rids:
            ln = self._tracks[rid]
            if not ln.members:
                coasting.append(rid)
                continue
            starts.append(len(idx))
            sizes.append(len(ln.members))
            with_members.append(rid)
            links.append(ln)
            strain = ln.strain
            for m in ln.members.items():
                idx.append(index[m[0]][m[1]])
                names.append(m)
                before.append(strain.get(m, 0.0))
        if with_members:
            table = self._table
            i = np.array(idx, dtype=np.intp)
            raw = table.f.take(i, axis=0)
            stamps = table.stamps.take(i)
            f = tab.predict_rows(raw, (t_ns - stamps) * 1e-9)
            s = np.array(starts)
            # Each member's strain so far scales its covariance down in the fusion; its
            # distance to the fused position then moves its strain on.
            size = np.array(sizes)
            so_far = np.array(before)
            fused, nis = tab.fuse_ray(f, table.ray.take(i, axis=0), s, so_far, size)
            flags = np.logical_or.reduceat(table.flags.take(i, axis=0), s, axis=0)
            slots = st.slots(with_members)
            best = s
            if len(idx) > len(starts):  # some track has several members
                run = np.arange(len(starts)).repeat(size)
                # Best member: least position trace, the first of equals (a stable sort).
                best = np.lexsort((f[:, DIAG_P].sum(axis=1), run))[s]
                after = tab.strain_steps(
                    so_far, nis, ((t_ns - st.stamp[slots]) * 1e-9)[run]
                ).tolist()
                when = stamps.tolist()
                measured: list[list[float]] = raw[:, _MEASURED].tolist()
                ends = [*starts[1:], len(idx)]
                for ln, rid, a, b in zip(links, with_members, starts, ends, strict=True):
                    if b - a == 1:
                        if ln.strain:
                            ln.strain = {}
                        continue
                    ln.strain = dict(zip(names[a:b], after[a:b], strict=True))
                    shared[rid] = [(names[j][0], when[j], measured[j]) for j in range(a, b)]
            else:
                for ln in links:
                    if ln.strain:
                        ln.strain = {}
            fused_at = (slots, fused, flags, table.extra.take(i[best], axis=0))
        if coasting:
            coast_at = (st.slots(coasting), st.coast(coasting, t_ns))
        ended: list[int] = []
        coast_ns = int(self.params.max_coast_s * 1e9)
        if t_ns - self._seen_floor > coast_ns:
            # Some track may be unseen too long: look (the floor is the oldest sighting, kept
            # low while tracks are seen, so that most steps need not look at every track).
            every = list(self._tracks)
            late = (t_ns - st.seen[st.slots(every)] > coast_ns).tolist()
            for rid, old in zip(every, late, strict=True):
                if old and rid not in touched:
                    ended.append(self._end(rid))
            left = st.slots(list(self._tracks))
            self._seen_floor = int(st.seen[left].min()) if len(left) else t_ns
        if not rids:
            return ended, shared, None
        if fused_at is not None:
            slots, rows, fl, extra = fused_at
            st.f[slots], st.extra[slots], st.described[slots] = rows, extra, True
            seen, moving = fl[:, SEEN], fl[:, MOVING]
            st.life[slots] = np.where(seen, np.where(moving, CONFIRMED, STATIONARY), COASTING)
            st.seen[slots[seen]] = t_ns
            st.vvalid[slots], st.hvalid[slots] = fl[:, VVALID], fl[:, HVALID]
        if coast_at is not None:  # no member: its own state predicted on, the rest kept
            st.f[coast_at[0]], st.life[coast_at[0]] = coast_at[1], COASTING
        # Without coasting tracks, the fused ones are every touched one, in the same order.
        every_slot = st.slots(rids) if fused_at is None or coasting else fused_at[0]
        st.stamp[every_slot] = t_ns
        self._seen_floor = min(self._seen_floor, t_ns)
        late = (t_ns - st.seen[every_slot] > coast_ns).tolist()
        if not any(late):
            self._kept_slots = every_slot
            return ended, shared, rids
        keep = []
        for rid, old in zip(rids, late, strict=True):
            if old:
                ended.append(self._end(rid))
                shared.pop(rid, None)
            else:
                keep.append(rid)
        return ended, shared, keep

    def _end(self, rid: int) -> int:
        """End room track ``rid`` and drop its links; returns ``rid``."""
        tr = self._tracks.pop(rid)
        self._state.end(rid)
        self._bare.discard(rid)
        for rig, tid in tr.members.items():
            self._links.get(rig, {}).pop(tid, None)
        return rid
