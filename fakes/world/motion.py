"""Motion of a solid's centre: a constant-acceleration trajectory or a piecewise-linear path."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._base import _ZERO3, F64, Vec3, _build


@dataclass(frozen=True)
class Trajectory:
    """Centre motion ``p(t) = p0 + v (t - t_ref) + g (t - t_ref)^2 / 2`` (scene seconds).

    Outside ``[t_start, t_end]`` the object is absent, or (``hold``) rests at the end point.
    """

    p0_m: Vec3
    v_mps: Vec3 = _ZERO3
    g_mps2: Vec3 = _ZERO3
    t_ref_s: float = 0.0
    t_start_s: float | None = None
    t_end_s: float | None = None
    hold: bool = False

    def present(self, t_s: float) -> bool:
        if self.hold:
            return True
        if self.t_start_s is not None and t_s < self.t_start_s:
            return False
        return not (self.t_end_s is not None and t_s > self.t_end_s)

    def state(self, t_s: float) -> tuple[F64, F64]:
        """(position, velocity) at ``t_s`` (clamped into the interval when outside it)."""
        t = t_s
        moving = True
        if self.t_start_s is not None and t < self.t_start_s:
            t, moving = self.t_start_s, False
        if self.t_end_s is not None and t > self.t_end_s:
            t, moving = self.t_end_s, False
        dt = t - self.t_ref_s
        p0, v, g = (np.asarray(a, dtype=np.float64) for a in (self.p0_m, self.v_mps, self.g_mps2))
        pos = p0 + v * dt + 0.5 * g * dt * dt
        vel = v + g * dt if moving else np.zeros(3)
        return pos, vel

    def position(self, t_s: float) -> F64:
        return self.state(t_s)[0]


@dataclass(frozen=True)
class Waypoints:
    """Piecewise-linear path: the centre is at ``points_m[k]`` at scene time ``times_s[k]``.

    Between two waypoints it moves at constant velocity; two equal consecutive points make a
    stop.  Outside ``[times_s[0], times_s[-1]]`` the object is absent, or (``hold``) rests at
    the nearest end.  At a waypoint the velocity is that of the segment that starts there.
    """

    points_m: tuple[Vec3, ...]
    times_s: tuple[float, ...]
    hold: bool = False

    def __post_init__(self) -> None:
        if len(self.points_m) != len(self.times_s) or not self.points_m:
            raise ValueError("Waypoints: points_m and times_s must be non-empty, equal lengths")
        if any(b <= a for a, b in zip(self.times_s[:-1], self.times_s[1:], strict=True)):
            raise ValueError("Waypoints: times_s must increase strictly")

    @property
    def t_start_s(self) -> float:
        """Time of the first waypoint, s (the object appears then)."""
        return float(self.times_s[0])

    @property
    def t_end_s(self) -> float:
        """Time of the last waypoint, s (the object vanishes after it unless held)."""
        return float(self.times_s[-1])

    def present(self, t_s: float) -> bool:
        """Whether the object is in the scene at ``t_s`` (always when held)."""
        return self.hold or self.times_s[0] <= t_s <= self.times_s[-1]

    def state(self, t_s: float) -> tuple[F64, F64]:
        """(position m, velocity m/s) at ``t_s`` (at rest outside the time span)."""
        pts = np.asarray(self.points_m, dtype=np.float64)
        ts = self.times_s
        if len(ts) == 1 or t_s < ts[0]:
            return pts[0].copy(), np.zeros(3)
        if t_s >= ts[-1]:
            return pts[-1].copy(), np.zeros(3)
        k = int(np.searchsorted(np.asarray(ts), t_s, side="right")) - 1
        vel = (pts[k + 1] - pts[k]) / (ts[k + 1] - ts[k])
        return pts[k] + vel * (t_s - ts[k]), vel

    def position(self, t_s: float) -> F64:
        """Centre at ``t_s``, m."""
        return self.state(t_s)[0]


Motion = Trajectory | Waypoints


def motion_from_dict(d: dict[str, Any]) -> Motion:
    """Rebuild a Trajectory or Waypoints from its ``asdict`` form (``kind`` tells which)."""
    d = dict(d)
    kind = d.pop("kind", "Trajectory")
    if kind == "Waypoints":
        return Waypoints(
            tuple(tuple(float(c) for c in p) for p in d["points_m"]),  # type: ignore[misc]
            tuple(float(t) for t in d["times_s"]),
            bool(d.get("hold", False)),
        )
    return _build(Trajectory, d)  # type: ignore[no-any-return]
