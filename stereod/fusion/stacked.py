"""Every room track's fused state in stacked arrays, one slot per live room track.

A fusion step writes the room tracks it fused with one assignment per column (state rows,
stamps, lifecycle codes, flags, what the best member passes on) instead of one Python object
per track, and hands them on as a :class:`FusedFrame` of the same columns; a
:class:`RoomTrack` object is built only when a caller asks for one (tests, tools), never on
the node's path. A row of :attr:`RoomState.f` is a ``rows.WIDTH`` row: position (m), velocity
(m/s), their covariances (m^2, (m/s)^2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from stereod.fusion.rows import PCOV, POS, VCOV, VEL, WIDTH, predict_rows
from stereod.fusion.wire import CONFIRMED, EXTRA, STATES
from stereod.tracking.types import TrackLifecycle


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
    """(rig name, its track id) -> that member's strain (``rows.strain_step``): its squared
    Mahalanobis distance to this track's fused position, averaged over the last few frames
    (none while the track has one member)."""


class Links:
    """A room track's members and their strains: the bookkeeping association works on, one
    small object per room track. Both dicts are replaced, never written into, so a frame can
    keep them as they were at its step without copying."""

    __slots__ = ("members", "strain")

    def __init__(self) -> None:
        self.members: dict[str, int] = {}
        """Rig name -> that rig's track id."""
        self.strain: dict[tuple[str, int], float] = {}
        """(rig name, its track id) -> that member's strain (``rows.strain_step``)."""


class Columns:
    """Some room tracks' figures as arrays, one entry per track: what a frame hands on."""

    __slots__ = ("described", "extra", "first", "hvalid", "ids", "life", "seen", "stamp", "vvalid")

    def __init__(self, state: RoomState, slots: np.ndarray, ids: list[int]) -> None:
        self.ids = ids
        """Room ids, in the frame's order."""
        self.life = state.life[slots]
        """Lifecycle codes (``wire.STATES``)."""
        self.stamp = state.stamp[slots]
        self.first = state.first[slots]
        self.seen = state.seen[slots]
        """Stamp of the state, first and last sighting, UTC ns."""
        self.vvalid = state.vvalid[slots]
        self.hvalid = state.hvalid[slots]
        self.extra = state.extra[slots]
        """(n, len(EXTRA)) what each track's best member passes on."""
        self.described = state.described[slots]
        """Whether a track had a member to describe it (its :attr:`extra` set)."""


class FusedFrame:
    """One fusion step's result: the room tracks at ``t_ns`` (as columns, and as
    :class:`RoomTrack` objects built when asked for) and the ids that ended."""

    def __init__(
        self,
        t_ns: int,
        ended: list[int],
        shared: dict[int, list[tuple[str, int, list[float]]]] | None = None,
        rows: np.ndarray | None = None,
        columns: Columns | None = None,
        links: list[Links] | None = None,
    ) -> None:
        self.t_ns = t_ns
        self.ended = ended
        self.shared = shared if shared is not None else {}
        """For each room id fused at this step that more than one rig sees: each rig's name,
        its track's own stamp (UTC ns, as corrected) and its position (m) and position
        covariance (m^2, row-major) there as twelve floats, in the room frame, not predicted
        (what clock offsets are estimated from: capture stamps only)."""
        self.rows = rows
        """The tracks' states as rows of ``rows.WIDTH`` columns (position, velocity, their
        covariances), in the order of :attr:`ids`; None when there are none."""
        self.columns = columns
        """The tracks' other figures, in the same order; None when there are none."""
        self._links = [(ln.members, ln.strain) for ln in links] if links else []
        self._tracks: list[RoomTrack] | None = None

    @property
    def ids(self) -> list[int]:
        """The room ids of the tracks, in order."""
        return self.columns.ids if self.columns is not None else []

    @property
    def tracks(self) -> list[RoomTrack]:
        """The room tracks as objects (built once, at the first call), by id."""
        if self._tracks is None:
            c, rows = self.columns, self.rows
            self._tracks = (
                []
                if c is None or rows is None
                else [
                    _track(c, rows, j, members, strain)
                    for j, (members, strain) in enumerate(self._links)
                ]
            )
        return self._tracks


