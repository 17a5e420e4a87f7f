"""The scene: rig, clocks, objects, room, light, transport; timing, truth and rendering."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import numpy.typing as npt

from ._base import EYES, F32, F64, U8, _build, _eye_index, _jsonable
from .background import Bound, _Backdrop
from .camera import Clock, Photometry, Quality, RenderedFrame, Rig
from .light import Blocker, Lamps, Lighting
from .motion import Waypoints, motion_from_dict
from .people import Person
from .raycast import _Caster, _Placed
from .shapes import _SHAPES, Shape
from .textures import Room
from .transport import Transport

SceneObject = Shape | Person


@dataclass(frozen=True)
class Scene(_Backdrop, _Caster):
    """Everything needed to render a stereo sequence and its ground truth."""

    rig: Rig = field(default_factory=Rig)
    left_clock: Clock = field(default_factory=Clock)
    right_clock: Clock = field(default_factory=Clock)
    objects: tuple[SceneObject, ...] = ()
    lighting: Lighting = field(default_factory=Lighting)
    photometry: Photometry = field(default_factory=Photometry)
    room: Room = field(default_factory=Room)
    quality: Quality = field(default_factory=Quality)
    seed: int = 0
    t0_ns: int = 1_000_000_000_000
    duration_s: float = 5.0
    exposure_s: float = 0.0
    name: str = "scene"
    lamps: Lamps | None = None  # None: unlit wall and floor, directional object light
    transport: Transport = field(default_factory=Transport)

    def __post_init__(self) -> None:
        object.__setattr__(self, "objects", tuple(self.objects))
        names = [o.name for o in self.objects]
        if len(set(names)) != len(names):
            raise ValueError("object names must be unique")

    # -- time ---------------------------------------------------------------------------------

    def time_s(self, t_ns: int) -> float:
        return (int(t_ns) - self.t0_ns) * 1e-9

    def to_ns(self, t_s: float) -> int:
        return self.t0_ns + round(t_s * 1e9)

    def clock(self, eye: str) -> Clock:
        return self.left_clock if _eye_index(eye) == 0 else self.right_clock

    @cached_property
    def _schedule(self) -> dict[str, npt.NDArray[np.int64]]:
        out: dict[str, npt.NDArray[np.int64]] = {}
        for i, eye in enumerate(EYES):
            rng = np.random.default_rng([self.seed, 1000 + i])
            t = self.clock(eye).capture_times_s(self.duration_s, rng)
            out[eye] = self.t0_ns + np.round(t * 1e9).astype(np.int64)
        return out

    def frame_times(self, eye: str) -> list[int]:
        """Capture (exposure start) timestamps of one eye, ns, strictly increasing."""
        return [int(t) for t in self._schedule[EYES[_eye_index(eye)]]]

    def all_frame_times(self) -> list[int]:
        return sorted(set(self.frame_times("left")) | set(self.frame_times("right")))

    def skew_frames(self) -> F64:
        """Skew of every right frame vs the nearest left frame, in left frame periods."""
        left = np.asarray(self.frame_times("left"), dtype=np.float64)
        right = np.asarray(self.frame_times("right"), dtype=np.float64)
        if left.size == 0 or right.size == 0:
            return np.zeros(0)
        idx = np.clip(np.searchsorted(left, right), 1, max(1, left.size - 1))
        cand = np.stack([left[idx - 1], left[np.minimum(idx, left.size - 1)]])
        best = cand[np.argmin(np.abs(right[None, :] - cand), axis=0), np.arange(right.size)]
        return (right - best) * 1e-9 / self.left_clock.period_s

    # -- truth --------------------------------------------------------------------------------

    def truth(self, t_ns: int) -> dict[str, tuple[F64, F64]]:
        """Object name -> (centre m, velocity m/s) at ``t_ns``, for objects present then."""
        t = self.time_s(t_ns)
        return {o.name: o.state(t) for o in self.objects if o.present(t)}

    def truth_details(self, t_ns: int) -> dict[str, dict[str, Any]]:
        """Object name -> kind, centre and velocity (as :meth:`truth`), the centroid of the
        volume, the torso centre (people; else the centre) and the axis-aligned extent
        ``lo``/``hi`` of the object's solids (m, rig frame), for objects present at t_ns."""
        t = self.time_s(t_ns)
        out: dict[str, dict[str, Any]] = {}
        for o in self.objects:
            if not o.present(t):
                continue
            p, v = o.state(t)
            if isinstance(o, Person):
                lo, hi = o.extent(t)
                vol = o.volume_centroid(t)
            else:
                lo, hi = p - o.half_extent_m(), p + o.half_extent_m()
                vol = p
            kind = type(o).__name__
            out[o.name] = {"kind": kind, "centre": p, "velocity": v, "torso": p,
                           "volume_centroid": vol, "lo": lo, "hi": hi}  # fmt: skip
        return out

    def object(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    def coverage(self, eye: str, t_ns: int) -> dict[str, float]:
        """Visible (unoccluded, in-image) area in px of each present object, exposure-averaged."""
        _, cov = self._render(eye, t_ns, want_image=False)
        t = self.time_s(t_ns)
        present = [
            o.name for o in self.objects if any(o.present(ti) for ti in self._exposure_times_s(t))
        ]
        return {n: cov.get(n, 0.0) for n in present}

    def visible(self, name: str, eye: str, t_ns: int) -> bool:
        """True when some of the object is in this eye's image and not fully occluded."""
        self.object(name)
        return self.coverage(eye, t_ns).get(name, 0.0) > 0.0

    # -- background ---------------------------------------------------------------------------

    # -- objects ------------------------------------------------------------------------------

    def _exposure_times_s(self, t_s: float) -> F64:
        e = self.exposure_s
        if e <= 0.0:
            return np.array([t_s])
        n = self.quality.exposure_samples or self._auto_exposure_samples(t_s)
        return t_s + e * (np.arange(n) + 0.5) / n

    def _auto_exposure_samples(self, t_s: float) -> int:
        """Enough temporal samples that objects move < 0.5 px between them."""
        e = self.exposure_s
        disp = 0.0
        for o in self.objects:
            if not (o.present(t_s) or o.present(t_s + e)):
                continue
            for (solid, p0), (_, p1) in zip(o.parts(t_s), o.parts(t_s + e), strict=True):
                if min(p0[2], p1[2]) < 0.05:
                    return 64
                for eye in EYES:
                    uv = self.rig.project(eye, np.stack([p0, p1]))
                    disp = max(disp, float(np.abs(uv[1] - uv[0]).max()))
                grow = self.rig.focal_px * float(solid.half_extent_m().max())
                disp = max(disp, grow * abs(1.0 / p0[2] - 1.0 / p1[2]))
        return int(np.clip(math.ceil(disp / 0.5), 2, 64)) if math.isfinite(disp) else 64

    def _placed(self, t_s: float) -> list[_Placed]:
        return [
            (o.name, solid, centre)
            for o in self.objects
            if o.present(t_s)
            for solid, centre in o.parts(t_s)
        ]

    def _moving(self, t0_s: float, t1_s: float) -> bool:
        """Whether any object moves, appears or vanishes during [t0, t1] (scene seconds)."""
        for o in self.objects:
            if isinstance(o, Person):
                if o.moving(t0_s, t1_s):
                    return True
                continue
            tr = o.trajectory
            if tr.present(t0_s) != tr.present(t1_s):
                return True
            if isinstance(tr, Waypoints):  # moving, or a stop ending inside the span
                edges: list[float | None] = list(tr.times_s)
            else:
                edges = [tr.t_start_s, tr.t_end_s]
            if any(e is not None and t0_s < e < t1_s for e in edges):
                return True
            if tr.present(t0_s) and np.any(tr.state(t0_s)[1] != 0.0):
                return True
        return False

    def _render(self, eye: str, t_ns: int, want_image: bool) -> tuple[F32 | None, dict[str, float]]:
        """Radiance (or None) and coverage (px) of a frame whose row 0 starts at t_ns.

        With a rolling shutter each row r is cast at its own instants ``t + r readout / H``
        (+ exposure samples) unless nothing moves during the frame's readout and exposure.
        A frame where nothing moves is kept and reused by the next frame with the same
        content (a still stretch renders once)."""
        eye = EYES[_eye_index(eye)]
        t = self.time_s(t_ns)
        h = self.rig.height_px
        readout = self.transport.row_readout_s
        span = readout + max(self.exposure_s, 0.0)
        still = not self._moving(t, t + span)
        key = None
        if still and want_image:
            key = (eye, tuple((n, s, tuple(c)) for n, s, c in self._placed(t)))
            hit = self._still_cache.get(eye)
            if hit is not None and hit[0] == key:
                return hit[1].copy(), dict(hit[2])
        if readout <= 0.0 or still:
            out, cov = self._render_band(eye, self._exposure_times_s(t), 0, h, want_image)
        else:
            out = np.empty((h, self.rig.width_px, 3), np.float32) if want_image else None
            cov = {}
            k = max(1, self.quality.rolling_band_rows)
            for r in range(0, h, k):
                r1 = min(h, r + k)
                times = self._exposure_times_s(t + 0.5 * (r + r1 - 1) * readout / h)
                band, bcov = self._render_band(eye, times, r, r1, want_image)
                if out is not None and band is not None:
                    out[r:r1] = band
                for name, a in bcov.items():
                    cov[name] = cov.get(name, 0.0) + a
        if key is not None and out is not None:
            self._still_cache[eye] = (key, out.copy(), dict(cov))
        return out, cov

    @cached_property
    def _still_cache(self) -> dict[str, tuple[Any, F32, dict[str, float]]]:
        return {}

    def _render_band(
        self, eye: str, times: F64, r0: int, r1: int, want_image: bool
    ) -> tuple[F32 | None, dict[str, float]]:
        """Rows [r0, r1) averaged over the sample instants ``times`` (scene seconds)."""
        n = len(times)
        h = self.rig.height_px
        lit = self.lamps is not None
        bg = self._background_image(eye) if want_image else None
        out = bg[r0:r1].copy() if bg is not None else None
        if lit and out is not None:
            out[:] = 0.0
        cov: dict[str, float] = {}
        for t in times:
            placed = self._placed(float(t))
            blockers: list[Blocker] = [(solid, c) for _, solid, c in placed]
            frame = bg
            if lit and bg is not None:
                pr0, pr1 = max(0, r0 - 1), min(h, r1 + 1)
                frame = self._shadowed(eye, blockers, self._bounds(placed), pr0, pr1)
            layer = frame[r0:r1].copy() if (lit and frame is not None) else None
            for rect, group in self._groups(eye, placed):
                if rect[1] <= r0 or rect[0] >= r1:
                    continue
                clip = (max(rect[0], r0 - 1), min(rect[1], r1 + 1), rect[2], rect[3])
                if clip[:2] != rect[:2]:  # a band: only the solids that reach its rows
                    group = [it for it in group if self._reaches(eye, it, clip[0], clip[1])]
                    if not group:
                        continue
                back = frame if frame is not None else np.zeros((0, 0, 3), np.float32)
                vals, gcov = self._render_group(
                    eye, clip, group, want_image, back, blockers, (r0, r1)
                )
                if out is not None and bg is not None and vals is not None:
                    a, b = max(clip[0], r0), min(clip[1], r1)
                    part = vals[a - clip[0] : b - clip[0]]
                    c0, c1 = rect[2], rect[3]
                    if layer is not None:
                        layer[a - r0 : b - r0, c0:c1] = part
                    elif n == 1:
                        out[a - r0 : b - r0, c0:c1] = part
                    else:
                        out[a - r0 : b - r0, c0:c1] += (part - bg[a:b, c0:c1]) / n
                for name, area in gcov.items():
                    cov[name] = cov.get(name, 0.0) + area / n
            if out is not None and layer is not None:
                out += layer / n if n > 1 else layer
        return out, cov

    def _reaches(self, eye: str, item: _Placed, r0: int, r1: int) -> bool:
        """Whether a placed solid's conservative pixel rectangle meets rows [r0, r1)."""
        half = item[1].half_extent_m()
        rect = self._pixel_rect(eye, item[2] - half, item[2] + half, 2)
        return rect is not None and rect[0] < r1 and rect[1] > r0

    @staticmethod
    def _bounds(placed: list[_Placed]) -> list[Bound]:
        """Bounding sphere (centre, radius) of each object's solids (for shadow culling)."""
        boxes: dict[str, tuple[F64, F64]] = {}
        for name, solid, c in placed:
            h = solid.half_extent_m()
            lo, hi = boxes.get(name, (c - h, c + h))
            boxes[name] = (np.minimum(lo, c - h), np.maximum(hi, c + h))
        return [
            (0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))) for lo, hi in boxes.values()
        ]

    # -- images -------------------------------------------------------------------------------

    def render_radiance(self, eye: str, t_ns: int) -> F32:
        """Scene radiance (H, W, 3) float32 BGR: pixel-area and exposure average, no photometry."""
        img, _ = self._render(eye, t_ns, want_image=True)
        assert img is not None
        return img

    def gain(self, eye: str, t_ns: int) -> float:
        """Total photometric gain (per-eye gain times drift) averaged over the exposure."""
        times = self._exposure_times_s(self.time_s(t_ns))
        return float(np.mean([self.photometry.gain(eye, float(t)) for t in times]))

    def render(self, eye: str, t_ns: int) -> U8:
        """Final uint8 BGR image of an eye captured at ``t_ns`` (noise seeded by seed/eye/t)."""
        img = self.render_radiance(eye, t_ns)
        tr = self.transport
        if tr.flicker_depth > 0.0:
            rows = tr.row_starts_s(self.time_s(t_ns), self.rig.height_px)
            img *= tr.flicker(rows, self.exposure_s).astype(np.float32)[:, None, None]
        img *= np.float32(self.gain(eye, t_ns))
        sigma = self.photometry.noise_sigma
        if sigma > 0.0:
            rng = np.random.default_rng([self.seed, _eye_index(eye), int(t_ns)])
            noise = rng.standard_normal(img.shape, dtype=np.float32)
            noise *= np.float32(sigma)
            img += noise
        img += np.float32(0.5)
        np.clip(img, 0.0, 255.0, out=img)
        return tr.encode(img.astype(np.uint8))

    def frames(self) -> Iterator[RenderedFrame]:
        """All frames of both eyes in capture-time order (ties: left first)."""
        sched = [
            (t, i, seq) for i, eye in enumerate(EYES) for seq, t in enumerate(self.frame_times(eye))
        ]
        sched.sort()
        for t, i, seq in sched:
            yield RenderedFrame(EYES[i], self.render(EYES[i], t), t, seq)

    # -- serialisation ------------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        objs = []
        for o in self.objects:
            od = {"kind": type(o).__name__, **asdict(o)}
            if not isinstance(o, Person) and isinstance(o.trajectory, Waypoints):
                od["trajectory"] = {"kind": type(o.trajectory).__name__, **od["trajectory"]}
            objs.append(od)
        d["objects"] = objs
        return dict(_jsonable(d))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scene:
        objs: list[SceneObject] = []
        for od in d.get("objects", []):
            od = dict(od)
            if od.get("kind") == "Person":
                objs.append(Person.from_dict(od))
                continue
            kind = _SHAPES[od.pop("kind")]
            od["trajectory"] = motion_from_dict(od["trajectory"])
            objs.append(_build(kind, od))
        return cls(
            rig=_build(Rig, d["rig"]),
            left_clock=_build(Clock, d["left_clock"]),
            right_clock=_build(Clock, d["right_clock"]),
            objects=tuple(objs),
            lighting=_build(Lighting, d["lighting"]),
            photometry=_build(Photometry, d["photometry"]),
            room=_build(Room, d["room"]),
            quality=_build(Quality, d["quality"]),
            seed=int(d["seed"]),
            t0_ns=int(d["t0_ns"]),
            duration_s=float(d["duration_s"]),
            exposure_s=float(d["exposure_s"]),
            name=str(d.get("name", "scene")),
            lamps=Lamps.from_dict(d["lamps"]) if d.get("lamps") else None,
            transport=_build(Transport, d.get("transport", {})),
        )
