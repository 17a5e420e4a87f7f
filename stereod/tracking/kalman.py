"""Constant-velocity Kalman filter in 3D, for one track.

State x = [px, py, pz, vx, vy, vz] (m, m/s, rig frame), covariance P (6, 6). The motion model is
constant velocity driven by white acceleration noise of spectral density ``q`` (m^2/s^3),
optionally plus a known constant acceleration (gravity, for an object in free fall); the
measurement is a position with its own covariance R (3, 3), from triangulation, so far points
(depth sigma growing as Z^2, eq. 12) pull the estimate less than near ones. ``dt`` is seconds
between capture timestamps, never a frame count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

H = np.hstack([np.eye(3), np.zeros((3, 3))])
"""Measurement matrix: the position part of the state, (3, 6)."""


_EYE6 = np.eye(6)
_ZERO6 = np.zeros((6, 6))
_DT_AT = [3, 10, 17]
"""Where dt goes in F, flattened: (0, 3), (1, 4), (2, 5)."""
_Q_AT = [i * 6 + j for i in range(3) for j in (i, i + 3)] + [
    (i + 3) * 6 + j for i in range(3) for j in (i, i + 3)
]
"""Where Q's terms go, flattened: each position's (i, i) and (i, i + 3), then each
velocity's (i + 3, i) and (i + 3, i + 3)."""


def transition(dt_s: float) -> np.ndarray:
    """F (6, 6): p' = p + v dt, v' = v."""
    f = _EYE6.copy()
    f.put(_DT_AT, dt_s)
    return f


def process_noise(dt_s: float, q: float) -> np.ndarray:
    """Q (6, 6) of a white-noise acceleration of spectral density ``q`` (m^2/s^3) over ``dt_s``:
    q dt^3 / 3 on positions, q dt^2 / 2 between position and velocity, q dt on velocities."""
    dt2 = dt_s * dt_s
    pp, pv, vv = q * dt2 * dt_s / 3.0, q * dt2 / 2.0, q * dt_s
    m = _ZERO6.copy()
    m.put(_Q_AT, [pp, pv, pp, pv, pp, pv, pv, vv, pv, vv, pv, vv])
    return m


@dataclass
class KalmanState:
    """x (6,) and P (6, 6) at time ``t_ns`` (monotonic, ns)."""

    x: np.ndarray
    P: np.ndarray
    t_ns: int

    @property
    def position_m(self) -> np.ndarray:
        return self.x[:3]

    @property
    def velocity_mps(self) -> np.ndarray:
        return self.x[3:]

    @property
    def velocity_cov(self) -> np.ndarray:
        return self.P[3:, 3:]


def initiate(
    z_m: np.ndarray, r_m2: np.ndarray, t_ns: int, velocity_sigma_mps: float
) -> KalmanState:
    """A state from a first position measurement ``z_m`` (3,) with covariance ``r_m2``; the
    velocity starts at zero with sigma ``velocity_sigma_mps`` per axis."""
    x = np.concatenate([np.asarray(z_m, float), np.zeros(3)])
    p = np.zeros((6, 6))
    p[:3, :3] = r_m2
    p[3:, 3:] = np.eye(3) * velocity_sigma_mps**2
    return KalmanState(x, p, t_ns)


def predict(
    s: KalmanState, t_ns: int, q: float, accel_mps2: np.ndarray | None = None
) -> KalmanState:
    """The state at ``t_ns``: x = F x (+ the known acceleration's a dt^2 / 2 and a dt),
    P = F P F' + Q."""
    dt = (t_ns - s.t_ns) * 1e-9
    if dt == 0:
        return s
    f = transition(dt)
    x = f @ s.x
    if accel_mps2 is not None:
        half = 0.5 * dt * dt
        ax, ay, az = accel_mps2.tolist()
        x += np.array([half * ax, half * ay, half * az, dt * ax, dt * ay, dt * az])
    return KalmanState(x, f @ s.P @ f.T + process_noise(abs(dt), q), t_ns)


def position_at(s: KalmanState, t_ns: int, accel_mps2: np.ndarray | None = None) -> np.ndarray:
    """The predicted position (3,) m at ``t_ns``, without the covariance (cheap)."""
    dt = (t_ns - s.t_ns) * 1e-9
    p = s.x[:3] + s.x[3:] * dt
    return p if accel_mps2 is None else p + 0.5 * dt * dt * accel_mps2


