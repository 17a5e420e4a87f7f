"""The paper's Table I scenarios as synthetic scenes (for benchmarks and accuracy tests).

Table I: a robot moves at constant speed on the floor in front of a Minoru (0.060 m baseline),
in eight directions. Here it is a 0.08 m sphere 0.25 m below the optical axes, crossing about
1.8 m in front of the rig, seen at 640x480 and 15 Hz with sensor noise, a slow lighting drift
and the right eye half a frame late (the worst case of two free-running eyes).
"""

from __future__ import annotations

from dataclasses import dataclass

from .synth import Ball, Scene


@dataclass(frozen=True)
class TableRow:
    """One row of the paper's Table I: given and measured direction (deg) and speed (m/s)."""

    heading_deg: float
    speed_mps: float
    paper_heading_deg: float
    paper_speed_mps: float


TABLE_I = (
    TableRow(0, 0.9, 5, 0.7),
    TableRow(30, 0.7, 27, 0.6),
    TableRow(60, 0.7, 58, 0.6),
    TableRow(90, 0.4, 91, 0.4),
    TableRow(180, 0.9, 176, 0.8),
    TableRow(210, 0.7, 208, 0.6),
    TableRow(240, 0.7, 242, 0.7),
    TableRow(270, 0.4, 271, 0.4),
)


def table_one_scene(
    heading_deg: float,
    speed_mps: float,
    *,
    fps: float = 15.0,
    skew_frames: float = 0.5,
    noise_sigma: float = 2.0,
    drift: float = 0.05,
    seed: int = 0,
) -> Scene:
    """The scene of one Table I row: the sphere travels at most 1.4 m (at most 2 s) through
    (0, 0.25, 1.8) m, after a 1 s empty lead-in for the background."""
    travel_s = min(2.0, 1.4 / speed_mps)
    lead_in = 1.0
    ball = Ball(
        centre_m=(0.0, 0.25, 1.8),
        heading_deg=heading_deg,
        speed_mps=speed_mps,
        radius_m=0.08,
        t_on_s=lead_in,
        t_off_s=lead_in + travel_s,
        t_mid_s=lead_in + travel_s / 2,
    )
    return Scene(
        fps=fps,
        duration_s=lead_in + travel_s + 0.3,
        skew_s=skew_frames / fps,
        noise_sigma=noise_sigma,
        drift=drift,
        drift_period_s=8.0,
        seed=seed,
        balls=[ball],
    )
