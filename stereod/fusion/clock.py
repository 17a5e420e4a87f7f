"""Each rig's clock offset, estimated from the objects several rigs see at once.

A rig whose clock reads ``d`` seconds ahead stamps a measurement made at ``t`` with ``t + d``.
So for a moving object two rigs see, rig ``r``'s position at its stamp ``s`` lies behind rig
``a``'s position at ``a``'s stamp ``s`` by ``v d`` (``v`` its velocity): the difference along
the velocity is rig ``r``'s clock minus rig ``a``'s. Rig ``a``'s position at ``s`` is
interpolated between its two measurements whose stamps bracket ``s``, so an observation rests
on capture stamps and measured positions only, never on when messages arrived nor on a
prediction: it is made once ``a``'s measurements on both sides of ``s`` are in, whatever the
order they came in. Weighted by what each observation can say (the difference's covariance
``S = P_r + P_a``), each gives ``d = -v^T S^-1 e / v^T S^-1 v`` (``e = x_r - x_a(s)``) with
weight ``v^T S^-1 v``; the offset is the weighted mean of the last observations within three
robust sigmas of their weighted median (a plain mean would follow a rig's stray track),
chained from the room file's first rig (the reference, offset 0) through rigs that share
objects with one already known. Only objects faster than ``min_speed_mps`` count: a slow one
says nothing of time.

Correction: a rig's offset is trusted once it rests on at least :data:`TRUSTED_SAMPLES` shared
observations and its standard error (the kept observations' weighted spread over the square
root of their number) is within :data:`CONFIDENT_SIGMA_MS`; from then on that
rig's stamps are moved by it onto the reference rig's clock before they are fused
(:attr:`ClockWatch.corrections_ns`). The correction follows the estimate while it stays trusted
and is held while it is not. Observations made on corrected stamps measure what is left, so
each one adds the correction in force back: the estimate stays the clock's whole offset,
corrected or not.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from stereod.fusion.fuser import FusedFrame

MIN_SAMPLES = 20
"""Shared observations needed before a rig's offset is given."""
TRUSTED_SAMPLES = 60
"""Shared observations needed before a rig's offset corrects its stamps (two seconds of one
object both rigs see at 30 Hz: fewer, taken one after another, are too alike to trust their
spread)."""
CONFIDENT_SIGMA_MS = 5.0
"""A rig's offset whose standard error is within this (a quarter of the default 20 ms bound)
corrects its stamps, ms."""


BRACKET_NS = 150_000_000
"""Rig ``a``'s two measurements around a stamp are interpolated only when this close, ns (a few
frames: across a longer gap an object may have turned)."""
HISTORY = 12
"""Measurements kept per rig and room track (0.4 s at 30 Hz), to interpolate between."""


@dataclass
class _Shared:
    """One room track's measurements by each rig that shares it: (the rig's own stamp ns,
    uncorrected; position m; covariance m^2), oldest first, and per rig the measurements not
    yet observed against the anchor rig."""

    seen: dict[str, deque[tuple[int, np.ndarray, np.ndarray]]] = field(default_factory=dict)
    waiting: dict[str, list[tuple[int, np.ndarray, np.ndarray]]] = field(default_factory=dict)


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The value below which half of the total weight ``w`` of the values ``x`` lies."""
    order = np.argsort(x)
    cum = np.cumsum(w[order])
    return float(x[order][np.searchsorted(cum, 0.5 * cum[-1])])


@dataclass(frozen=True)
class ClockEstimate:
    """One rig's clock minus the reference rig's (ms) and the observations behind it."""

    offset_ms: float | None
    samples: int
    off: bool
    sigma_ms: float | None = None
    """The offset's standard error, ms (None until enough observations)."""
    correction_ms: float = 0.0
    """What the rig's stamps are corrected by (its trusted offset, else 0), ms."""


