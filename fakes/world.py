"""Independent, physically based stereo scene renderer (ground truth for stereo trackers).

Everything here is derived from first principles (pinhole optics, ray casting, box-filtered
pixels); it deliberately shares no code with the program under test.  Only the standard
library, numpy and OpenCV are used.

Frames and units
----------------
* Rig (world) frame: origin midway between the two camera centres, +X right (as the cameras
  look), +Y down, +Z forward along both optical axes.  Metres, seconds, BGR colours 0..255.
* Scene time ``t_s`` is seconds since ``Scene.t0_ns``: ``t_ns = t0_ns + round(t_s * 1e9)``.
  All trajectory, clock and photometry times are scene times.

Cameras and pixel convention
----------------------------
Two identical ideal pinholes, optical axes parallel to +Z, centres ``(-B/2, 0, 0)`` (left) and
``(+B/2, 0, 0)`` (right).  We use the OpenCV convention: the integer pixel coordinate ``(u, v)``
(column, row) is the *centre* of pixel ``[v, u]``, which covers the square
``[u - 1/2, u + 1/2] x [v - 1/2, v + 1/2]``.  The image therefore spans
``u in [-1/2, W - 1/2]`` and the principal point (exact geometric centre) is
``cx = (W - 1) / 2``, ``cy = (H - 1) / 2``.  ``hfov`` spans the full width W, so
``f = (W / 2) / tan(hfov / 2)`` pixels (square pixels: fy = fx = f).  A point (X, Y, Z)
projects to ``u = cx + f (X - Cx) / Z``, ``v = cy + f Y / Z`` with ``Cx = -/+ B/2``; the
disparity of a point at depth Z is ``u_left - u_right = f B / Z``.

A pixel's value is the mean radiance over its square footprint (box filter), estimated by ray
casting (every ray meets the exact geometry; the nearest hit wins):
* static background (wall, floor): cast once per eye on a regular B x B grid per pixel
  (``Quality.background_supersample``);
* per frame, only a conservative rectangle around each object (projected bounding box, merged
  when they overlap) is re-cast, first on an (S+1) x (S+1) grid per pixel that includes the
  pixel borders (``Quality.supersample`` = S).  A pixel whose grid sees a single object is the
  trapezoid-rule mean of its shading; one whose grid sees only background keeps the static
  background value; a pixel whose grid sees more than one surface (silhouette or occlusion
  edge) is re-cast with an E x E sheared, n-rooks-stratified grid (``edge_supersample``) and
  its 8 neighbours, which could hide slivers < 1/(2 S^2) px, with ``ring_supersample``^2 rays.
This rule only depends on the pixel, so the result is bit-identical to casting every pixel.
With the defaults the silhouette centroid of a sphere / box / cylinder matches the exact
projected silhouette to ~0.01 px (for objects under ~2 px radius the centroid of *any* pixel
image deviates by a few 0.01 px from the continuous one).  Rays hitting objects at depth
< 1 cm are ignored (near clip).

Clocks, timestamps and exposure
-------------------------------
Each eye free-runs: frame k is captured at ``phase + k * period (+ jitter_k)``; only captures
in ``[0, duration)`` are emitted and ``seq`` counts emitted frames per eye from 0.  ``t_ns``
(integer ns, monotonic) is the instant the exposure *starts*.  With ``exposure_s > 0`` the pixel
is the time average of the scene over ``[t, t + exposure]`` (midpoint rule with N temporal
samples; by default enough that objects move < 0.5 px per sample, 2..64), so a blurred object
is centred near its position at ``t + exposure / 2``; the photometric gain is averaged over the
same samples.  Truth is reported at the exact instant asked for.  The skew of the right eye is
``(t_right - nearest t_left) / period_left`` in frames (positive: right captures later).

Scene content
-------------
A textured vertical wall (plane Z = wall distance) and a textured floor (plane Y = floor
height), unlit, with seeded procedural colour textures defined in world coordinates (bilinear
over a ``Room.texel_m`` grid: multi-octave value noise, palette blends, posters, floor tiles),
so the parallax between the eyes is exact.
Objects (spheres, upright cylinders, axis-aligned boxes; centre = centre of the volume) are
Lambertian under one directional light plus ambient; they translate without rotating and cast
no shadows.  Photometry: ``image = clip(round(radiance * eye_gain * drift(t) + noise))`` with
Gaussian noise seeded by (seed, eye, t_ns), so any frame can be re-rendered identically.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Literal, TextIO

import cv2
import numpy as np
import numpy.typing as npt

__all__ = [
    "EYES",
    "PRESETS",
    "Box",
    "Clock",
    "Cylinder",
    "Lighting",
    "MODE_320x240_30",
    "MODE_640x480_15",
    "Photometry",
    "Quality",
    "RenderedFrame",
    "Rig",
    "Room",
    "Scene",
    "Shape",
    "Sphere",
    "Trajectory",
    "clocks_for_skew",
    "crossing",
    "fast_ball",
    "load_scene",
    "robot_ball",
    "robot_box",
    "robot_cylinder",
    "write_scene",
]

F64 = npt.NDArray[np.float64]
F32 = npt.NDArray[np.float32]
U8 = npt.NDArray[np.uint8]
I32 = npt.NDArray[np.int32]
Vec3 = tuple[float, float, float]
Eye = Literal["left", "right"]
EYES: tuple[Eye, Eye] = ("left", "right")
Mode = tuple[int, int, float]
MODE_320x240_30: Mode = (320, 240, 30.0)
MODE_640x480_15: Mode = (640, 480, 15.0)
Skew = float | Literal["wander"]
Rect = tuple[int, int, int, int]  # row0, row1, col0, col1 (end exclusive)

_NEAR_M = 0.01
_ZERO3: Vec3 = (0.0, 0.0, 0.0)


def _eye_index(eye: str) -> int:
    if eye == "left":
        return 0
    if eye == "right":
        return 1
    raise ValueError(f"eye must be 'left' or 'right', not {eye!r}")


# --------------------------------------------------------------------------------------------
# Rig, clocks, motion
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Rig:
    """Two identical parallel pinhole cameras (see module docstring for conventions)."""

    width_px: int = 320
    height_px: int = 240
    hfov_deg: float = 60.0
    baseline_m: float = 0.060

    def __post_init__(self) -> None:
        if self.width_px < 2 or self.height_px < 2:
            raise ValueError("image must be at least 2x2")
        if not 0.0 < self.hfov_deg < 179.0:
            raise ValueError("hfov_deg out of range")

    @property
    def focal_px(self) -> float:
        return 0.5 * self.width_px / math.tan(math.radians(self.hfov_deg) / 2.0)

    @property
    def cx(self) -> float:
        return (self.width_px - 1) / 2.0

    @property
    def cy(self) -> float:
        return (self.height_px - 1) / 2.0

    @property
    def vfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(0.5 * self.height_px / self.focal_px))

    def camera_centre(self, eye: str) -> F64:
        x = -0.5 * self.baseline_m if _eye_index(eye) == 0 else 0.5 * self.baseline_m
        return np.array([x, 0.0, 0.0])

    def intrinsics(self) -> F64:
        f = self.focal_px
        return np.array([[f, 0.0, self.cx], [0.0, f, self.cy], [0.0, 0.0, 1.0]])

    def project(self, eye: str, points: npt.ArrayLike) -> F64:
        """Pixel coordinates (..., 2) = (u, v) of rig-frame points (..., 3)."""
        p = np.asarray(points, dtype=np.float64)
        c = self.camera_centre(eye)
        f = self.focal_px
        z = p[..., 2]
        return np.stack(
            [self.cx + f * (p[..., 0] - c[0]) / z, self.cy + f * (p[..., 1] - c[1]) / z], axis=-1
        )

    def disparity_px(self, depth_m: float) -> float:
        return self.focal_px * self.baseline_m / depth_m


@dataclass(frozen=True)
class Clock:
    """Free-running frame clock of one eye: capture k at ``phase + k * period + jitter_k``."""

    period_s: float = 1.0 / 30.0
    phase_s: float = 0.0
    jitter_s: float = 0.0  # std-dev of Gaussian jitter, clipped to +-period/4

    def capture_times_s(self, duration_s: float, rng: np.random.Generator | None = None) -> F64:
        n = max(0, math.ceil((duration_s - self.phase_s) / self.period_s) + 2)
        t = self.phase_s + np.arange(n) * self.period_s
        if self.jitter_s > 0.0:
            gen = rng if rng is not None else np.random.default_rng(0)
            j = gen.normal(0.0, self.jitter_s, size=n)
            t = t + np.clip(j, -0.25 * self.period_s, 0.25 * self.period_s)
        return np.asarray(t[(t >= 0.0) & (t < duration_s)], dtype=np.float64)


def clocks_for_skew(
    fps: float,
    skew_start: float,
    skew_end: float | None = None,
    duration_s: float = 5.0,
    jitter_s: float = 0.0,
) -> tuple[Clock, Clock]:
    """(left, right) clocks whose skew drifts linearly from ``skew_start`` to ``skew_end``.

    Skew is in frames of the left clock, within [-1/2, +1/2]: the right frame captured at
    scene time t is ``s(t) = skew_start + (skew_end - skew_start) * t / duration_s`` left
    periods after the nearest left frame.  The left clock has phase 0; solving for the right
    clock gives ``period_r = P / (1 - (skew_end - skew_start) * P / duration_s)`` and
    ``phase_r = (skew_start (+1 if negative)) * period_r``.  Because s is evaluated at the
    capture instants, a wander from -1/2 to +1/2 never lands exactly on the +-1/2 tie.
    """
    end = skew_start if skew_end is None else skew_end
    for s in (skew_start, end):
        if not -0.5 <= s <= 0.5:
            raise ValueError("skew must lie in [-0.5, 0.5] frames")
    period = 1.0 / fps
    right_period = period / (1.0 - (end - skew_start) * period / duration_s)
    phase = (skew_start + (1.0 if skew_start < 0.0 else 0.0)) * right_period
    return Clock(period, 0.0, jitter_s), Clock(right_period, phase, jitter_s)


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


# --------------------------------------------------------------------------------------------
# Solids
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class _Solid:
    """Common fields: a name, a trajectory of the volume centre, colour and an optional band.

    The band (``stripe_bgr``) covers the points whose local y (relative to the centre) is
    within ``stripe_half_width_m`` of ``stripe_offset_m`` (a horizontal band).
    """

    name: str
    trajectory: Trajectory
    colour_bgr: Vec3 = (40.0, 120.0, 230.0)
    stripe_bgr: Vec3 | None = None
    stripe_half_width_m: float = 0.0
    stripe_offset_m: float = 0.0

    def half_extent_m(self) -> F64:
        raise NotImplementedError

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        """Ray depth s (= Z travelled) of the first hit of rays ``c + s (dx, dy, 1)``.

        ``o`` = camera centre minus object centre.  Returns inf where missed.
        """
        raise NotImplementedError

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        """Outward unit normals at surface points q (relative to the centre)."""
        raise NotImplementedError


@dataclass(frozen=True, kw_only=True)
class Sphere(_Solid):
    radius_m: float

    def half_extent_m(self) -> F64:
        return np.full(3, self.radius_m)

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        ox, oy, oz = (float(x) for x in o)
        r = self.radius_m
        a = dx * dx + dy * dy + 1.0
        b = ox * dx + oy * dy + oz
        c = ox * ox + oy * oy + oz * oz - r * r
        disc = b * b - a * c
        s = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        return np.where((disc >= 0.0) & (s > _NEAR_M), s, np.inf)

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        n = np.sqrt(qx * qx + qy * qy + qz * qz)
        return qx / n, qy / n, qz / n


@dataclass(frozen=True, kw_only=True)
class Cylinder(_Solid):
    """Upright cylinder (axis parallel to Y), like a small round robot."""

    radius_m: float
    height_m: float

    def half_extent_m(self) -> F64:
        return np.array([self.radius_m, 0.5 * self.height_m, self.radius_m])

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        ox, oy, oz = (float(x) for x in o)
        r, h = self.radius_m, 0.5 * self.height_m
        a = dx * dx + 1.0
        b = ox * dx + oz
        c = ox * ox + oz * oz - r * r
        disc = b * b - a * c
        s_side = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        y = oy + s_side * dy
        ok = (disc >= 0.0) & (s_side > _NEAR_M) & (np.abs(y) <= h)
        s = np.where(ok, s_side, np.inf)
        if abs(oy) > h:  # the camera sees one cap
            yc = -h if oy < -h else h
            with np.errstate(divide="ignore", invalid="ignore"):
                s_cap = (yc - oy) / dy
                xc = ox + s_cap * dx
                zc = oz + s_cap
                cap = np.isfinite(s_cap) & (s_cap > _NEAR_M) & (xc * xc + zc * zc <= r * r)
            s = np.where(cap & (s_cap < s), s_cap, s)
        return np.broadcast_to(s, np.broadcast_shapes(np.shape(dx), np.shape(dy)))

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        rho = np.sqrt(qx * qx + qz * qz)
        side = np.abs(rho - self.radius_m) < np.abs(np.abs(qy) - 0.5 * self.height_m)
        safe = np.where(rho > 0.0, rho, 1.0)
        nx = np.where(side, qx / safe, 0.0)
        ny = np.where(side, 0.0, np.sign(qy))
        nz = np.where(side, qz / safe, 0.0)
        return nx, ny, nz


@dataclass(frozen=True, kw_only=True)
class Box(_Solid):
    """Axis-aligned box with half sizes (hx, hy, hz)."""

    half_size_m: Vec3

    def half_extent_m(self) -> F64:
        return np.asarray(self.half_size_m, dtype=np.float64)

    def intersect(self, o: F64, dx: F64, dy: F64) -> F64:
        hx, hy, hz = (float(x) for x in self.half_size_m)
        ox, oy, oz = (float(x) for x in o)
        with np.errstate(divide="ignore", invalid="ignore"):
            ix = 1.0 / dx
            iy = 1.0 / dy
            ax, bx = (-hx - ox) * ix, (hx - ox) * ix
            ay, by = (-hy - oy) * iy, (hy - oy) * iy
            az, bz = -hz - oz, hz - oz
            t_in = np.maximum(np.maximum(np.minimum(ax, bx), np.minimum(ay, by)), min(az, bz))
            t_out = np.minimum(np.minimum(np.maximum(ax, bx), np.maximum(ay, by)), max(az, bz))
            hit = (t_in <= t_out) & (t_in > _NEAR_M)
        return np.where(hit, t_in, np.inf)

    def normals(self, qx: F64, qy: F64, qz: F64) -> tuple[F64, F64, F64]:
        h = self.half_extent_m()
        rel = np.stack([np.abs(qx) / h[0], np.abs(qy) / h[1], np.abs(qz) / h[2]])
        axis = np.argmax(rel, axis=0)
        return tuple(  # type: ignore[return-value]
            np.where(axis == i, np.sign(q), 0.0) for i, q in enumerate((qx, qy, qz))
        )


Shape = Sphere | Cylinder | Box
_SHAPES: dict[str, type[Sphere] | type[Cylinder] | type[Box]] = {
    "Sphere": Sphere,
    "Cylinder": Cylinder,
    "Box": Box,
}


# --------------------------------------------------------------------------------------------
# Light, photometry, room, quality
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Lighting:
    """Lambert: radiance = colour * (ambient + diffuse * max(0, n . l)), l = towards the light."""

    towards_light: Vec3 = (-0.3, -1.0, -0.5)  # up (-Y), a bit left and towards the cameras
    ambient: float = 0.35
    diffuse: float = 0.75

    def unit(self) -> F64:
        v = np.asarray(self.towards_light, dtype=np.float64)
        return v / np.linalg.norm(v)


@dataclass(frozen=True)
class Photometry:
    """Per-eye gain, global drift ``1 + a sin(2 pi t / T + phi)`` and Gaussian noise."""

    left_gain: float = 1.0
    right_gain: float = 1.03
    drift_amplitude: float = 0.10
    drift_period_s: float = 6.0
    drift_phase_rad: float = 0.0
    noise_sigma: float = 3.0

    def gain(self, eye: str, t_s: float) -> float:
        g = self.left_gain if _eye_index(eye) == 0 else self.right_gain
        if self.drift_amplitude == 0.0:
            return g
        w = 2.0 * math.pi * t_s / self.drift_period_s + self.drift_phase_rad
        return g * (1.0 + self.drift_amplitude * math.sin(w))


@dataclass(frozen=True)
class Room:
    """Back wall at Z = ``wall_distance_m``, floor plane Y = ``floor_height_m`` (None: none)."""

    wall_distance_m: float = 4.0
    floor_height_m: float | None = 0.35
    texture: Literal["noise", "flat"] = "noise"
    flat_wall_bgr: Vec3 = (128.0, 128.0, 128.0)
    flat_floor_bgr: Vec3 = (96.0, 96.0, 96.0)
    texel_m: float = 0.004


@dataclass(frozen=True)
class Quality:
    supersample: int = 4  # S x S rays per pixel in object regions
    edge_supersample: int = 16  # E x E rays per pixel cut by a silhouette / occlusion edge
    ring_supersample: int = 8  # rays per pixel (squared) for the neighbours of those pixels
    background_supersample: int = 4  # rays per pixel for the static background
    exposure_samples: int = 0  # temporal samples when exposure > 0 (0: automatic)


@dataclass(frozen=True, eq=False)
class RenderedFrame:
    eye: str
    image: U8
    t_ns: int
    seq: int


# --------------------------------------------------------------------------------------------
# Procedural textures
# --------------------------------------------------------------------------------------------


@dataclass
class _Textures:
    atlas: F32  # wall rows [0, wall_rows), floor rows [floor_row0, ...)
    texel: float
    wall_x0: float
    wall_y0: float
    wall_shape: tuple[int, int]
    floor_x0: float
    floor_z0: float
    floor_row0: int
    floor_shape: tuple[int, int]


def _value_noise(rng: np.random.Generator, ny: int, nx: int, cell: float, ch: int = 1) -> F32:
    """Smooth value noise in about [-1, 1], lattice spacing ``cell`` texels, shape (ny, nx, ch)."""
    cell = max(cell, 1.0)
    gy, gx = math.ceil(ny / cell) + 3, math.ceil(nx / cell) + 3
    lattice = rng.uniform(-1.0, 1.0, size=(gy, gx, ch)).astype(np.float32)
    size = (max(nx + 1, round(gx * cell)), max(ny + 1, round(gy * cell)))
    big = cv2.resize(lattice, size, interpolation=cv2.INTER_CUBIC)
    big = big.reshape(size[1], size[0], ch)
    oy = int(rng.integers(0, max(1, size[1] - ny)))
    ox = int(rng.integers(0, max(1, size[0] - nx)))
    return np.ascontiguousarray(big[oy : oy + ny, ox : ox + nx])


def _fbm(
    rng: np.random.Generator, ny: int, nx: int, texel: float, octaves: Sequence[tuple[float, float]]
) -> F32:
    out = np.zeros((ny, nx, 1), np.float32)
    for wavelength_m, amp in octaves:
        out += amp * _value_noise(rng, ny, nx, wavelength_m / texel)
    return out


def _palette_mix(rng: np.random.Generator, ny: int, nx: int, cell: float, palette: F32) -> F32:
    w = np.exp(4.0 * _value_noise(rng, ny, nx, cell, palette.shape[0]))
    w /= w.sum(axis=2, keepdims=True)
    return np.asarray(w @ palette, dtype=np.float32)


def _wall_texture(
    rng: np.random.Generator, ny: int, nx: int, texel: float, x0: float, y0: float, floor_y: float
) -> F32:
    palette = np.array(
        [
            [95, 140, 185],  # warm beige / orange-ish
            [150, 150, 140],  # grey
            [70, 90, 150],  # terracotta
            [170, 185, 200],  # light cream
            [60, 75, 95],  # dark brown
            [150, 110, 80],  # blue-grey
        ],
        np.float32,
    )
    tex = _palette_mix(rng, ny, nx, 1.2 / texel, palette)
    lum = 1.0 + _fbm(rng, ny, nx, texel, [(0.35, 0.22), (0.09, 0.14), (0.025, 0.08), (0.01, 0.05)])
    tint = 1.0 + 0.06 * _value_noise(rng, ny, nx, 0.15 / texel, 3)
    tex = tex * lum * tint
    # Posters / doors: sharp-edged uniform-ish rectangles, some close to object colours.
    xs = x0 + (np.arange(nx) + 0.5) * texel
    ys = y0 + (np.arange(ny) + 0.5) * texel
    x_lo, x_hi = xs[0] + 0.3, xs[-1] - 0.3
    y_lo, y_hi = ys[0] + 0.3, min(ys[-1], floor_y) - 0.15
    extras = np.array([[40, 120, 230], [150, 90, 40], [60, 160, 60], [200, 200, 200]], np.float32)
    colours = np.concatenate([palette, extras])
    for _ in range(8):
        cxp, cyp = rng.uniform(x_lo, x_hi), rng.uniform(y_lo, max(y_lo, y_hi))
        hw, hh = rng.uniform(0.1, 0.4), rng.uniform(0.1, 0.45)
        col = colours[rng.integers(0, len(colours))] * rng.uniform(0.7, 1.15)
        c0, c1 = np.searchsorted(xs, [cxp - hw, cxp + hw])
        r0, r1 = np.searchsorted(ys, [cyp - hh, cyp + hh])
        if c1 > c0 and r1 > r0:
            patch = lum[r0:r1, c0:c1] * 0.3 + 0.7
            tex[r0:r1, c0:c1] = col * patch
    return np.clip(tex, 8.0, 240.0).astype(np.float32)


def _floor_texture(
    rng: np.random.Generator, nz: int, nx: int, texel: float, x0: float, z0: float
) -> F32:
    palette = np.array(
        [[60, 100, 140], [120, 120, 115], [90, 110, 125], [150, 160, 170]], np.float32
    )
    tex = _palette_mix(rng, nz, nx, 1.5 / texel, palette)
    lum = 1.0 + _fbm(rng, nz, nx, texel, [(0.2, 0.15), (0.05, 0.1), (0.012, 0.07)])
    tile, grout = 0.30, 0.006
    xs = x0 + (np.arange(nx) + 0.5) * texel
    zs = z0 + (np.arange(nz) + 0.5) * texel
    ix = np.floor(xs / tile).astype(np.int64)
    iz = np.floor(zs / tile).astype(np.int64)
    tones = rng.uniform(0.82, 1.15, size=(iz.max() - iz.min() + 1, ix.max() - ix.min() + 1))
    tone = tones[(iz - iz.min())[:, None], (ix - ix.min())[None, :]].astype(np.float32)
    tex = tex * lum * tone[:, :, None]
    gmask = (np.mod(zs, tile) < grout)[:, None] | (np.mod(xs, tile) < grout)[None, :]
    tex[gmask] = np.array([45, 50, 55], np.float32)
    return np.clip(tex, 8.0, 240.0).astype(np.float32)


def _make_textures(rig: Rig, room: Room, seed: int) -> _Textures:
    rng = np.random.default_rng([seed, 7001])
    tau = room.texel_m
    f = rig.focal_px
    tx, ty = 0.5 * rig.width_px / f, 0.5 * rig.height_px / f
    zw = room.wall_distance_m
    margin = 0.25
    half_x = 0.5 * rig.baseline_m + zw * tx + margin
    wall_y0 = -zw * ty - margin
    floor_y = room.floor_height_m
    wall_y1 = (floor_y if floor_y is not None else zw * ty) + margin
    wnx, wny = math.ceil(2 * half_x / tau), math.ceil((wall_y1 - wall_y0) / tau)
    wall = _wall_texture(rng, wny, wnx, tau, -half_x, wall_y0, floor_y if floor_y else 1e9)
    if floor_y is not None:
        z0 = max(0.0, floor_y / ty - margin)
        fnz, fnx = math.ceil((zw + margin - z0) / tau), wnx
        floor = _floor_texture(rng, fnz, fnx, tau, -half_x, z0)
    else:
        z0, fnz, fnx = 0.0, 1, 1
        floor = np.zeros((1, 1, 3), np.float32)
    row0 = wny + 4
    atlas = np.zeros((row0 + fnz, max(wnx, fnx), 3), np.float32)
    atlas[:wny, :wnx] = wall
    atlas[row0:, :fnx] = floor
    return _Textures(atlas, tau, -half_x, wall_y0, (wny, wnx), -half_x, z0, row0, (fnz, fnx))


def _remap(atlas: F32, mx: F32, my: F32) -> F32:
    """Bilinear lookup of ``atlas`` at float texel coordinates (any shape, any size)."""
    n = mx.size
    cols = min(max(n, 1), 1024)
    rows = -(-n // cols)
    px = np.zeros(rows * cols, np.float32)
    py = np.zeros(rows * cols, np.float32)
    px[:n] = mx.ravel()
    py[:n] = my.ravel()
    out = cv2.remap(
        atlas,
        px.reshape(rows, cols),
        py.reshape(rows, cols),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return np.asarray(out.reshape(-1, 3)[:n].reshape((*mx.shape, 3)), dtype=np.float32)


def _bilinear(img: F32, mx: F64, my: F64) -> F64:
    """Exact float64 bilinear interpolation with edge clamping (reference lookups)."""
    h, w = img.shape[:2]
    x = np.clip(mx, 0.0, w - 1.0)
    y = np.clip(my, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2 if h > 1 else 0)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    im = img.astype(np.float64)
    top = im[y0, x0] * (1 - fx) + im[y0, x1] * fx
    bot = im[y1, x0] * (1 - fx) + im[y1, x1] * fx
    return np.asarray(top * (1 - fy) + bot * fy)


# --------------------------------------------------------------------------------------------
# Scene
# --------------------------------------------------------------------------------------------

_Placed = tuple[int, Shape, F64]  # (object index, solid, centre)


@dataclass(frozen=True)
class Scene:
    """Everything needed to render a stereo sequence and its ground truth."""

    rig: Rig = field(default_factory=Rig)
    left_clock: Clock = field(default_factory=Clock)
    right_clock: Clock = field(default_factory=Clock)
    objects: tuple[Shape, ...] = ()
    lighting: Lighting = field(default_factory=Lighting)
    photometry: Photometry = field(default_factory=Photometry)
    room: Room = field(default_factory=Room)
    quality: Quality = field(default_factory=Quality)
    seed: int = 0
    t0_ns: int = 1_000_000_000_000
    duration_s: float = 5.0
    exposure_s: float = 0.0
    name: str = "scene"

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
        return {o.name: o.trajectory.state(t) for o in self.objects if o.trajectory.present(t)}

    def object(self, name: str) -> Shape:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    def coverage(self, eye: str, t_ns: int) -> dict[str, float]:
        """Visible (unoccluded, in-image) area in px of each present object, exposure-averaged."""
        _, cov = self._render(eye, t_ns, want_image=False)
        t = self.time_s(t_ns)
        present = [
            o.name
            for o in self.objects
            if any(o.trajectory.present(ti) for ti in self._exposure_times_s(t))
        ]
        return {n: cov.get(n, 0.0) for n in present}

    def visible(self, name: str, eye: str, t_ns: int) -> bool:
        """True when some of the object is in this eye's image and not fully occluded."""
        self.object(name)
        return self.coverage(eye, t_ns).get(name, 0.0) > 0.0

    # -- background ---------------------------------------------------------------------------

    @cached_property
    def _textures(self) -> _Textures:
        return _make_textures(self.rig, self.room, self.seed)

    @cached_property
    def _bg_cache(self) -> dict[str, F32]:
        return {}

    def _background(self, eye: str, dx: F64, dy: F64) -> F32:
        """Radiance of the wall / floor along rays (dx, dy, 1) from the eye's centre."""
        room = self.room
        cam_x = float(self.rig.camera_centre(eye)[0])
        zw = room.wall_distance_m
        shape = np.broadcast_shapes(np.shape(dx), np.shape(dy))
        dxb, dyb = np.broadcast_to(dx, shape), np.broadcast_to(dy, shape)
        if room.floor_height_m is not None:
            yf = room.floor_height_m
            on_floor = dyb * zw > yf
            s = np.where(on_floor, yf / np.where(on_floor, dyb, 1.0), zw)
        else:
            on_floor = np.zeros(shape, bool)
            s = np.full(shape, zw)
        if room.texture == "flat":
            wall = np.asarray(room.flat_wall_bgr, np.float32)
            flo = np.asarray(room.flat_floor_bgr, np.float32)
            return np.where(on_floor[..., None], flo, wall).astype(np.float32)
        tex = self._textures
        tau = tex.texel
        x = cam_x + s * dxb
        wy, wx = tex.wall_shape
        fz, fx = tex.floor_shape
        mx_w = np.clip((x - tex.wall_x0) / tau - 0.5, 0.0, wx - 1.0)
        my_w = np.clip((zw * dyb - tex.wall_y0) / tau - 0.5, 0.0, wy - 1.0)
        mx_f = np.clip((x - tex.floor_x0) / tau - 0.5, 0.0, fx - 1.0)
        my_f = tex.floor_row0 + np.clip((s - tex.floor_z0) / tau - 0.5, 0.0, fz - 1.0)
        mx = np.where(on_floor, mx_f, mx_w).astype(np.float32)
        my = np.where(on_floor, my_f, my_w).astype(np.float32)
        return _remap(tex.atlas, mx, my)

    def _background_image(self, eye: str) -> F32:
        cache = self._bg_cache
        if eye not in cache:
            rig = self.rig
            s = self.quality.background_supersample
            f = rig.focal_px
            w, h = rig.width_px, rig.height_px
            offs = (np.arange(s) + 0.5) / s - 0.5
            dx = ((np.arange(w)[:, None] + offs[None, :]).ravel() - rig.cx) / f
            out = np.empty((h, w, 3), np.float32)
            step = max(1, (1 << 19) // (w * s * s))
            for r0 in range(0, h, step):
                r1 = min(h, r0 + step)
                v = (np.arange(r0, r1)[:, None] + offs[None, :]).ravel()
                samp = self._background(eye, dx[None, :], ((v - rig.cy) / f)[:, None])
                out[r0:r1] = samp.reshape(r1 - r0, s, w, s, 3).mean(axis=(1, 3))
            cache[eye] = out
        return cache[eye]

    def background_radiance(self, eye: str) -> F32:
        """Static background radiance image of an eye (before photometry), float32 BGR."""
        return self._background_image(EYES[_eye_index(eye)]).copy()

    def wall_radiance(self, x: npt.ArrayLike, y: npt.ArrayLike) -> F64:
        """Wall texture (BGR radiance) at world points (x, y, wall distance)."""
        xa, ya = np.asarray(x, np.float64), np.asarray(y, np.float64)
        if self.room.texture == "flat":
            return np.broadcast_to(np.asarray(self.room.flat_wall_bgr, np.float64), (*xa.shape, 3))
        t = self._textures
        wall = t.atlas[: t.wall_shape[0], : t.wall_shape[1]]
        return _bilinear(wall, (xa - t.wall_x0) / t.texel - 0.5, (ya - t.wall_y0) / t.texel - 0.5)

    def floor_radiance(self, x: npt.ArrayLike, z: npt.ArrayLike) -> F64:
        """Floor texture (BGR radiance) at world points (x, floor height, z)."""
        xa, za = np.asarray(x, np.float64), np.asarray(z, np.float64)
        if self.room.texture == "flat":
            return np.broadcast_to(np.asarray(self.room.flat_floor_bgr, np.float64), (*xa.shape, 3))
        t = self._textures
        fl = t.atlas[t.floor_row0 : t.floor_row0 + t.floor_shape[0], : t.floor_shape[1]]
        return _bilinear(fl, (xa - t.floor_x0) / t.texel - 0.5, (za - t.floor_z0) / t.texel - 0.5)

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
            tr = o.trajectory
            if not (tr.present(t_s) or tr.present(t_s + e)):
                continue
            p0, p1 = tr.position(t_s), tr.position(t_s + e)
            if min(p0[2], p1[2]) < 0.05:
                disp = math.inf
                break
            for eye in EYES:
                uv = self.rig.project(eye, np.stack([p0, p1]))
                disp = max(disp, float(np.abs(uv[1] - uv[0]).max()))
            grow = self.rig.focal_px * float(o.half_extent_m().max())
            disp = max(disp, grow * abs(1.0 / p0[2] - 1.0 / p1[2]))
        return int(np.clip(math.ceil(disp / 0.5), 2, 64)) if math.isfinite(disp) else 64

    def _placed(self, t_s: float) -> list[_Placed]:
        return [
            (i, o, o.trajectory.position(t_s))
            for i, o in enumerate(self.objects)
            if o.trajectory.present(t_s)
        ]

    def _pixel_rect(self, eye: str, lo: F64, hi: F64, margin: int) -> Rect | None:
        """Conservative pixel rectangle of the box [lo, hi] (clipped to Z >= near) or None."""
        if hi[2] <= _NEAR_M:
            return None
        rig = self.rig
        z_lo = max(float(lo[2]), _NEAR_M)
        cam_x = float(rig.camera_centre(eye)[0])
        f = rig.focal_px
        us, vs = [], []
        for z in (z_lo, float(hi[2])):
            for x in (float(lo[0]), float(hi[0])):
                us.append(rig.cx + f * (x - cam_x) / z)
            for y in (float(lo[1]), float(hi[1])):
                vs.append(rig.cy + f * y / z)
        c0 = max(0, math.floor(min(us) + 0.5) - margin)
        c1 = min(rig.width_px, math.floor(max(us) + 0.5) + 1 + margin)
        r0 = max(0, math.floor(min(vs) + 0.5) - margin)
        r1 = min(rig.height_px, math.floor(max(vs) + 0.5) + 1 + margin)
        if c0 >= c1 or r0 >= r1:
            return None
        return (r0, r1, c0, c1)

    def _groups(self, eye: str, placed: list[_Placed]) -> list[tuple[Rect, list[_Placed]]]:
        groups: list[tuple[Rect, list[_Placed]]] = []
        for item in placed:
            half = item[1].half_extent_m()
            rect = self._pixel_rect(eye, item[2] - half, item[2] + half, 2)
            if rect is not None:
                groups.append((rect, [item]))
        merged = True
        while merged:
            merged = False
            for i in range(len(groups)):
                for j in range(i + 1, len(groups)):
                    a, b = groups[i][0], groups[j][0]
                    if a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]:
                        rect = (min(a[0], b[0]), max(a[1], b[1]), min(a[2], b[2]), max(a[3], b[3]))
                        groups[i] = (rect, groups[i][1] + groups[j][1])
                        del groups[j]
                        merged = True
                        break
                if merged:
                    break
        return groups

    def _shade(self, solid: Shape, o: F64, s: F64, dx: F64, dy: F64) -> F32:
        qx, qy, qz = o[0] + s * dx, o[1] + s * dy, o[2] + s
        nx, ny, nz = solid.normals(qx, qy, qz)
        lt = self.lighting
        lv = lt.unit()
        lam = lt.ambient + lt.diffuse * np.maximum(0.0, nx * lv[0] + ny * lv[1] + nz * lv[2])
        col = np.asarray(solid.colour_bgr, np.float64)
        rad = lam[:, None] * col[None, :]
        if solid.stripe_bgr is not None and solid.stripe_half_width_m > 0.0:
            band = np.abs(qy - solid.stripe_offset_m) <= solid.stripe_half_width_m
            stripe = np.asarray(solid.stripe_bgr, np.float64)
            rad[band] = lam[band, None] * stripe[None, :]
        return rad.astype(np.float32)

    def _cast(self, eye: str, group: list[_Placed], dx: F64, dy: F64) -> tuple[I32, F32]:
        """Nearest object hit per ray: (local object id or -1, shaded radiance or 0)."""
        shape = np.broadcast_shapes(dx.shape, dy.shape)
        cam = self.rig.camera_centre(eye)
        best = np.full(shape, np.inf)
        ids = np.full(shape, -1, np.int32)
        for k, (_, solid, centre) in enumerate(group):
            s = solid.intersect(cam - centre, dx, dy)
            closer = s < best
            best = np.where(closer, s, best)
            ids[closer] = k
        rad = np.zeros((*shape, 3), np.float32)
        dxb, dyb = np.broadcast_to(dx, shape), np.broadcast_to(dy, shape)
        for k, (_, solid, centre) in enumerate(group):
            m = ids == k
            if m.any():
                rad[m] = self._shade(solid, cam - centre, best[m], dxb[m], dyb[m])
        return ids, rad

    def _render_group(
        self, eye: str, rect: Rect, group: list[_Placed], want_image: bool
    ) -> tuple[F32 | None, dict[str, float]]:
        rig, q = self.rig, self.quality
        f, s = rig.focal_px, q.supersample
        r0, r1, c0, c1 = rect
        h, w = r1 - r0, c1 - c0
        # Coarse pass: an (S+1) x (S+1) grid per pixel that includes the pixel's borders (shared
        # with the neighbours), so a silhouette edge crossing a pixel always separates samples.
        m, n = np.arange(w * s + 1), np.arange(h * s + 1)
        u = (c0 + m // s - 0.5) + (m % s) / s  # same floats whatever the region origin
        v = (r0 + n // s - 0.5) + (n % s) / s
        ids, rad = self._cast(eye, group, ((u - rig.cx) / f)[None, :], ((v - rig.cy) / f)[:, None])
        cmin = np.minimum.reduce([ids[:, k : k + w * s : s] for k in range(s + 1)])
        cmax = np.maximum.reduce([ids[:, k : k + w * s : s] for k in range(s + 1)])
        idmin = np.minimum.reduce([cmin[k : k + h * s : s] for k in range(s + 1)])
        idmax = np.maximum.reduce([cmax[k : k + h * s : s] for k in range(s + 1)])
        mixed = (idmin != idmax).astype(np.uint8)
        ring = cv2.dilate(mixed, np.ones((3, 3), np.uint8)).astype(bool)
        pure = (idmin == idmax) & (idmin >= 0) & ~ring
        cov: dict[str, float] = {}
        out: F32 | None = None
        if want_image:
            out = self._background_image(eye)[r0:r1, c0:c1].copy()
            ru = 0.5 * (rad[:, :-1] + rad[:, 1:])  # composite trapezoid rule over the pixel
            ruv = 0.5 * (ru[:-1] + ru[1:])
            out[pure] = ruv.reshape(h, s, w, s, 3).mean(axis=(1, 3))[pure]
        for k, (_, solid, _) in enumerate(group):
            cov[solid.name] = float(np.count_nonzero(pure & (idmin == k)))
        # Edge pass on mixed pixels (E x E) and on their 8 neighbours, which can only hide
        # slivers < 1/(2 S^2) px between the coarse samples (ring_supersample^2 rays).
        mixed_b = mixed.astype(bool)
        for sel, rays in ((mixed_b, q.edge_supersample), (ring & ~mixed_b, q.ring_supersample)):
            rr, cc = np.nonzero(sel)
            if rr.size:
                self._refine(eye, group, r0 + rr, c0 + cc, rays, out, rr, cc, cov)
        return out, cov

    def _refine(
        self,
        eye: str,
        group: list[_Placed],
        rows: npt.NDArray[np.intp],
        cols: npt.NDArray[np.intp],
        e: int,
        out: F32 | None,
        rr: npt.NDArray[np.intp],
        cc: npt.NDArray[np.intp],
        cov: dict[str, float],
    ) -> None:
        """Re-cast pixels (rows, cols) with an E x E sheared ("n-rooks") grid, stratified to
        1/E^2 along both axes; write them to out[rr, cc] and add their coverage to cov."""
        rig = self.rig
        f = rig.focal_px
        i, j = np.meshgrid(np.arange(e), np.arange(e), indexing="ij")
        ox = ((i + (j + 0.5) / e) / e - 0.5).ravel()
        oy = ((j + (i + 0.5) / e) / e - 0.5).ravel()
        dx = (cols[:, None] + ox[None, :] - rig.cx) / f
        dy = (rows[:, None] + oy[None, :] - rig.cy) / f
        ids, rad = self._cast(eye, group, dx, dy)
        for k, (_, solid, _) in enumerate(group):
            cov[solid.name] += float(np.count_nonzero(ids == k)) / (e * e)
        if out is not None:
            miss = ids < 0
            rad[miss] = self._background(eye, dx[miss], dy[miss])
            out[rr, cc] = rad.mean(axis=1)

    def _render(self, eye: str, t_ns: int, want_image: bool) -> tuple[F32 | None, dict[str, float]]:
        eye = EYES[_eye_index(eye)]
        times = self._exposure_times_s(self.time_s(t_ns))
        n = len(times)
        bg = self._background_image(eye) if want_image else None
        out = bg.copy() if bg is not None else None
        cov: dict[str, float] = {}
        for t in times:
            for rect, group in self._groups(eye, self._placed(float(t))):
                vals, gcov = self._render_group(eye, rect, group, want_image)
                if out is not None and bg is not None and vals is not None:
                    r0, r1, c0, c1 = rect
                    if n == 1:
                        out[r0:r1, c0:c1] = vals
                    else:
                        out[r0:r1, c0:c1] += (vals - bg[r0:r1, c0:c1]) / n
                for name, a in gcov.items():
                    cov[name] = cov.get(name, 0.0) + a / n
        return out, cov

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
        img *= np.float32(self.gain(eye, t_ns))
        sigma = self.photometry.noise_sigma
        if sigma > 0.0:
            rng = np.random.default_rng([self.seed, _eye_index(eye), int(t_ns)])
            noise = rng.standard_normal(img.shape, dtype=np.float32)
            noise *= np.float32(sigma)
            img += noise
        img += np.float32(0.5)
        np.clip(img, 0.0, 255.0, out=img)
        return img.astype(np.uint8)

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
        d["objects"] = [{"kind": type(o).__name__, **asdict(o)} for o in self.objects]
        return dict(_jsonable(d))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scene:
        objs: list[Shape] = []
        for od in d.get("objects", []):
            od = dict(od)
            kind = _SHAPES[od.pop("kind")]
            od["trajectory"] = _build(Trajectory, od["trajectory"])
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
        )


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def _tuplify(x: Any) -> Any:
    if isinstance(x, list):
        return tuple(_tuplify(v) for v in x)
    return x


def _build(cls: Any, d: dict[str, Any]) -> Any:
    return cls(**{k: _tuplify(v) for k, v in d.items()})


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------


def write_scene(scene: Scene, out_dir: str | Path) -> Path:
    """Write left/right.mkv (FFV1), left/right.csv, truth.csv and scene.json into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    size = (scene.rig.width_px, scene.rig.height_px)
    fourcc = cv2.VideoWriter.fourcc(*"FFV1")
    writers: dict[str, cv2.VideoWriter] = {}
    stamp_files: dict[str, TextIO] = {}
    stamp_writers: dict[str, Any] = {}
    try:
        for eye in EYES:
            fps = 1.0 / scene.clock(eye).period_s
            wr = cv2.VideoWriter(str(out / f"{eye}.mkv"), fourcc, fps, size, True)
            if not wr.isOpened():
                raise RuntimeError(f"cannot open FFV1 writer for {out / f'{eye}.mkv'}")
            writers[eye] = wr
            fh = (out / f"{eye}.csv").open("w", newline="")
            stamp_files[eye] = fh
            stamp_writers[eye] = csv.writer(fh)
            stamp_writers[eye].writerow(["t_ns", "seq"])
        for fr in scene.frames():
            writers[fr.eye].write(fr.image)
            stamp_writers[fr.eye].writerow([fr.t_ns, fr.seq])
    finally:
        for wr in writers.values():
            wr.release()
        for sf in stamp_files.values():
            sf.close()
    with (out / "truth.csv").open("w", newline="") as fh:
        tw = csv.writer(fh)
        tw.writerow(["object", "t_ns", "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps"])
        for t in scene.all_frame_times():
            for name, (p, v) in scene.truth(t).items():
                tw.writerow([name, t, *(f"{x:.9f}" for x in p), *(f"{x:.9f}" for x in v)])
    rig = scene.rig
    meta = {
        "scene": scene.to_dict(),
        "derived": {
            "focal_px": rig.focal_px,
            "cx_px": rig.cx,
            "cy_px": rig.cy,
            "vfov_deg": rig.vfov_deg,
            "frames": {eye: len(scene.frame_times(eye)) for eye in EYES},
            "pixel_convention": "integer (u, v) is the pixel centre; principal point (W-1)/2",
            "timestamp_convention": "t_ns = start of exposure; image averages [t, t+exposure]",
            "frame": "rig frame: X right, Y down, Z forward; origin between camera centres",
        },
    }
    (out / "scene.json").write_text(json.dumps(meta, indent=2))
    return out


def load_scene(path: str | Path) -> Scene:
    """Rebuild a Scene from a ``scene.json`` written by :func:`write_scene` (or its folder)."""
    p = Path(path)
    if p.is_dir():
        p = p / "scene.json"
    data = json.loads(p.read_text())
    return Scene.from_dict(data.get("scene", data))


# --------------------------------------------------------------------------------------------
# Presets
# --------------------------------------------------------------------------------------------

BALL_BGR: Vec3 = (45.0, 125.0, 215.0)  # orange; lit side ~ grey 160-170, like parts of the wall
BALL2_BGR: Vec3 = (200.0, 120.0, 50.0)  # blue
ROBOT_BGR: Vec3 = (150.0, 140.0, 130.0)
BOX_BGR: Vec3 = (70.0, 150.0, 90.0)


def _vec(a: npt.ArrayLike) -> Vec3:
    x, y, z = (float(c) for c in np.asarray(a, dtype=np.float64))
    return (x, y, z)


def _clocks(mode: Mode, skew: Skew, duration_s: float) -> tuple[Clock, Clock]:
    fps = float(mode[2])
    if isinstance(skew, str):
        if skew != "wander":
            raise ValueError("skew must be a fraction of a frame or 'wander'")
        return clocks_for_skew(fps, -0.5, 0.5, duration_s)
    return clocks_for_skew(fps, float(skew), float(skew), duration_s)


def _box_in_view(rig: Rig, centre: F64, half: F64) -> bool:
    """Whether the object's bounding box can be seen by at least one eye (conservative)."""
    probe = Scene(rig=rig)
    return any(probe._pixel_rect(eye, centre - half, centre + half, 0) for eye in EYES)


def _centre_in_both(rig: Rig, centre: F64) -> bool:
    if centre[2] < 0.1:
        return False
    for eye in EYES:
        u, v = rig.project(eye, centre)
        if not (-0.5 <= u <= rig.width_px - 0.5 and -0.5 <= v <= rig.height_px - 0.5):
            return False
    return True


def _scan_out(
    rig: Rig, half: F64, pos: Callable[[float], F64], step: float, limit: float
) -> tuple[float, bool]:
    """Walk t = step, 2 step, ... until the box leaves both views: (|t|, exited)."""
    t = 0.0
    while abs(t) < limit:
        t += step
        if not _box_in_view(rig, pos(t), half):
            return abs(t), True
    return limit, False


def _scene(
    name: str,
    rig: Rig,
    mode: Mode,
    skew: Skew,
    duration_s: float,
    objects: Sequence[Shape],
    seed: int,
    room: Room,
    exposure_s: float,
    photometry: Photometry | None,
) -> Scene:
    left, right = _clocks(mode, skew, duration_s)
    return Scene(
        rig=rig,
        left_clock=left,
        right_clock=right,
        objects=tuple(objects),
        photometry=photometry or Photometry(),
        room=room,
        seed=seed,
        duration_s=duration_s,
        exposure_s=exposure_s,
        name=name,
    )


def _robot(
    name: str,
    solid: Shape,
    heading_deg: float,
    speed_mps: float,
    mode: Mode,
    hfov_deg: float,
    seed: int,
    skew: Skew,
    lead_in_s: float,
    distance_m: float,
    lateral_offset_m: float,
    half_path_m: float | None,
    exposure_s: float,
    photometry: Photometry | None,
    room: Room | None,
) -> Scene:
    if speed_mps <= 0.0:
        raise ValueError("speed must be positive")
    room = room or Room()
    rig = Rig(int(mode[0]), int(mode[1]), hfov_deg)
    half = solid.half_extent_m()
    floor_y = room.floor_height_m if room.floor_height_m is not None else 0.35
    mid = np.array([lateral_offset_m, floor_y - half[1], distance_m])
    h = math.radians(heading_deg)
    vel = speed_mps * np.array([math.sin(h), 0.0, math.cos(h)])
    if half_path_m is None and abs(math.sin(h)) < 0.5:
        half_path_m = 0.5  # radial: no way in from the side, appear in view
    z_lo, z_hi = 0.3 + half[2], room.wall_distance_m - 0.3 - half[2]

    def z_limit(sign: float) -> float:
        if half_path_m is not None:
            return half_path_m / speed_mps
        vz = sign * vel[2]
        if abs(vz) < 1e-9:
            return 30.0
        return ((z_hi if vz > 0 else z_lo) - mid[2]) / vz

    def pos(t: float) -> F64:
        return mid + vel * t

    t_back, exited_b = _scan_out(rig, half, pos, -0.004, z_limit(-1.0))
    t_fwd, exited_f = _scan_out(rig, half, pos, 0.004, z_limit(1.0))
    if exited_b:
        t_back += 0.05
    t_mid = lead_in_s + t_back
    duration = t_mid + t_fwd + (0.3 if exited_f else 0.0)
    traj = Trajectory(_vec(mid), _vec(vel), t_ref_s=t_mid, t_start_s=lead_in_s, t_end_s=duration)
    obj = replace(solid, trajectory=traj)
    return _scene(name, rig, mode, skew, duration, [obj], seed, room, exposure_s, photometry)


_HOLD = Trajectory(_ZERO3)


def robot_ball(
    heading_deg: float = 90.0,
    speed_mps: float = 0.5,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    radius_m: float = 0.07,
    distance_m: float = 1.6,
    lateral_offset_m: float = 0.05,
    half_path_m: float | None = None,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
    room: Room | None = None,
) -> Scene:
    """Ball rolling on the floor at a compass heading (0 = away, 90 = +X, 180 = towards).

    Passes ``(lateral_offset, floor - r, distance)`` at mid-time, moving from the lead-in on.
    Non-radial headings enter the view from outside, already moving, unless the path reaches
    the near (Z = 0.3 m) or far (0.3 m before the wall) limit first, where it then appears;
    radial ones (within 30 deg of the axis) appear at their start point ``half_path_m``
    (default 0.5 m) before the mid point.  The scene ends 0.3 s after the object leaves the
    view, or when it reaches the end of its path.
    """
    ball = Sphere(
        name="ball",
        trajectory=_HOLD,
        radius_m=radius_m,
        colour_bgr=BALL_BGR,
        stripe_bgr=(40.0, 40.0, 45.0),
        stripe_half_width_m=0.008 * radius_m / 0.07,
    )
    return _robot(
        "robot_ball", ball, heading_deg, speed_mps, mode, hfov_deg, seed, skew, lead_in_s,
        distance_m, lateral_offset_m, half_path_m, exposure_s, photometry, room,
    )  # fmt: skip


def robot_cylinder(
    heading_deg: float = 90.0,
    speed_mps: float = 0.5,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    radius_m: float = 0.10,
    height_m: float = 0.15,
    distance_m: float = 1.6,
    lateral_offset_m: float = 0.05,
    half_path_m: float | None = None,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
    room: Room | None = None,
) -> Scene:
    """Small round robot (upright cylinder standing on the floor); same motion as robot_ball."""
    robot = Cylinder(
        name="robot",
        trajectory=_HOLD,
        radius_m=radius_m,
        height_m=height_m,
        colour_bgr=ROBOT_BGR,
        stripe_bgr=(40.0, 60.0, 200.0),
        stripe_half_width_m=0.015,
    )
    return _robot(
        "robot_cylinder", robot, heading_deg, speed_mps, mode, hfov_deg, seed, skew, lead_in_s,
        distance_m, lateral_offset_m, half_path_m, exposure_s, photometry, room,
    )  # fmt: skip


def robot_box(
    heading_deg: float = 90.0,
    speed_mps: float = 0.5,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    half_size_m: Vec3 = (0.12, 0.075, 0.09),
    distance_m: float = 1.6,
    lateral_offset_m: float = 0.05,
    half_path_m: float | None = None,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
    room: Room | None = None,
) -> Scene:
    """Axis-aligned box sliding on the floor (does not rotate); same motion as robot_ball."""
    box = Box(
        name="box",
        trajectory=_HOLD,
        half_size_m=half_size_m,
        colour_bgr=BOX_BGR,
        stripe_bgr=(60.0, 200.0, 230.0),
        stripe_half_width_m=0.012,
    )
    return _robot(
        "robot_box", box, heading_deg, speed_mps, mode, hfov_deg, seed, skew, lead_in_s,
        distance_m, lateral_offset_m, half_path_m, exposure_s, photometry, room,
    )  # fmt: skip


def crossing(
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    depths_m: tuple[float, float] = (1.5, 1.8),
    speeds_mps: tuple[float, float] = (0.6, 0.5),
    radius_m: float = 0.07,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
    room: Room | None = None,
) -> Scene:
    """Two balls rolling in opposite directions; 'near' (+X) passes in front of 'far' (-X).

    Both reach x ~ 0 at mid-time, so the near ball occludes the far one in both eyes then.
    """
    room = room or Room()
    rig = Rig(int(mode[0]), int(mode[1]), hfov_deg)
    floor_y = room.floor_height_m if room.floor_height_m is not None else 0.35
    half = np.full(3, radius_m)
    mids = [np.array([0.0, floor_y - radius_m, depths_m[0]]),
            np.array([0.02, floor_y - radius_m, depths_m[1]])]  # fmt: skip
    vels = [np.array([speeds_mps[0], 0.0, 0.0]), np.array([-speeds_mps[1], 0.0, 0.0])]
    backs, fwds = [], []
    for m, v in zip(mids, vels, strict=True):

        def pos(t: float, m: F64 = m, v: F64 = v) -> F64:
            return m + v * t

        backs.append(_scan_out(rig, half, pos, -0.004, 30.0)[0] + 0.05)
        fwds.append(_scan_out(rig, half, pos, 0.004, 30.0)[0])
    t_mid = lead_in_s + max(backs)
    duration = t_mid + max(fwds) + 0.3
    objs: list[Shape] = []
    for name, m, v, back, col in zip(
        ("near", "far"), mids, vels, backs, (BALL_BGR, BALL2_BGR), strict=True
    ):
        tr = Trajectory(_vec(m), _vec(v), t_ref_s=t_mid, t_start_s=t_mid - back, t_end_s=duration)
        objs.append(Sphere(name=name, trajectory=tr, radius_m=radius_m, colour_bgr=col))
    return _scene("crossing", rig, mode, skew, duration, objs, seed, room, exposure_s, photometry)


def fast_ball(
    direction: Literal["lateral", "radial"] = "lateral",
    speed_mps: float = 15.0,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    radius_m: float = 0.04,
    distance_m: float = 2.75,
    min_frames: float = 3.0,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
    room: Room | None = None,
) -> Scene:
    """A thrown ball (gravity on, apex at mid-time), speeds of 10-20 m/s.

    'lateral': flies left to right through (0, -0.05, distance) at mid-time; if a purely lateral
    flight would stay in view for fewer than ``min_frames`` frame periods, the path is tilted
    (receding while crossing) just enough.  'radial': appears at (-0.25, 0, 5) after the lead-in
    and flies towards the rig, passing (0.15, 0, 1) before leaving the view.  The wall is moved
    to 6 m by default so that the flight fits in the room.
    """
    room = room or Room(wall_distance_m=6.0)
    rig = Rig(int(mode[0]), int(mode[1]), hfov_deg)
    g = np.array([0.0, 9.81, 0.0])
    half = np.full(3, radius_m)
    period = 1.0 / mode[2]
    if direction == "lateral":
        mid = np.array([0.0, -0.05, distance_m])
        z_max = room.wall_distance_m - 0.3
        vel = np.zeros(3)
        for tilt in range(0, 62, 2):
            h = math.radians(90.0 - tilt)
            vel = speed_mps * np.array([math.sin(h), 0.0, math.cos(h)])
            window = 0.0
            for sign in (-1.0, 1.0):
                t = 0.0
                while True:
                    p = mid + vel * (t + sign * 0.001) + 0.5 * g * (t + sign * 0.001) ** 2
                    if not (_centre_in_both(rig, p) and p[2] < z_max):
                        break
                    t += sign * 0.001
                window += abs(t)
            if window >= min_frames * period:
                break
        vel_c, mid_c = vel.copy(), mid.copy()

        def pos(t: float) -> F64:
            return mid_c + vel_c * t + 0.5 * g * t * t

        t_back = _scan_out(rig, half, pos, -0.001, 10.0)[0] + 0.02
        t_fwd = _scan_out(rig, half, pos, 0.001, 10.0)[0] + 0.02
        t_ref = lead_in_s + t_back
        t_end = t_ref + t_fwd
        p_ref = mid_c
    elif direction == "radial":
        start = np.array([-0.25, 0.0, 5.0])
        end = np.array([0.15, 0.0, 1.0])
        flight = float(np.linalg.norm((end - start)[[0, 2]])) / speed_mps
        vel_c = (end - start) / flight - 0.5 * g * flight
        p_ref = start

        def pos(t: float) -> F64:
            return start + vel_c * t + 0.5 * g * t * t

        t_ref = lead_in_s
        t_fwd = _scan_out(rig, half, pos, 0.001, 10.0)[0] + 0.02
        t_end = t_ref + t_fwd
    else:
        raise ValueError("direction must be 'lateral' or 'radial'")
    duration = t_end + 0.3
    traj = Trajectory(
        _vec(p_ref), _vec(vel_c), _vec(g), t_ref_s=t_ref, t_start_s=lead_in_s, t_end_s=t_end
    )
    ball = Sphere(
        name="ball",
        trajectory=traj,
        radius_m=radius_m,
        colour_bgr=(60.0, 200.0, 190.0),  # yellow-green tennis ball
        stripe_bgr=(215.0, 225.0, 230.0),
        stripe_half_width_m=0.12 * radius_m,
    )
    return _scene(
        f"fast_ball_{direction}", rig, mode, skew, duration, [ball], seed, room, exposure_s,
        photometry,
    )  # fmt: skip


PRESETS: dict[str, Callable[..., Scene]] = {
    "robot_ball": robot_ball,
    "robot_cylinder": robot_cylinder,
    "robot_box": robot_box,
    "crossing": crossing,
    "fast_ball": fast_ball,
}


def main(argv: Sequence[str] | None = None) -> int:
    """Quick look: ``python -m stereod_fakes.world robot_ball OUT_DIR [--vga] [--bench]``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("preset", choices=sorted(PRESETS))
    ap.add_argument("out_dir", nargs="?")
    ap.add_argument("--vga", action="store_true", help="640x480 at 15 fps (default 320x240@30)")
    ap.add_argument("--hfov", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--skew", default="0", help="fraction of a frame or 'wander'")
    ap.add_argument("--bench", action="store_true", help="time the rendering of frame pairs")
    a = ap.parse_args(argv)
    skew: Skew = "wander" if a.skew == "wander" else float(a.skew)
    mode = MODE_640x480_15 if a.vga else MODE_320x240_30
    scene = PRESETS[a.preset](mode=mode, hfov_deg=a.hfov, seed=a.seed, skew=skew)
    print(f"{scene.name}: {scene.duration_s:.2f} s, "
          f"{len(scene.frame_times('left'))}+{len(scene.frame_times('right'))} frames")  # fmt: skip
    if a.bench:
        times = scene.all_frame_times()
        scene.render("left", times[0])
        scene.render("right", times[0])
        t0 = time.perf_counter()
        for t in times[::4]:
            scene.render("left", t)
            scene.render("right", t)
        print(f"{(time.perf_counter() - t0) / len(times[::4]) * 1e3:.1f} ms per pair")
    if a.out_dir:
        print(write_scene(scene, a.out_dir))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
