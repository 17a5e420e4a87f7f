"""The stereo rig: pinhole cameras, free-running frame clocks, photometry and sampling quality.

Conventions are in the package docstring: rig frame X right, Y down, Z forward (metres); the
integer pixel (u, v) is the pixel centre; ``t`` values are scene seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ._base import F64, U8, _eye_index


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
class Quality:
    supersample: int = 4  # S x S rays per pixel in object regions
    edge_supersample: int = 16  # E x E rays per pixel cut by a silhouette / occlusion edge
    ring_supersample: int = 8  # rays per pixel (squared) for the neighbours of those pixels
    background_supersample: int = 4  # rays per pixel for the static background
    exposure_samples: int = 0  # temporal samples when exposure > 0 (0: automatic)
    shadow_supersample: int = 2  # S x S rays per pixel where a lamp's shadow may fall
    rolling_band_rows: int = 1  # rolling shutter: rows cast at one instant (1: exact)


@dataclass(frozen=True, eq=False)
class RenderedFrame:
    eye: str
    image: U8
    t_ns: int
    seq: int