def point_at(
    s: KalmanState, t_ns: int, accel_mps2: np.ndarray | None = None
) -> tuple[float, float, float]:
    """:func:`position_at` as three Python floats (m), the same arithmetic to the bit: most
    callers want one coordinate, or all three for a projection, and numpy's per-call cost is
    most of the work on three numbers."""
    dt = (t_ns - s.t_ns) * 1e-9
    x, y, z, vx, vy, vz = s.x.tolist()
    x, y, z = x + vx * dt, y + vy * dt, z + vz * dt
    if accel_mps2 is None:
        return x, y, z
    half = 0.5 * dt * dt
    ax, ay, az = accel_mps2.tolist()
    return x + half * ax, y + half * ay, z + half * az


def inflate_velocity(s: KalmanState, sigma_mps: float) -> KalmanState:
    """The state with ``sigma_mps`` per axis added to its velocity uncertainty: after a
    manoeuvre the old velocity is no guide. Apply it to the state before a prediction, so the
    prediction correlates position with the re-opened velocity and the next measurement
    corrects both."""
    p = s.P.copy()
    p[3:, 3:] += np.eye(3) * sigma_mps**2
    return KalmanState(s.x.copy(), p, s.t_ns)


def innovation(s: KalmanState, z_m: np.ndarray, r_m2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """y = z - H x (3,) and S = H P H' + R (3, 3)."""
    y = np.asarray(z_m, float) - s.x[:3]
    return y, s.P[:3, :3] + r_m2


ILL_CONDITIONED = 1e-8
"""The smallest det / (a e i) :func:`inverse3` inverts in closed form (Hadamard's ratio: 1
for a diagonal matrix, 0 for a singular one)."""


def inverse3(m: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The inverse and determinant of a symmetric 3 x 3 matrix by its adjugate, in closed
    form: a track solves with S several times a pair, and LAPACK's per-call cost dwarfs nine
    products on a 3 x 3. ``None`` when the matrix is not positive definite (a leading minor
    not positive), or so ill-conditioned that the adjugate's cancellation would cost more
    than half the digits (det under ``ILL_CONDITIONED`` of the diagonal's product: a far
    object, whose depth and lateral errors are almost one); the caller then solves with
    LAPACK, which is backward-stable (and gives a minus-infinite likelihood for a matrix
    that is not a covariance)."""
    (a, b, c), (d, e, f), (g, h, i) = m.tolist()
    c11, c12, c13 = e * i - f * h, f * g - d * i, d * h - e * g
    det = a * c11 + b * c12 + c * c13
    if not (a > 0.0 and a * e - b * d > 0.0 and det > 0.0 and det > ILL_CONDITIONED * a * e * i):
        return None
    if not math.isfinite(det):
        return None
    inv = [
        [c11 / det, (c * h - b * i) / det, (b * f - c * e) / det],
        [c12 / det, (a * i - c * g) / det, (c * d - a * f) / det],
        [c13 / det, (b * g - a * h) / det, (a * e - b * d) / det],
    ]
    return np.array(inv), det


def mahalanobis2(s: KalmanState, z_m: np.ndarray, r_m2: np.ndarray) -> float:
    """Squared Mahalanobis distance y' S^-1 y of a measurement from the state (chi^2, 3 dof)."""
    y, cov = innovation(s, z_m, r_m2)
    return _mahalanobis2(y, cov, inverse3(cov))


def log_likelihood(s: KalmanState, z_m: np.ndarray, r_m2: np.ndarray) -> float:
    """Log of the Gaussian density of measurement ``z_m`` under the state's prediction:
    -(y' S^-1 y + log det S + 3 log 2 pi) / 2; comparing two models' sums picks the likelier."""
    y, cov = innovation(s, z_m, r_m2)
    return _log_likelihood(y, cov, inverse3(cov))


def update(s: KalmanState, z_m: np.ndarray, r_m2: np.ndarray) -> KalmanState:
    """Fold in a position: K = P H' S^-1, x = x + K y, P = (I - K H) P (I - K H)' + K R K'
    (Joseph's form: it stays a covariance through rounding, where P - K H P, equal in exact
    arithmetic, can lose a variance's sign on a precise measurement after a long coast)."""
    y, cov = innovation(s, z_m, r_m2)
    return _update(s, y, cov, inverse3(cov), r_m2)


def correct(
    pred: KalmanState, z_m: np.ndarray, r_m2: np.ndarray, chi2_max: float, widen: int = 3
) -> tuple[KalmanState, float]:
    """:func:`update` of a prediction with a position, and the position's
    :func:`log_likelihood` under the prediction as it was. A squared Mahalanobis distance
    beyond ``chi2_max`` (a manoeuvre, or a prediction too sure of itself) first widens the
    prediction's covariance by that ratio, up to ``widen`` times, so the update leans on the
    measurement as much as the surprise calls for (a fading memory). S is inverted once per
    covariance."""
    y, cov = innovation(pred, z_m, r_m2)
    inv = inverse3(cov)
    nis = _mahalanobis2(y, cov, inv)
    ll = _log_likelihood(y, cov, inv, nis)
    for k in range(widen):
        if k:
            nis = _mahalanobis2(y, cov, inv)
        if nis <= chi2_max:
            break
        pred = KalmanState(pred.x, pred.P * (nis / chi2_max), pred.t_ns)
        cov = pred.P[:3, :3] + r_m2
        inv = inverse3(cov)
    return _update(pred, y, cov, inv, r_m2), ll


_LOG_2PI_3 = 3.0 * math.log(2.0 * math.pi)


def _mahalanobis2(y: np.ndarray, cov: np.ndarray, inv: tuple[np.ndarray, float] | None) -> float:
    if inv is None:
        return float(y @ np.linalg.solve(cov, y))
    return quadratic3(y, inv[0])


def quadratic3(y: np.ndarray, m: np.ndarray) -> float:
    """y' M y for a 3-vector and a 3 x 3 matrix, in Python floats (numpy's per-call cost is
    most of the work at this size)."""
    a, b, c = y.tolist()
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m.tolist()
    return (
        a * (m00 * a + m01 * b + m02 * c)
        + b * (m10 * a + m11 * b + m12 * c)
        + c * (m20 * a + m21 * b + m22 * c)
    )


def _log_likelihood(
    y: np.ndarray,
    cov: np.ndarray,
    inv: tuple[np.ndarray, float] | None,
    nis: float | None = None,
) -> float:
    """Gaussian log-density of the innovation ``y`` (``nis``: y' S^-1 y when known)."""
    if inv is None:
        sign, logdet = np.linalg.slogdet(cov)
        if sign <= 0:
            return -math.inf
        return -0.5 * (float(y @ np.linalg.solve(cov, y)) + logdet + _LOG_2PI_3)
    if nis is None:
        nis = quadratic3(y, inv[0])
    return -0.5 * (nis + math.log(inv[1]) + _LOG_2PI_3)


def _update(
    s: KalmanState,
    y: np.ndarray,
    cov: np.ndarray,
    inv: tuple[np.ndarray, float] | None,
    r_m2: np.ndarray,
) -> KalmanState:
    # K = P H' S^-1 = (S^-1 H P)', P and S being symmetric
    k = s.P[:, :3] @ inv[0] if inv is not None else np.linalg.solve(cov, s.P[:3, :]).T
    x = s.x + k @ y
    ikh = _EYE6.copy()
    ikh[:, :3] -= k
    p = ikh @ s.P @ ikh.T + k @ r_m2 @ k.T
    return KalmanState(x, 0.5 * (p + p.T), s.t_ns)


def initiate_two(
    z1_m: np.ndarray,
    r1_m2: np.ndarray,
    t1_ns: int,
    z2_m: np.ndarray,
    r2_m2: np.ndarray,
    t2_ns: int,
    accel_mps2: np.ndarray | None = None,
) -> KalmanState:
    """A state at ``t2_ns`` from two position measurements: the position is the second, the
    velocity their difference over the time between them (eq. 21 over one step; under a
    known acceleration that is the velocity half-way, plus a dt / 2 at the second), with the
    covariance that follows: P_pp = R2, P_pv = R2 / dt, P_vv = (R1 + R2) / dt^2."""
    dt = (t2_ns - t1_ns) * 1e-9
    if not dt > 0:
        raise ValueError(f"the second measurement must be later than the first, got dt={dt} s")
    z2 = np.asarray(z2_m, float)
    v = (z2 - np.asarray(z1_m, float)) / dt
    if accel_mps2 is not None:
        v = v + 0.5 * dt * accel_mps2
    x = np.concatenate([z2, v])
    p = np.zeros((6, 6))
    p[:3, :3] = r2_m2
    p[:3, 3:] = p[3:, :3] = r2_m2 / dt
    p[3:, 3:] = (r1_m2 + r2_m2) / (dt * dt)
    return KalmanState(x, p, t2_ns)
