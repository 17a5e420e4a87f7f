"""Pair left and right frames by nearest capture timestamp (design sec. 1).

The Minoru's eyes free-run, so a left frame's best partner is the right frame nearest in time,
at most half a frame period away. The pairer sees both streams in arrival order and decides each
pair as soon as it is unambiguous: the earlier head frame is paired with the other eye's head when
no later frame of its own eye could be nearer to that partner. Every frame that is not paired is
counted under a reason. The class is single-threaded and pure; the daemon serialises calls.

Near half a frame of skew both neighbours are almost equally near, and the strict nearest rule
would drop a frame whenever jitter tips the balance. So the pairing keeps its phase until the
other neighbour is nearer by more than ``HYSTERESIS`` of a period: every frame stays paired
one-to-one while the skew hovers around half a frame (pairs then at most 0.6 frame apart, which
skew compensation takes), and one frame is dropped only when the phase has really moved on.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

from stereod.sources.frames import Eye, Frame, StereoPair

HYSTERESIS = 0.1
"""Share of a frame period by which another partner must be nearer before the pairing changes
phase (and one frame is dropped)."""
DEFAULT_TOLERANCE_NS = 40_000_000
"""Largest |skew| (ns) of a pair by default: more than half a frame at 15 Hz and above."""
DROP_NO_PARTNER = "no_partner"
"""No frame of the other eye within the tolerance."""
DROP_SUPERSEDED = "superseded"
"""The next frame of the same eye was nearer to the partner."""
DROP_NON_MONOTONIC = "non_monotonic"
"""The frame's timestamp was not after the previous frame of the same eye."""
DROP_OVERFLOW = "overflow"
"""Too many frames of one eye waited for the other eye (the other eye stalled)."""
DROP_CLOCK_JUMP = "clock_jump"
"""A frame stamped ahead of its eye's clock, found out when the eye's next frames, in order
among themselves, all came before it (see ``RESYNC_AFTER``)."""
RESYNC_AFTER = 3
"""Frames of one eye in a row, in order among themselves, that must come before the eye's last
accepted frame before that frame counts as a jump of its clock, not theirs: it is dropped and
the eye goes on from them. Without this, one frame stamped days ahead would stop all pairing
until the clock caught up."""


@dataclass
class PairerStats:
    """Counters since start: frames in per eye, pairs out, drops by reason."""

    frames: dict[Eye, int] = field(default_factory=lambda: {Eye.LEFT: 0, Eye.RIGHT: 0})
    pairs: int = 0
    drops: dict[str, int] = field(default_factory=collections.Counter)
    resyncs: dict[Eye, int] = field(default_factory=lambda: {Eye.LEFT: 0, Eye.RIGHT: 0})
    """Times an eye's clock was found to have jumped ahead (see ``RESYNC_AFTER``)."""


