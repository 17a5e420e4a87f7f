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

import math
from bisect import bisect_left
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

_Measured = tuple[int, list[float]]
"""A rig's measurement of a room track: its own stamp (ns, uncorrected) and its position (m)
and position covariance (m^2, row-major) as twelve floats (``FusedFrame.shared``)."""


@dataclass
class _Shared:
    """One room track's measurements by each rig that shares it, oldest first, and per rig the
    measurements not yet observed against the anchor rig."""

    seen: dict[str, deque[_Measured]] = field(default_factory=dict)
    waiting: dict[str, list[_Measured]] = field(default_factory=dict)


class _Samples:
    """One rig's last ``maxlen`` observations (offset ms, weight s^-2), oldest first, in one
    array: a robust mean reads them as two columns, with no list of tuples made into arrays."""

    def __init__(self, maxlen: int) -> None:
        self.maxlen = maxlen
        self._buf = np.zeros((2 * maxlen, 2))
        self._start = self._end = 0

    def __len__(self) -> int:
        return self._end - self._start

    def append(self, offset_ms: float, weight: float) -> None:
        """Add an observation, dropping the oldest beyond ``maxlen``."""
        if self._end == len(self._buf):  # full to its end: the newest maxlen - 1 to the front
            keep = self.maxlen - 1
            self._buf[:keep] = self._buf[self._end - keep : self._end]
            self._start, self._end = 0, keep
        self._buf[self._end] = offset_ms, weight
        self._end += 1
        if self._end - self._start > self.maxlen:
            self._start += 1

    def columns(self) -> tuple[np.ndarray, np.ndarray]:
        """The observations' offsets (ms) and weights, oldest first, (n,) each."""
        rows = self._buf[self._start : self._end]
        return rows[:, 0], rows[:, 1]


