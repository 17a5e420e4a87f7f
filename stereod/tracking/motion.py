"""Motion parameters from positions over time (paper sec. VI, eq. 21-23).

Velocity is eq. 21's finite difference over a time base tau, speed is eq. 22's norm and heading
eq. 23's angle in the XZ plane, as a compass-like bearing: alpha = atan2(dx, dz) in degrees in
[0, 360), 0 = straight away from the camera (+Z), 90 = towards +X, 180 = towards the camera.

Beyond the paper, :func:`fit_velocity` fits a straight line to every position in the window
(least squares); with two samples it is eq. 21 exactly, with more it averages the triangulation
noise down instead of using only the two end points.
"""

from __future__ import annotations

import math

import numpy as np


def finite_difference(p1_m: np.ndarray, p2_m: np.ndarray, tau_s: float) -> np.ndarray:
    """Eq. 21: v = (p2 - p1) / tau, (3,) m/s from two (3,) positions (m) tau seconds apart."""
    if not tau_s > 0:
        raise ValueError(f"time base must be > 0 s, got {tau_s}")
    return (np.asarray(p2_m, dtype=np.float64) - np.asarray(p1_m, dtype=np.float64)) / tau_s


def speed(v_mps: np.ndarray) -> float:
    """Eq. 22: |v| = sqrt(vx^2 + vy^2 + vz^2) (m/s)."""
    return float(math.sqrt(float(np.dot(v_mps, v_mps))))


def heading_deg(dx: float, dz: float) -> float:
    """Eq. 23 as a full-circle bearing: atan2(dx, dz) in degrees in [0, 360)."""
    return math.degrees(math.atan2(dx, dz)) % 360.0


def heading_sigma_deg(vx: float, vz: float, sx: float, sz: float, cxz: float = 0.0) -> float:
    """First-order sigma (deg) of eq. 23's heading for velocity sigmas ``sx``, ``sz`` (m/s)
    and their covariance ``cxz`` (m^2/s^2): the velocity's sigma across its direction on the
    ground over the ground speed."""
    h2 = vx * vx + vz * vz
    if h2 <= 0.0:
        return 180.0
    across2 = (vz * sx) ** 2 + (vx * sz) ** 2 - 2.0 * vx * vz * cxz
    return math.degrees(math.sqrt(max(across2, 0.0)) / h2)


def fit_velocity(
    t_s: np.ndarray, p_m: np.ndarray, sigma_m: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares constant-velocity fit to (n,) times (s) and (n, 3) positions (m).

    Returns the (3,) velocity (m/s) and its (3,) sigma (m/s). ``sigma_m`` (n, 3) weights each
    sample by its triangulation sigma (far points count less, eq. 12); without it the sigma comes
    from the fit residuals. Needs n >= 2 distinct times.
    """
    t = np.asarray(t_s, dtype=np.float64)
    p = np.asarray(p_m, dtype=np.float64)
    n = t.shape[0]
    if n < 2:
        raise ValueError("a velocity needs at least two positions")
    w = np.ones_like(p) if sigma_m is None else 1.0 / np.square(np.maximum(sigma_m, 1e-9))
    sw = w.sum(axis=0)
    t_mean = (w * t[:, None]).sum(axis=0) / sw
    p_mean = (w * p).sum(axis=0) / sw
    dt = t[:, None] - t_mean
    stt = (w * dt * dt).sum(axis=0)
    if np.any(stt <= 0):
        raise ValueError("a velocity needs at least two distinct times")
    v = (w * dt * (p - p_mean)).sum(axis=0) / stt
    if sigma_m is not None:
        sigma_v = np.sqrt(1.0 / stt)
    elif n > 2:
        resid = p - (p_mean + dt * v)
        s2 = (resid * resid).sum(axis=0) / (n - 2)
        sigma_v = np.sqrt(s2 / stt)
    else:
        sigma_v = np.full(3, np.inf)
    return v, sigma_v


def circular_median_deg(angles_deg: np.ndarray | list[float]) -> float:
    """Median of headings (deg) that wraps correctly at 0/360: the median of their differences
    from the circular mean, added back, in [0, 360)."""
    a = np.radians(np.asarray(angles_deg, dtype=np.float64))
    if a.size == 0:
        raise ValueError("no angles")
    mean = math.atan2(float(np.sin(a).sum()), float(np.cos(a).sum()))
    d = (a - mean + math.pi) % (2 * math.pi) - math.pi
    return math.degrees(mean + float(np.median(d))) % 360.0


def angle_diff_deg(a: float, b: float) -> float:
    """Smallest signed difference a - b between two headings (deg), in (-180, 180]."""
    d = (a - b + 180.0) % 360.0 - 180.0
    return 180.0 if d == -180.0 else d