class Pairer:
    """Match the two eyes by nearest timestamp within ``tolerance_ns``.

    ``max_pending`` bounds how many frames of one eye may wait for the other; beyond that the
    oldest is dropped (``overflow``), so a stalled eye never grows memory. When frames come in
    capture-time order across both eyes (``in_order``: a file's, merged), a frame that waited
    that long has no partner: the other eye gave nothing for ``max_pending`` frames (a damaged
    or missing stretch of its video), and the drop is counted as ``no_partner`` (which holds
    while ``max_pending`` frame periods exceed the tolerance, as with the defaults: 8 frames
    against 40 ms).
    """

    def __init__(self, tolerance_ns: int = DEFAULT_TOLERANCE_NS, max_pending: int = 8) -> None:
        if tolerance_ns <= 0:
            raise ValueError(f"pairing tolerance must be > 0 ns, got {tolerance_ns}")
        self.tolerance_ns = tolerance_ns
        self.max_pending = max(2, max_pending)
        self._pending: dict[Eye, collections.deque[Frame]] = {
            Eye.LEFT: collections.deque(),
            Eye.RIGHT: collections.deque(),
        }
        self._last_t: dict[Eye, int | None] = {Eye.LEFT: None, Eye.RIGHT: None}
        self._period_ns: dict[Eye, float | None] = {Eye.LEFT: None, Eye.RIGHT: None}
        self._rejected: dict[Eye, list[int]] = {Eye.LEFT: [], Eye.RIGHT: []}
        self._period_before: dict[Eye, float | None] = {Eye.LEFT: None, Eye.RIGHT: None}
        """Each eye's period estimate before its last accepted frame (a clock jump's frame
        must not leave its gap in the estimate)."""
        self._next_seq = 0
        self.stats = PairerStats()
        self.in_order = False
        """Whether frames come in capture-time order across both eyes (see the class)."""

    def last_ns(self, eye: Eye) -> int | None:
        """The capture time (ns) of the last frame of an eye taken in order (None before)."""
        return self._last_t[eye]

    def period_ns(self, eye: Eye) -> float | None:
        """Running estimate of an eye's frame period (ns), from successive timestamps."""
        return self._period_ns[eye]

    def push(self, frame: Frame) -> list[StereoPair]:
        """Take one frame; return the pairs that became unambiguous."""
        eye = frame.eye
        self.stats.frames[eye] += 1
        last = self._last_t[eye]
        if last is not None and frame.t_ns <= last:
            rejected = self._rejected[eye]
            if rejected and frame.t_ns <= rejected[-1]:
                rejected.clear()  # not a stream of its own: just a frame out of order
            rejected.append(frame.t_ns)
            if len(rejected) < RESYNC_AFTER:
                self.stats.drops[DROP_NON_MONOTONIC] += 1
                return []
            self._resync(eye, rejected[0])
            last = self._last_t[eye]
        self._rejected[eye].clear()
        self._period_before[eye] = self._period_ns[eye]
        if last is not None:
            dt = float(frame.t_ns - last)
            p = self._period_ns[eye]
            self._period_ns[eye] = dt if p is None else 0.9 * p + 0.1 * dt
        self._last_t[eye] = frame.t_ns
        queue = self._pending[eye]
        queue.append(frame)
        if len(queue) > self.max_pending:
            queue.popleft()
            self.stats.drops[DROP_NO_PARTNER if self.in_order else DROP_OVERFLOW] += 1
        return self._match(final=False)

    def _resync(self, eye: Eye, t_ns: int) -> None:
        """The eye's last accepted frames from ``t_ns`` (ns) on were stamped ahead of its
        clock: drop them (``clock_jump``) and go on from the frames rejected meanwhile (all but
        the newest, still counted ``non_monotonic``; the newest is taken now)."""
        queue = self._pending[eye]
        ahead = [f for f in queue if f.t_ns >= t_ns]
        for f in ahead:
            queue.remove(f)
        self.stats.drops[DROP_CLOCK_JUMP] += len(ahead)
        self.stats.resyncs[eye] += 1
        self._last_t[eye] = queue[-1].t_ns if queue else None
        self._period_ns[eye] = self._period_before[eye]
        self._rejected[eye].clear()

    def flush(self) -> list[StereoPair]:
        """End of input: pair what can be paired and count the rest as unpaired."""
        pairs = self._match(final=True)
        for queue in self._pending.values():
            self.stats.drops[DROP_NO_PARTNER] += len(queue)
            queue.clear()
        return pairs

    def pending(self) -> int:
        """Frames waiting for a partner, both eyes."""
        return sum(len(q) for q in self._pending.values())

    def _match(self, *, final: bool) -> list[StereoPair]:
        out: list[StereoPair] = []
        left, right = self._pending[Eye.LEFT], self._pending[Eye.RIGHT]
        while left and right:
            early_q, other_q = (left, right) if left[0].t_ns <= right[0].t_ns else (right, left)
            early, other = early_q[0], other_q[0]
            gap = other.t_ns - early.t_ns
            if gap > self.tolerance_ns:
                early_q.popleft()
                self.stats.drops[DROP_NO_PARTNER] += 1
                continue
            period = self._period_ns[early.eye]
            margin = HYSTERESIS * period if period is not None else 0.0
            if len(early_q) > 1:
                if abs(early_q[1].t_ns - other.t_ns) < gap - margin:
                    early_q.popleft()
                    self.stats.drops[DROP_SUPERSEDED] += 1
                    continue
            elif not final and (period is None or gap > (0.5 + HYSTERESIS) * period):
                break
            early_q.popleft()
            other_q.popleft()
            l_frame, r_frame = (early, other) if early.eye is Eye.LEFT else (other, early)
            out.append(StereoPair(self._next_seq, l_frame, r_frame))
            self._next_seq += 1
            self.stats.pairs += 1
        return out
