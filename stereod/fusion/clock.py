"""Each rig's clock offset, estimated from the objects several rigs see at once.

A rig whose clock reads ``d`` seconds ahead stamps a measurement made at ``t`` with ``t + d``;
predicted to the fusion instant from there, its position lags the object's by ``v d`` (``v``
its velocity). So for a moving object two rigs see, the difference of their positions along
the velocity is rig ``r``'s clock minus rig ``a``'s. Weighted by what each observation can say
(the difference's covariance ``S = P_r + P_a``), the offset over the last observations is the
least-squares ``d = -sum v^T S^-1 e / sum v^T S^-1 v`` (``e = x_r - x_a``), chained from the
room file's first rig (the reference, offset 0) through rigs that share objects with one
already known. Only objects faster than ``min_speed_mps`` count: a slow one says nothing of
time.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from stereod.fusion.fuser import FusedFrame

MIN_SAMPLES = 20
"""Shared observations needed before a rig's offset is given."""


@dataclass(frozen=True)
class ClockEstimate:
    """One rig's clock minus the reference rig's (ms) and the observations behind it."""

    offset_ms: float | None
    samples: int
    off: bool


class ClockWatch:
    """Rig clock offsets from fused frames; ``bound_ms`` flags a rig beyond it."""

    def __init__(
        self,
        rigs: list[str],
        *,
        bound_ms: float = 20.0,
        min_speed_mps: float = 0.3,
        window: int = 300,
    ) -> None:
        self.rigs = rigs
        self.bound_ms = bound_ms
        self.min_speed_mps = min_speed_mps
        self._samples: dict[str, deque[tuple[float, float]]] = {
            r: deque(maxlen=window) for r in rigs
        }
        """Per rig, (numerator, weight) of each observation: its offset estimate (ms) times
        its weight v^T S^-1 v (s^-2), and that weight."""

    def set_rigs(self, rigs: list[str], changed: list[str]) -> None:
        """A room file read again: ``rigs`` in its order, ``changed`` those whose pose moved
        (their observations were made in the old pose and are dropped). A new reference rig
        (the first) drops every rig's observations: they were offsets from the old one."""
        window = next(iter(self._samples.values())).maxlen if self._samples else 300
        keep = rigs[:1] == self.rigs[:1]
        self._samples = {
            r: self._samples[r] if keep and r in self._samples and r not in changed else
            deque(maxlen=window)
            for r in rigs
        }  # fmt: skip
        self.rigs = rigs

    def observe(self, frame: FusedFrame) -> None:
        """Take the shared observations of one fusion step (its room tracks' rig tracks,
        predicted to the step's instant)."""
        for track in frame.tracks:
            ms = frame.shared.get(track.room_id, [])
            if len(ms) < 2:
                continue
            v = track.velocity
            speed2 = float(v @ v)
            if speed2 < self.min_speed_mps**2:
                continue
            by_rig = {rig: (p, pc) for rig, p, pc in ms}
            known = {r: self._median(r) for r in by_rig}
            anchor = next((r for r in self.rigs if r in by_rig and known[r] is not None), None)
            if anchor is None:
                anchor = next(r for r in self.rigs if r in by_rig)
                if anchor != self.rigs[0]:
                    continue
            base_ms = known[anchor] or 0.0
            ref_p, ref_c = by_rig[anchor]
            for rig, (p, pc) in by_rig.items():
                if rig == anchor:
                    continue
                s_inv_v = np.linalg.solve(pc + ref_c, v)
                weight = float(v @ s_inv_v)
                d_ms = -float((p - ref_p) @ s_inv_v) / weight * 1e3
                self._samples[rig].append(((base_ms + d_ms) * weight, weight))

    def _median(self, rig: str) -> float | None:
        if rig == self.rigs[0]:
            return 0.0
        s = self._samples[rig]
        if len(s) < MIN_SAMPLES:
            return None
        return sum(n for n, _ in s) / sum(w for _, w in s)

    def estimate(self, rig: str) -> ClockEstimate:
        """``rig``'s clock minus the reference rig's, ms (None until enough observations)."""
        offset = self._median(rig)
        n = len(self._samples[rig])
        if rig == self.rigs[0]:
            return ClockEstimate(0.0, n, False)
        return ClockEstimate(offset, n, offset is not None and abs(offset) > self.bound_ms)
