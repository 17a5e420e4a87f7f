"""A rig's track as the fusion sees it: its state moved into the room frame with its
covariance, and predicted to another instant.

A rig publishes per-axis sigmas (its covariance's diagonal in the rig frame); in the room frame
that covariance is ``R P R^T``, no longer diagonal when the rig is turned. Prediction to the
fusion's common instant is constant velocity with a white-acceleration allowance, so that a
track stamped a few milliseconds before or after that instant lands where the object was then.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stereod.bus.messages import ObjectState
from stereod.fusion.room import RigPose
from stereod.tracking.types import TrackLifecycle

UNKNOWN_VELOCITY_SIGMA_MPS = 2.0
"""Velocity sigma assumed per axis while a rig does not know its track's (a walking pace), m/s."""
ACCEL_SIGMA_MPS2 = 2.0
"""Acceleration sigma per axis allowed for between a stamp and the instant it is predicted to
(a person starting or stopping), m/s^2."""
RAY_LATERAL_FLOOR = 0.1
"""Least share of the published X sigma left across the viewing ray when the ray's part of the
depth error is taken out of it (:func:`ray_cov`), dimensionless."""


@dataclass(frozen=True)
class RigTrack:
    """One rig's track at one instant, in the room frame (m, m/s, UTC ns)."""

    rig: str
    track_id: int
    state: TrackLifecycle
    stamp_utc_ns: int
    position: np.ndarray
    """(3,) position in the room frame, m."""
    position_cov: np.ndarray
    """(3, 3) position covariance in the room frame, m^2."""
    velocity: np.ndarray
    """(3,) velocity in the room frame, m/s."""
    velocity_cov: np.ndarray
    """(3, 3) velocity covariance in the room frame, (m/s)^2."""
    velocity_valid: bool
    heading_valid: bool
    source: ObjectState
    """The rig's message of this track (blobs, disparity, size stay the rig's)."""

    @property
    def seen(self) -> bool:
        """Whether the rig measured it in this pair (not coasting, not tentative)."""
        return self.state in (TrackLifecycle.CONFIRMED, TrackLifecycle.STATIONARY)


def _diag(sigmas: tuple[float, float, float] | None, default: float) -> np.ndarray:
    """A diagonal covariance from per-axis sigmas; ``default`` for a missing or non-finite one."""
    s = [default if sigmas is None or not math.isfinite(v) else v for v in (sigmas or (0, 0, 0))]
    return np.diag(np.square(np.asarray(s, dtype=np.float64)))


def ray_cov(position: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(n, 3, 3) position covariances (m^2, rig frame) rebuilt from a message's per-axis sigmas
    (n, 3) at positions (n, 3) (m), with the same diagonal. A stereo point's depth error, from
    its horizontal disparity, moves it along its viewing ray: ``X / Z`` in X per unit of depth,
    so the published X sigma of a point seen off axis holds the ray's share ``s_z X / Z`` of
    its depth error, and the published diagonal drops that X-Z correlation (a track then
    weighs across its ray as little as its depth error allows). Here that share is put back
    as far as the X sigma holds it, leaving at least :data:`RAY_LATERAL_FLOOR` of it across
    the ray. Y keeps its own error (the pipeline's does not follow the ray on the rendered
    rooms). A point at or behind the rig (Z <= 1 cm) keeps the diagonal."""
    s2 = np.square(sigma)
    cov = np.zeros((len(s2), 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = s2
    cov[:, 0, 2] = cov[:, 2, 0] = ray_xz(position, sigma)
    return cov


def ray_xz(position: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(n,) the X-Z covariance :func:`ray_cov` puts back, m^2 (0 where it keeps the
    diagonal)."""
    s2 = np.square(sigma)
    z = position[:, 2]
    every = np.logical_and.reduce
    ok = every(np.isfinite(position), axis=1) & every(np.isfinite(s2), axis=1) & (z > 0.01)
    wx = np.where(ok, position[:, 0] / np.where(ok, z, 1.0), 0.0)
    share = s2[:, 2] * np.square(wx)
    room = (1.0 - RAY_LATERAL_FLOOR**2) * s2[:, 0]
    wx *= np.where(share > room, room / np.where(share > 0, share, 1.0), 1.0)
    return np.where(ok, s2[:, 2] * wx, 0.0)


def to_room(rig: RigPose, obj: ObjectState) -> RigTrack:
    """``obj`` (rig frame) in the room frame: p' = R p + t, v' = R v, P' = R P R^T."""
    r = rig.rotation()
    p_cov = _diag(obj.position_sigma_m, 1.0)
    v_cov = _diag(obj.velocity_sigma_mps, UNKNOWN_VELOCITY_SIGMA_MPS)
    return RigTrack(
        rig=rig.name,
        track_id=obj.track_id,
        state=obj.state,
        stamp_utc_ns=obj.stamp_utc_ns,
        position=r @ np.asarray(obj.position_m, dtype=np.float64) + rig.translation(),
        position_cov=r @ p_cov @ r.T,
        velocity=r @ np.asarray(obj.velocity_mps, dtype=np.float64),
        velocity_cov=r @ v_cov @ r.T,
        velocity_valid=obj.velocity_valid,
        heading_valid=obj.heading_valid,
        source=obj,
    )


def predict(
    position: np.ndarray,
    position_cov: np.ndarray,
    velocity: np.ndarray,
    velocity_cov: np.ndarray,
    dt_s: float,
    accel_sigma_mps2: float = ACCEL_SIGMA_MPS2,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Position, its covariance, velocity and its covariance ``dt_s`` seconds later (or
    earlier, for a negative one): constant velocity, the velocity's uncertainty and a white
    acceleration of ``accel_sigma_mps2`` growing the position's by dt^2 V + (a dt^2 / 2)^2."""
    dt = float(dt_s)
    q = accel_sigma_mps2**2
    p = position + velocity * dt
    p_cov = position_cov + dt * dt * velocity_cov + np.eye(3) * (q * dt**4 / 4.0)
    v_cov = velocity_cov + np.eye(3) * (q * dt * dt)
    return p, p_cov, velocity.copy(), v_cov


def predicted(track: RigTrack, t_ns: int) -> RigTrack:
    """``track`` predicted to the UTC instant ``t_ns`` (ns)."""
    dt = (t_ns - track.stamp_utc_ns) * 1e-9
    p, pc, v, vc = predict(
        track.position, track.position_cov, track.velocity, track.velocity_cov, dt
    )
    return RigTrack(
        rig=track.rig,
        track_id=track.track_id,
        state=track.state,
        stamp_utc_ns=t_ns,
        position=p,
        position_cov=pc,
        velocity=v,
        velocity_cov=vc,
        velocity_valid=track.velocity_valid,
        heading_valid=track.heading_valid,
        source=track.source,
    )