class ClockWatch:
    """Rig clock offsets from fused frames; ``bound_ms`` flags a rig beyond it."""

    def __init__(
        self,
        rigs: list[str],
        *,
        bound_ms: float = 20.0,
        min_speed_mps: float = 0.3,
        window: int = 300,
        correct: bool = True,
    ) -> None:
        self.rigs = rigs
        self.bound_ms = bound_ms
        self.min_speed_mps = min_speed_mps
        self.correct = correct
        self.corrections_ns: dict[str, int] = {}
        """Per rig, what its stamps are to be corrected by (subtracted), ns: its offset once
        trusted (none for the reference rig, nor with ``correct`` False)."""
        self._samples: dict[str, deque[tuple[float, float]]] = {
            r: deque(maxlen=window) for r in rigs
        }
        self._shared: dict[int, _Shared] = {}
        """Per room id, the rigs' measurements of it (what observations are made from)."""
        """Per rig, each observation's offset estimate (ms) and its weight v^T S^-1 v
        (s^-2)."""
        self._means: dict[str, tuple[float | None, float | None]] = {}
        """Per rig, :meth:`_mean` of its observations as they are now (dropped when one is
        added): a step asks for the same rigs' offsets once per shared object."""

    def set_rigs(self, rigs: list[str], changed: list[str]) -> None:
        """A room file read again: ``rigs`` in its order, ``changed`` those whose pose moved
        (their observations were made in the old pose and are dropped). A new reference rig
        (the first) drops every rig's observations: they were offsets from the old one."""
        window = next(iter(self._samples.values())).maxlen if self._samples else 300
        keep = rigs[:1] == self.rigs[:1]
        if not keep:
            self.corrections_ns = {}
        self._samples = {
            r: self._samples[r] if keep and r in self._samples and r not in changed else
            deque(maxlen=window)
            for r in rigs
        }  # fmt: skip
        self.rigs = rigs
        self._means = {}
        self._shared = {}  # measurements made in the poses before

    def observe(self, frame: FusedFrame) -> None:
        """Take the shared measurements of one fusion step (each at its own stamp, corrected
        by :attr:`corrections_ns`), make every observation they complete, then update the
        corrections."""
        for rid in frame.ended:
            self._shared.pop(rid, None)
        if not frame.shared:
            return
        # The frame's tracks' velocities (its rows: a frame that shares has some).
        v = frame.rows[:, 3:6] if frame.rows is not None else np.zeros((0, 3))
        speed2 = np.einsum("ij,ij->i", v, v).tolist()
        velocity = {
            rid: (v[j], speed2[j]) for j, rid in enumerate(frame.ids) if rid in frame.shared
        }
        min2 = self.min_speed_mps**2
        corrections = self.corrections_ns
        touched: set[str] = set()
        for rid, ms in frame.shared.items():
            sh = self._shared.get(rid)
            if sh is None:
                sh = self._shared[rid] = _Shared()
            v_s2 = velocity.get(rid)
            # Only a moving object's measurements are observed (a slow one says nothing of
            # time): the others go to the history alone.
            moving = v_s2 is not None and v_s2[1] >= min2
            for rig, stamp, p, pc in ms:
                # The rig's own stamp, the correction in force taken off again: the pairs
                # observed are then the same whenever the correction came in.
                raw = stamp + corrections.get(rig, 0)
                hist = sh.seen.get(rig)
                if hist is None:
                    hist = sh.seen[rig] = deque(maxlen=HISTORY)
                elif hist and hist[-1][0] >= raw:
                    continue  # this measurement is in already (a step of another rig)
                entry = (raw, p, pc)
                hist.append(entry)
                if moving:
                    sh.waiting.setdefault(rig, []).append(entry)
            if moving:
                assert v_s2 is not None
                touched |= self._observe(sh, v_s2[0])
            else:
                sh.waiting.clear()
        if self.correct:
            for rig in touched:
                offset, sigma = self._mean(rig)
                if (
                    offset is not None
                    and sigma is not None
                    and sigma <= CONFIDENT_SIGMA_MS
                    and len(self._samples[rig]) >= TRUSTED_SAMPLES
                ):
                    self.corrections_ns[rig] = round(offset * 1e6)

    def _observe(self, sh: _Shared, v: np.ndarray) -> set[str]:
        """Every waiting measurement of one room track that the anchor rig's (the first rig
        with a known offset among those that measured it) now brackets, observed against
        the anchor's interpolated at its stamp; returns the rigs observed."""
        known = {r: self._median(r) for r in sh.seen}
        anchor = next((r for r in self.rigs if r in sh.seen and known[r] is not None), None)
        if anchor is None:
            return set()
        base_ms = known[anchor] or 0.0
        ref = sh.seen[anchor]
        stamps = np.array([e[0] for e in ref], dtype=np.int64)
        done: set[str] = set()
        for rig, waiting in sh.waiting.items():
            if rig == anchor:
                continue
            keep = []
            for stamp, p, pc in waiting:
                k = int(np.searchsorted(stamps, stamp))
                if k >= len(stamps):
                    keep.append((stamp, p, pc))  # a's measurement after it: not yet
                    continue
                if k == 0 and stamps[0] != stamp:
                    continue  # before a's first kept measurement: never bracketed
                s0, p0, c0 = ref[max(k - 1, 0)]
                s1, p1, c1 = ref[k]
                if s1 - s0 > BRACKET_NS:
                    continue
                w = 0.0 if s1 == s0 else (stamp - s0) / (s1 - s0)
                pa, ca = (1 - w) * p0 + w * p1, (1 - w) * c0 + w * c1
                s_inv_v = np.linalg.solve(pc + ca, v)
                weight = float(v @ s_inv_v)
                d_ms = -float((p - pa) @ s_inv_v) / weight * 1e3
                self._samples[rig].append((base_ms + d_ms, weight))
                self._means.pop(rig, None)
                done.add(rig)
            sh.waiting[rig] = keep
        sh.waiting[anchor] = []
        return done

    def _median(self, rig: str) -> float | None:
        return self._mean(rig)[0]

    def _mean(self, rig: str) -> tuple[float | None, float | None]:
        """``rig``'s offset (ms) and its standard error (ms): the weighted mean of its
        observations within three robust sigmas (1.4826 x their weighted median absolute
        deviation) of their weighted median, and that spread over the root of their number.
        Robust: a stretch of observations from a rig's stray track (a mismeasured object fused
        with the other rig's for a second) is left out. None, None with fewer than
        :data:`MIN_SAMPLES`."""
        if rig == self.rigs[0]:
            return 0.0, 0.0
        known = self._means.get(rig)
        if known is None:
            known = self._means[rig] = self._robust_mean(rig)
        return known

    def _robust_mean(self, rig: str) -> tuple[float | None, float | None]:
        """:meth:`_mean` worked out from ``rig``'s observations."""
        s = self._samples[rig]
        if len(s) < MIN_SAMPLES:
            return None, None
        x = np.array([v for v, _ in s])
        w = np.array([w for _, w in s])
        mid = _weighted_median(x, w)
        sigma = 1.4826 * _weighted_median(np.abs(x - mid), w)
        keep = np.abs(x - mid) <= 3.0 * sigma if sigma > 0 else np.ones(len(x), dtype=bool)
        x, w = x[keep], w[keep]
        mean = float(np.average(x, weights=w))
        spread = float(np.average((x - mean) ** 2, weights=w))
        return mean, float(np.sqrt(spread / len(x)))

    def estimate(self, rig: str) -> ClockEstimate:
        """``rig``'s clock minus the reference rig's, ms (None until enough observations),
        its standard error and the correction in force."""
        offset, sigma = self._mean(rig)
        n = len(self._samples[rig])
        if rig == self.rigs[0]:
            return ClockEstimate(0.0, n, False, 0.0, 0.0)
        return ClockEstimate(
            offset,
            n,
            offset is not None and abs(offset) > self.bound_ms,
            sigma,
            self.corrections_ns.get(rig, 0) * 1e-6,
        )
