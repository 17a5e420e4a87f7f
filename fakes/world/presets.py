"""Preset scenes: a ball / robot / box moving on the floor, two balls crossing, a thrown ball."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Literal

import numpy as np

from ._base import _ZERO3, EYES, F64, Mode, MODE_320x240_30, Skew, Vec3, _vec
from .camera import Clock, Photometry, Rig, clocks_for_skew
from .motion import Trajectory
from .scene import Scene
from .shapes import Box, Cylinder, Shape, Sphere
from .textures import Room

BALL_BGR: Vec3 = (45.0, 125.0, 215.0)  # orange; lit side ~ grey 160-170, like parts of the wall
BALL2_BGR: Vec3 = (200.0, 120.0, 50.0)  # blue
ROBOT_BGR: Vec3 = (150.0, 140.0, 130.0)
BOX_BGR: Vec3 = (70.0, 150.0, 90.0)


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