def _track(
    c: Columns, rows: np.ndarray, j: int, members: dict[str, int], strain: dict[Any, float]
) -> RoomTrack:
    """Track ``j`` of columns ``c`` and state rows ``rows`` as a :class:`RoomTrack`."""
    r = rows[j]
    return RoomTrack(
        room_id=c.ids[j],
        stamp_utc_ns=int(c.stamp[j]),
        first_ns=int(c.first[j]),
        last_seen_ns=int(c.seen[j]),
        position=r[POS].copy(),
        position_cov=r[PCOV].reshape(3, 3).copy(),
        velocity=r[VEL].copy(),
        velocity_cov=r[VCOV].reshape(3, 3).copy(),
        state=STATES[int(c.life[j])],
        members=dict(members),
        extra=c.extra[j].copy() if c.described[j] else None,
        velocity_valid=bool(c.vvalid[j]),
        heading_valid=bool(c.hvalid[j]),
        strain=dict(strain),
    )


class RoomState:
    """The live room tracks' states, one slot each in every column; a track's slot is its
    own from :meth:`open` to :meth:`end`, then taken by a later track."""

    def __init__(self, capacity: int = 64) -> None:
        self.slot: dict[int, int] = {}
        """Room id -> its slot."""
        self._free: list[int] = []
        self._make(capacity)

    def _make(self, n: int) -> None:
        """Columns of ``n`` slots, the slots in use copied over."""
        old = getattr(self, "f", None)
        cols: dict[str, np.ndarray] = {
            "f": np.zeros((n, WIDTH)),
            "stamp": np.zeros(n, dtype=np.int64),
            "first": np.zeros(n, dtype=np.int64),
            "seen": np.zeros(n, dtype=np.int64),
            "life": np.full(n, CONFIRMED, dtype=np.int8),
            "vvalid": np.zeros(n, dtype=bool),
            "hvalid": np.zeros(n, dtype=bool),
            "extra": np.zeros((n, len(EXTRA))),
            "described": np.zeros(n, dtype=bool),
        }
        if old is not None:
            m = len(old)
            for name, col in cols.items():
                col[:m] = getattr(self, name)
            self._free = list(range(n - 1, m - 1, -1)) + self._free
        else:
            self._free = list(range(n - 1, -1, -1))
        self.f = cols["f"]
        """(n, WIDTH) each track's fused state at :attr:`stamp`."""
        self.stamp = cols["stamp"]
        """Each track's state's UTC stamp, ns."""
        self.first = cols["first"]
        """When each track was opened, UTC ns."""
        self.seen = cols["seen"]
        """When a rig last measured each track, UTC ns."""
        self.life = cols["life"]
        """Each track's lifecycle code (``wire.STATES``)."""
        self.vvalid = cols["vvalid"]
        self.hvalid = cols["hvalid"]
        """Whether its velocity and heading are valid (any member's)."""
        self.extra = cols["extra"]
        """(n, len(EXTRA)) what its best member passed on at its last fusion."""
        self.described = cols["described"]
        """Whether :attr:`extra` is set (a member fused it once)."""

    def open(self, rid: int, row: np.ndarray, t_ns: int) -> None:
        """A new track ``rid`` at ``t_ns`` (UTC ns) from one state row ``row`` (WIDTH,)."""
        if not self._free:
            self._make(2 * len(self.f))
        k = self._free.pop()
        self.slot[rid] = k
        self.f[k] = row
        self.stamp[k] = self.first[k] = self.seen[k] = t_ns
        self.life[k] = CONFIRMED
        self.vvalid[k] = self.hvalid[k] = self.described[k] = False

    def end(self, rid: int) -> None:
        """Free track ``rid``'s slot."""
        self._free.append(self.slot.pop(rid))

    def slots(self, rids: list[int]) -> np.ndarray:
        """The slots of tracks ``rids``, in order, (n,)."""
        slot = self.slot
        return np.array([slot[r] for r in rids], dtype=np.intp)

    def coast(self, rids: list[int], t_ns: int) -> np.ndarray:
        """Tracks ``rids``' own last states predicted to ``t_ns``, (n, WIDTH)."""
        k = self.slots(rids)
        return predict_rows(self.f[k], (t_ns - self.stamp[k]) * 1e-9)
