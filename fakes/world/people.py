"""Articulated people: capsule limbs and torso and a sphere head, scripted to sit, wave,
stand up, walk (swinging arms and legs) and stand still.

Body (for ``height_m`` = 1.79 m; every length scales with the height): hip joints 0.91 m
above the floor and 0.09 m either side of the body axis; thigh 0.44 m (radius 7 cm), shin
0.42 m (radius 5 cm, the foot is its rounded end); torso a vertical capsule from 0.10 to
0.50 m above the hips (radius 15 cm); head a 11 cm sphere 0.77 m above the hips; shoulders
0.47 m above the hips, 0.20 m out; upper arm 0.29 m (4.5 cm), forearm 0.27 m (4 cm).
Seated, the thighs are horizontal on a 0.40 m seat and the shins vertical.

Walking, the legs swing +-26 deg about the hips and the knees bend up to 29 deg, the arms
swing opposite to the legs; each walk is a whole number of steps (about 0.7 m long) so the
figure starts and ends with its legs together.

Truth: :meth:`Person.state` is the centroid of the torso capsule and its velocity (smooth:
it does not swing with the limbs); :meth:`Person.volume_centroid` is the centroid of the
figure's volume (the union of the solids, overlaps counted once, integrated on a 1 cm
lattice) and :meth:`Person.extent` the exact axis-aligned box of the union.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import cached_property
from typing import Any, Literal

import numpy as np

from ._base import _ZERO3, F64, Vec3, _build, _tuplify, _vec
from .motion import Trajectory
from .shapes import Capsule, Shape, Sphere

ActKind = Literal["stand", "sit", "walk", "stand_up", "sit_down"]
_HOLD = Trajectory(_ZERO3)
_REF_HEIGHT = 1.79
# Body lengths (m, for the reference height): see the module docstring.
_HIP_H, _HIP_W, _THIGH, _R_THIGH, _SHIN, _R_SHIN = 0.91, 0.09, 0.44, 0.07, 0.42, 0.05
_TORSO0, _TORSO1, _R_TORSO, _HEAD, _R_HEAD = 0.10, 0.50, 0.15, 0.77, 0.11
_SHOULDER_H, _SHOULDER_W, _UPPER, _R_UPPER, _FORE, _R_FORE = 0.47, 0.20, 0.29, 0.045, 0.27, 0.04
SEAT_HEIGHT_M = _SHIN + _R_SHIN - _R_THIGH  # 0.40 m: seated, the feet just touch the floor
_STEP_M = 0.7
_WAVE_HZ = 1.5


@dataclass(frozen=True)
class Act:
    """One step of a person's script.

    ``stand`` / ``sit``: hold still for ``duration_s`` (waving the right arm if ``wave``);
    ``stand_up`` / ``sit_down``: rise from / sink onto the seat (moving forward / back by a
    thigh length) in ``duration_s`` (default 1.5 s); ``walk``: straight to ``to_xz_m`` (x, z
    on the floor) at the person's speed, facing the way it walks (``duration_s`` ignored).
    """

    kind: ActKind
    duration_s: float = 0.0
    to_xz_m: tuple[float, float] | None = None
    wave: bool = False


@dataclass(frozen=True)
class _Seg:
    t0: float
    t1: float
    kind: ActKind
    p0: tuple[float, float]
    p1: tuple[float, float]
    yaw: float
    wave: bool
    steps: int


@dataclass(frozen=True)
class _Pose:
    x: float
    z: float
    yaw: float
    seated: float  # 0 standing .. 1 seated
    phase: float  # gait phase, rad
    gait: float  # 0 .. 1 gait amplitude
    wave: float | None  # wave elbow angle, rad, or None


@dataclass(frozen=True, kw_only=True)
class Person:
    """A person following ``acts`` from ``start_xz_m`` (floor position, m), first facing the
    compass heading ``facing_deg`` (0: +Z, away from the rig; 90: +X; 180: towards the rig).
    The floor is the plane Y = ``floor_y_m``; the person is in the scene from ``t_start_s``.
    """

    name: str
    start_xz_m: tuple[float, float]
    acts: tuple[Act, ...] = ()
    facing_deg: float = 180.0
    seated: bool = False
    floor_y_m: float = 1.0
    t_start_s: float = 0.0
    speed_mps: float = 1.2
    height_m: float = 1.75
    shirt_bgr: Vec3 = (150.0, 80.0, 40.0)
    trousers_bgr: Vec3 = (60.0, 50.0, 45.0)
    skin_bgr: Vec3 = (120.0, 150.0, 200.0)

    def __post_init__(self) -> None:
        if self.speed_mps <= 0.0 or self.height_m <= 0.0:
            raise ValueError(f"person {self.name!r}: speed_mps and height_m must be positive")

    # -- script -------------------------------------------------------------------------------

    @cached_property
    def _segments(self) -> list[_Seg]:
        segs: list[_Seg] = []
        t = self.t_start_s
        p = (float(self.start_xz_m[0]), float(self.start_xz_m[1]))
        yaw = math.radians(self.facing_deg)
        k = self.height_m / _REF_HEIGHT
        for act in self.acts:
            kind, p1, steps, dur = act.kind, p, 0, max(0.0, act.duration_s)
            if kind == "walk":
                if act.to_xz_m is None:
                    raise ValueError(f"person {self.name!r}: a walk needs to_xz_m")
                p1 = (float(act.to_xz_m[0]), float(act.to_xz_m[1]))
                dist = math.hypot(p1[0] - p[0], p1[1] - p[1])
                if dist > 0.0:
                    yaw = math.atan2(p1[0] - p[0], p1[1] - p[1])
                steps = max(1, round(dist / (_STEP_M * k)))
                dur = dist / self.speed_mps
            elif kind in ("stand_up", "sit_down"):
                dur = dur or 1.5
                sign = 1.0 if kind == "stand_up" else -1.0
                p1 = (
                    p[0] + sign * _THIGH * k * math.sin(yaw),
                    p[1] + sign * _THIGH * k * math.cos(yaw),
                )
            segs.append(_Seg(t, t + dur, kind, p, p1, yaw, act.wave, steps))
            t, p = t + dur, p1
        return segs

    @property
    def t_end_s(self) -> float:
        """End of the script (the person then holds its last pose)."""
        segs = self._segments
        return segs[-1].t1 if segs else self.t_start_s

    def present(self, t_s: float) -> bool:
        """Whether the person is in the scene at ``t_s`` (from ``t_start_s`` on)."""
        return t_s >= self.t_start_s

    def moving(self, t0_s: float, t1_s: float) -> bool:
        """Whether the figure changes at all during [t0, t1] (presence included)."""
        if self.present(t0_s) != self.present(t1_s):
            return True
        for s in self._segments:
            overlaps = s.t1 > t0_s and s.t0 < t1_s and s.t1 > s.t0
            if overlaps and (s.kind in ("walk", "stand_up", "sit_down") or s.wave):
                return True
        return False

    def _pose(self, t_s: float) -> _Pose:
        seated = 1.0 if self.seated else 0.0
        x, z = self.start_xz_m
        yaw = math.radians(self.facing_deg)
        for s in self._segments:
            if t_s < s.t0:
                break
            u = 1.0 if s.t1 <= s.t0 else min(1.0, (t_s - s.t0) / (s.t1 - s.t0))
            x, z, yaw = s.p1[0], s.p1[1], s.yaw
            if s.kind in ("sit", "sit_down"):
                seated = 1.0
            elif s.kind in ("stand", "stand_up", "walk"):
                seated = 0.0
            if t_s >= s.t1:
                continue
            # Inside this segment.
            if s.kind == "walk":
                x, z = s.p0[0] + u * (s.p1[0] - s.p0[0]), s.p0[1] + u * (s.p1[1] - s.p0[1])
                return _Pose(x, z, yaw, 0.0, math.pi * s.steps * u, 1.0, None)
            if s.kind in ("stand_up", "sit_down"):
                e = u * u * (3.0 - 2.0 * u)  # smoothstep
                x, z = s.p0[0] + e * (s.p1[0] - s.p0[0]), s.p0[1] + e * (s.p1[1] - s.p0[1])
                return _Pose(x, z, yaw, 1.0 - e if s.kind == "stand_up" else e, 0.0, 0.0, None)
            wave = None
            if s.wave:
                wave = 0.35 + 0.35 * math.sin(2.0 * math.pi * _WAVE_HZ * (t_s - s.t0))
            return _Pose(x, z, yaw, seated, 0.0, 0.0, wave)
        return _Pose(x, z, yaw, seated, 0.0, 0.0, None)

    # -- geometry -----------------------------------------------------------------------------

    def parts(self, t_s: float) -> list[tuple[Shape, F64]]:
        """The figure's solids and their centres at ``t_s`` (rig frame, m)."""
        q = self._pose(max(t_s, self.t_start_s))
        k = self.height_m / _REF_HEIGHT
        fwd = np.array([math.sin(q.yaw), 0.0, math.cos(q.yaw)])
        right = np.array([math.cos(q.yaw), 0.0, -math.sin(q.yaw)])
        down = np.array([0.0, 1.0, 0.0])
        hip_h = k * (_HIP_H + q.seated * (SEAT_HEIGHT_M + _R_THIGH - _HIP_H))
        root = np.array([q.x, self.floor_y_m - hip_h, q.z])
        out: list[tuple[Shape, F64]] = []

        def cap(a: F64, b: F64, r: float, colour: Vec3) -> None:
            c = Capsule(name=self.name, trajectory=_HOLD, colour_bgr=colour, radius_m=r * k,
                        half_axis_m=_vec(0.5 * (b - a)))  # fmt: skip
            out.append((c, 0.5 * (a + b)))

        def ray(angle: float, side: F64 | None = None) -> F64:
            return np.asarray(
                math.cos(angle) * down + math.sin(angle) * (fwd if side is None else side)
            )

        cap(root - down * _TORSO0 * k, root - down * _TORSO1 * k, _R_TORSO, self.shirt_bgr)
        head = Sphere(
            name=self.name, trajectory=_HOLD, colour_bgr=self.skin_bgr, radius_m=_R_HEAD * k
        )
        out.append((head, root - down * _HEAD * k))
        swing = 0.45 * q.gait * math.sin(q.phase)
        for sign, side in ((1.0, -1.0), (-1.0, 1.0)):  # left leg swings with +swing
            hip = root + side * _HIP_W * k * right
            flex = q.seated * math.pi / 2 + sign * swing
            bend = q.seated * math.pi / 2 + 0.5 * q.gait * max(0.0, sign * math.sin(q.phase))
            knee = hip + _THIGH * k * ray(flex)
            cap(hip, knee, _R_THIGH, self.trousers_bgr)
            cap(knee, knee + _SHIN * k * ray(flex - bend), _R_SHIN, self.trousers_bgr)
        for sign, side in ((-1.0, -1.0), (1.0, 1.0)):  # arms swing against the legs
            sh = root - down * _SHOULDER_H * k + side * _SHOULDER_W * k * right
            if side > 0 and q.wave is not None:
                lift = 2.3
                elbow = sh + _UPPER * k * ray(lift, right)
                hand = elbow + _FORE * k * ray(lift + q.wave, right)
            else:
                a = sign * 1.1 * swing + 0.3 * q.seated
                elbow = sh + _UPPER * k * ray(a)
                hand = elbow + _FORE * k * ray(a + 0.25 + 0.2 * q.seated)
            cap(sh, elbow, _R_UPPER, self.shirt_bgr)
            cap(elbow, hand, _R_FORE, self.skin_bgr)
        return out

    def half_extent_m(self) -> F64:
        """Half size of a box about the torso centre containing the figure in any pose."""
        k = self.height_m / _REF_HEIGHT
        return np.array([0.9, 1.1, 0.9]) * k

    def bound_m(self) -> float:
        """Radius of a sphere about the torso centre that holds the figure in any pose, m."""
        return float(np.linalg.norm(self.half_extent_m()))

    def extent(self, t_s: float) -> tuple[F64, F64]:
        """Exact axis-aligned box (lo, hi), m, of the union of the figure's solids at t."""
        lo = np.full(3, np.inf)
        hi = np.full(3, -np.inf)
        for solid, c in self.parts(t_s):
            h = solid.half_extent_m()
            lo, hi = np.minimum(lo, c - h), np.maximum(hi, c + h)
        return lo, hi

    def torso_centre(self, t_s: float) -> F64:
        """Centroid of the torso capsule at ``t_s`` (rig frame, m): the truth centre."""
        return self.parts(t_s)[0][1]

    def state(self, t_s: float) -> tuple[F64, F64]:
        """Truth (torso centre m, its velocity m/s by a +-0.1 ms central difference)."""
        h = 1e-4
        c = self.torso_centre(t_s)
        v = (self.torso_centre(t_s + h) - self.torso_centre(t_s - h)) / (2.0 * h)
        return c, v

    def volume_centroid(self, t_s: float, step_m: float = 0.01) -> F64:
        """Centroid of the union of the solids (overlaps once), on a global lattice of step."""
        parts = self.parts(t_s)
        key = (step_m, tuple((solid, tuple(c)) for solid, c in parts))
        cache = self._centroids
        if key in cache:
            return cache[key].copy()
        num, den = np.zeros(3), 0.0
        for solid, c in parts:
            h = solid.half_extent_m()
            axes = [
                np.arange(math.floor((c[i] - h[i]) / step_m), math.ceil((c[i] + h[i]) / step_m))
                for i in range(3)
            ]
            g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            p = (g + 0.5) * step_m
            mine = solid.contains(p - c)
            p = p[mine]
            count = np.zeros(len(p))
            for other, oc in parts:
                count += other.contains(p - oc)
            w = 1.0 / count
            num += (p * w[:, None]).sum(axis=0)
            den += float(w.sum())
        if len(cache) > 64:  # poses of a still stretch repeat; walking ones do not
            cache.clear()
        cache[key] = num / den
        return cache[key].copy()

    @cached_property
    def _centroids(self) -> dict[Any, F64]:
        return {}

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields with ``kind`` = "Person" (as written to scene.json)."""
        return {"kind": "Person", **asdict(self)}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Person:
        """Rebuild a person from :meth:`to_dict`'s output (lists back to tuples)."""
        d = dict(d)
        d.pop("kind", None)
        d["acts"] = tuple(_build(Act, a) for a in d.get("acts", []))
        return cls(**{k: (_tuplify(v) if k != "acts" else v) for k, v in d.items()})