def _offsets(rows: np.ndarray) -> np.ndarray:
    """Each observation's offset (ms) and weight (s^-2), (n, 2), from rows of forty numbers:
    rig ``r``'s position ``x_r`` (3) and covariance ``P_r`` (9), the anchor's two measurements
    around its stamp (twelve each, alike), where between them (0 to 1) and the track's velocity
    ``v`` (3). The anchor's position and covariance are interpolated there (``x_a``, ``P_a``);
    ``d = -v^T S^-1 e / v^T S^-1 v`` with ``e = x_r - x_a``, ``S = P_r + P_a``, weight
    ``v^T S^-1 v``."""
    w = rows[:, 36:37]
    a = (1 - w) * rows[:, 12:24] + w * rows[:, 24:36]
    v = rows[:, 37:40]
    s_inv_v = np.linalg.solve((rows[:, 3:12] + a[:, 3:]).reshape(-1, 3, 3), v[:, :, None])[:, :, 0]
    weight = _dot(v, s_inv_v)
    out = np.empty((len(rows), 2))
    out[:, 0] = -_dot(rows[:, 0:3] - a[:, 0:3], s_inv_v) / weight * 1e3
    out[:, 1] = weight
    return out


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (n, 3) arrays, (n,), summed x, y, z in that order."""
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    """The value below which half of the total weight ``w`` of the values ``x`` lies."""
    order = x.argsort()
    cum = w[order].cumsum()
    return float(x[order[cum.searchsorted(0.5 * cum[-1])]])


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
        self._samples: dict[str, _Samples] = {r: _Samples(window) for r in rigs}
        """Per rig, each observation's offset estimate (ms) and its weight v^T S^-1 v
        (s^-2)."""
        self._rank = {r: k for k, r in enumerate(rigs)}
        """Each rig's place in the room file (the anchor of a shared track is the first)."""
        self._shared: dict[int, _Shared] = {}
        """Per room id, the rigs' measurements of it (what observations are made from)."""
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
            _Samples(window)
            for r in rigs
        }  # fmt: skip
        self.rigs = rigs
        self._rank = {r: k for k, r in enumerate(rigs)}
        self._means = {}
        self._shared = {}  # measurements made in the poses before

    def observe(self, frame: FusedFrame) -> None:
        """Take the shared measurements of one fusion step (each at its own stamp, corrected
        by :attr:`corrections_ns`), make every observation they complete, then update the
        corrections.

        In three passes: the measurements go to each track's history and the observations
        they complete are found (plain Python over a few entries a track); every
        observation's offset and weight are worked out at once (:func:`_offsets`, whole
        arrays); then they are added track by track, each track's on its anchor's offset as
        it stands after the tracks before it (what observing track by track gives)."""
        for rid in frame.ended:
            self._shared.pop(rid, None)
        if not frame.shared:
            return
        # The frame's tracks' velocities (its rows: a frame that shares has some).
        vs = frame.rows[:, 3:6].tolist() if frame.rows is not None else []
        velocity = {
            rid: (v, v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
            for rid, v in zip(frame.ids, vs, strict=True)
            if rid in frame.shared
        }
        min2 = self.min_speed_mps**2
        corrections = self.corrections_ns
        counts = {r: len(s) for r, s in self._samples.items()}
        """Each rig's observations as they will be once those found so far are added."""
        groups: list[tuple[str, list[str]]] = []
        """Per track observed, its anchor and the rig of each of its observations."""
        rows: list[list[float]] = []
        """Per observation, what :func:`_offsets` reads."""
        for rid, ms in frame.shared.items():
            sh = self._shared.get(rid)
            if sh is None:
                sh = self._shared[rid] = _Shared()
            v_s2 = velocity.get(rid)
            # Only a moving object's measurements are observed (a slow one says nothing of
            # time): the others go to the history alone.
            moving = v_s2 is not None and v_s2[1] >= min2
            for rig, stamp, m in ms:
                # The rig's own stamp, the correction in force taken off again: the pairs
                # observed are then the same whenever the correction came in.
                raw = stamp + corrections.get(rig, 0)
                hist = sh.seen.get(rig)
                if hist is None:
                    hist = sh.seen[rig] = deque(maxlen=HISTORY)
                elif hist and hist[-1][0] >= raw:
                    continue  # this measurement is in already (a step of another rig)
                entry = (raw, m)
                hist.append(entry)
                if moving:
                    sh.waiting.setdefault(rig, []).append(entry)
            if moving:
                assert v_s2 is not None
                found = self._bracket(sh, v_s2[0], counts, rows)
                if found is not None and found[1]:
                    groups.append(found)
            else:
                sh.waiting.clear()
        if not groups:
            return
        offsets = _offsets(np.array(rows)).tolist()
        touched: set[str] = set()
        k = 0
        for anchor, rigs in groups:
            base_ms = self._median(anchor) or 0.0
            for rig in rigs:
                d_ms, weight = offsets[k]
                k += 1
                self._samples[rig].append(base_ms + d_ms, weight)
                self._means.pop(rig, None)
                touched.add(rig)
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

    def _bracket(
        self, sh: _Shared, v: list[float], counts: dict[str, int], rows: list[list[float]]
    ) -> tuple[str, list[str]] | None:
        """Every waiting measurement of one room track that the anchor rig's (the first rig
        with a known offset among those that measured it: one with :data:`MIN_SAMPLES`
        observations, ``counts``, or the reference) now brackets: its row for
        :func:`_offsets` (the measurement, the anchor's two around it, where between them,
        the track's velocity ``v``) is added to ``rows``, ``counts`` is moved on. Returns the
        anchor and the rig of each row added (None without an anchor)."""
        rank, ref_rig = self._rank, self.rigs[0]
        anchor = None
        for r in sh.seen:
            if (
                r in rank
                and (r == ref_rig or counts[r] >= MIN_SAMPLES)
                and (anchor is None or rank[r] < rank[anchor])
            ):
                anchor = r
        if anchor is None:
            return None
        ref = sh.seen[anchor]
        stamps = [e[0] for e in ref]
        done: list[str] = []
        for rig, waiting in sh.waiting.items():
            if rig == anchor:
                continue
            keep = []
            for stamp, m in waiting:
                k = bisect_left(stamps, stamp)
                if k >= len(stamps):
                    keep.append((stamp, m))  # a's measurement after it: not yet
                    continue
                if k == 0 and stamps[0] != stamp:
                    continue  # before a's first kept measurement: never bracketed
                s0, m0 = ref[max(k - 1, 0)]
                s1, m1 = ref[k]
                if s1 - s0 > BRACKET_NS:
                    continue
                w = 0.0 if s1 == s0 else (stamp - s0) / (s1 - s0)
                rows.append([*m, *m0, *m1, w, *v])
                done.append(rig)
                counts[rig] += 1
            sh.waiting[rig] = keep
        sh.waiting[anchor] = []
        return anchor, done

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
        x, w = s.columns()
        mid = _weighted_median(x, w)
        sigma = 1.4826 * _weighted_median(np.abs(x - mid), w)
        keep = np.abs(x - mid) <= 3.0 * sigma if sigma > 0 else np.ones(len(x), dtype=bool)
        x, w = x[keep], w[keep]
        # ``numpy.average``'s own sums, without its checks.
        total = w.sum()
        mean = float((x * w).sum() / total)
        spread = float(((x - mean) ** 2 * w).sum() / total)
        return mean, math.sqrt(spread / len(x))

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
