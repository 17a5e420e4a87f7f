"""Room presets: a ball under a lamp (hard or soft shadows), people who sit, wave, walk,
stop and approach, and a robot that stops and goes.

People presets put the rig 1 m above the floor (``Room(floor_height_m=1.0)``) with the wall
5 m away.  Their stops last ``stop_s`` (long by default, as in a room; short in tests): a
stretch where nothing moves is rendered once and reused, so long stops cost little.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from typing import Literal

from ._base import Mode, MODE_320x240_30, Skew
from .camera import Photometry, Quality, Rig
from .light import AreaLight, Lamps, PointLight
from .motion import Waypoints
from .people import SEAT_HEIGHT_M, Act, Person
from .presets import PRESETS as _BASE_PRESETS
from .presets import ROBOT_BGR, _clocks, robot_ball
from .scene import Scene, SceneObject
from .shapes import Box, Cylinder
from .textures import Room

PERSON_ROOM = Room(wall_distance_m=5.0, floor_height_m=1.0)
# People have long silhouettes: 8 x 8 rays per edge pixel (stratified to 1/64 px along each
# axis) and 4 x 4 for their neighbours halve the render time against the default 16 and 8.
PERSON_QUALITY = Quality(edge_supersample=8, ring_supersample=4)
STOOL_BGR = (40.0, 70.0, 110.0)


def lamp_ball(
    lamp: Literal["overhead", "side"] = "overhead",
    soft: bool = False,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    speed_mps: float = 0.5,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
) -> Scene:
    """A ball rolling across the textured floor (as :func:`robot_ball` at 90 deg) under one
    lamp: 'overhead' 1.95 m above the floor over the path's middle, or 'side' 0.8 m above
    the floor 2.55 m to the left (a shadow about 0.55 m long).  ``soft``: a 0.4 x 0.4 m
    area lamp (soft shadow, 4 x 4 samples) instead of a point lamp."""
    base = robot_ball(
        90.0, speed_mps, mode=mode, hfov_deg=hfov_deg, seed=seed, skew=skew,
        exposure_s=exposure_s, photometry=photometry,
    )  # fmt: skip
    floor = base.room.floor_height_m or 0.35
    where = (0.05, floor - 1.95, 1.6) if lamp == "overhead" else (-2.5, floor - 0.8, 1.6)
    power = 1.0 if lamp == "overhead" else 2.0
    if lamp not in ("overhead", "side"):
        raise ValueError("lamp must be 'overhead' or 'side'")
    if soft:
        lamps = Lamps(ambient=0.3, areas=(AreaLight(where, intensity=power),))
    else:
        lamps = Lamps(ambient=0.3, points=(PointLight(where, intensity=power),))
    return replace(base, lamps=lamps, name=f"lamp_ball_{lamp}" + ("_soft" if soft else ""))


def _room(
    name: str,
    mode: Mode,
    hfov_deg: float,
    skew: Skew,
    duration_s: float,
    objects: Sequence[SceneObject],
    seed: int,
    room: Room,
    exposure_s: float,
    photometry: Photometry | None,
    lamps: Lamps | None,
    quality: Quality | None = None,
) -> Scene:
    left, right = _clocks(mode, skew, duration_s)
    return Scene(
        rig=Rig(int(mode[0]), int(mode[1]), hfov_deg),
        left_clock=left,
        right_clock=right,
        objects=tuple(objects),
        photometry=photometry or Photometry(),
        room=room,
        seed=seed,
        duration_s=duration_s,
        exposure_s=exposure_s,
        name=name,
        lamps=lamps,
        quality=quality or Quality(),
    )


def _lamp(lit: bool, room: Room) -> Lamps | None:
    floor = room.floor_height_m or 1.0
    return Lamps(points=(PointLight((0.5, floor - 2.6, 2.0), intensity=0.9),)) if lit else None


def person_sit_walk(
    stop_s: float = 30.0,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    sit_s: float = 3.0,
    lit: bool = False,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
) -> Scene:
    """A person appears seated on a stool at (-1.0, 3.0) after the lead-in (the stool is
    there from the start), waves for ``sit_s``, stands up, walks across to (0.3, 2.5),
    stands still for ``stop_s``, then walks on out of the view to the right; the scene ends
    1 s after the person has left.  ``lit``: one ceiling lamp with shadows."""
    room = PERSON_ROOM
    floor = room.floor_height_m or 1.0
    h = 0.5 * SEAT_HEIGHT_M
    stool = Box(
        name="stool", trajectory=Waypoints(((-1.0, floor - h, 3.08),), (0.0,), hold=True),
        half_size_m=(0.18, h, 0.18), colour_bgr=STOOL_BGR,
    )  # fmt: skip
    acts = (
        Act("sit", sit_s, wave=True),
        Act("stand_up"),
        Act("walk", to_xz_m=(0.3, 2.5)),
        Act("stand", stop_s),
        Act("walk", to_xz_m=(3.2, 2.5)),
    )
    person = Person(
        name="person", start_xz_m=(-1.0, 3.0), acts=acts, seated=True, floor_y_m=floor,
        t_start_s=lead_in_s,
    )  # fmt: skip
    duration = person.t_end_s + 1.0
    return _room(
        "person_sit_walk", mode, hfov_deg, skew, duration, [stool, person], seed, room,
        exposure_s, photometry, _lamp(lit, room), PERSON_QUALITY,
    )  # fmt: skip


def person_approach(
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    start_m: float = 3.5,
    end_m: float = 0.8,
    hold_s: float = 2.0,
    lit: bool = False,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
) -> Scene:
    """A person appears standing ``start_m`` in front of the rig, waits 1 s, walks straight
    towards it and stops with the torso centre ``end_m`` away, then stands for ``hold_s``."""
    room = PERSON_ROOM
    acts = (Act("stand", 1.0), Act("walk", to_xz_m=(0.1, end_m)), Act("stand", hold_s))
    person = Person(
        name="person", start_xz_m=(0.1, start_m), acts=acts, floor_y_m=room.floor_height_m or 1.0,
        t_start_s=lead_in_s,
    )  # fmt: skip
    return _room(
        "person_approach", mode, hfov_deg, skew, person.t_end_s, [person], seed, room,
        exposure_s, photometry, _lamp(lit, room), PERSON_QUALITY,
    )  # fmt: skip


def people_crossing(
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    depths_m: tuple[float, float] = (2.2, 3.0),
    speeds_mps: tuple[float, float] = (1.2, 1.0),
    lit: bool = False,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
) -> Scene:
    """Two people walk across in opposite directions, 'near' (left to right) in front of
    'far' (right to left); both pass x = 0 at the same instant, 'near' hiding 'far'."""
    room = PERSON_ROOM
    floor = room.floor_height_m or 1.0
    near_x, far_x = 2.4, 2.8
    t_near, t_far = near_x / speeds_mps[0], far_x / speeds_mps[1]
    t_cross = lead_in_s + max(t_near, t_far)
    near = Person(
        name="near", start_xz_m=(-near_x, depths_m[0]), speed_mps=speeds_mps[0],
        acts=(Act("walk", to_xz_m=(near_x, depths_m[0])),), floor_y_m=floor,
        t_start_s=t_cross - t_near,
    )  # fmt: skip
    far = Person(
        name="far", start_xz_m=(far_x, depths_m[1]), speed_mps=speeds_mps[1],
        acts=(Act("walk", to_xz_m=(-far_x, depths_m[1])),), floor_y_m=floor,
        t_start_s=t_cross - t_far, height_m=1.65,
        shirt_bgr=(60.0, 140.0, 60.0), trousers_bgr=(110.0, 80.0, 60.0),
    )  # fmt: skip
    duration = max(near.t_end_s, far.t_end_s) + 0.3
    return _room(
        "people_crossing", mode, hfov_deg, skew, duration, [near, far], seed, room,
        exposure_s, photometry, _lamp(lit, room), PERSON_QUALITY,
    )  # fmt: skip


def robot_stop_go(
    stop_s: float = 5.0,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    speed_mps: float = 0.5,
    distance_m: float = 1.8,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
    room: Room | None = None,
) -> Scene:
    """A round robot (upright cylinder on the floor) drives in from the left at
    ``distance_m``, stops in the middle (x = 0) for ``stop_s``, then drives out to the right;
    the path is a :class:`Waypoints` (the truth velocity is zero during the stop)."""
    room = room or Room()
    floor = room.floor_height_m if room.floor_height_m is not None else 0.35
    r, height = 0.10, 0.15
    y = floor - 0.5 * height
    edge = distance_m * 0.6 + 0.5  # beyond the half width of a 60 deg view, and a bit
    drive = edge / speed_mps
    times = (
        lead_in_s,
        lead_in_s + drive,
        lead_in_s + drive + stop_s,
        lead_in_s + 2 * drive + stop_s,
    )
    points = (
        (-edge, y, distance_m),
        (0.0, y, distance_m),
        (0.0, y, distance_m),
        (edge, y, distance_m),
    )
    robot = Cylinder(
        name="robot", trajectory=Waypoints(points, times), radius_m=r, height_m=height,
        colour_bgr=ROBOT_BGR, stripe_bgr=(40.0, 60.0, 200.0), stripe_half_width_m=0.015,
    )  # fmt: skip
    return _room(
        "robot_stop_go", mode, hfov_deg, skew, times[-1] + 0.3, [robot], seed, room,
        exposure_s, photometry, None,
    )  # fmt: skip


BOX_BGR = (60.0, 150.0, 200.0)


def robot_push_box(
    push_m: float = 0.6,
    *,
    mode: Mode = MODE_320x240_30,
    hfov_deg: float = 60.0,
    seed: int = 0,
    skew: Skew = 0.0,
    lead_in_s: float = 1.2,
    speed_mps: float = 0.5,
    distance_m: float = 1.8,
    after_s: float = 7.0,
    exposure_s: float = 0.0,
    photometry: Photometry | None = None,
) -> Scene:
    """A box stands on the floor at x = -0.3 m, ``distance_m`` in front of the rig, from the
    start; the round robot of :func:`robot_stop_go` drives in from the left, pushes it
    ``push_m`` to the right, backs out of the view the way it came, and the scene goes on for
    ``after_s`` with the box at its new place: where the box stood, the floor it hid is seen
    again (what a moved object leaves behind)."""
    room = Room()
    floor = room.floor_height_m if room.floor_height_m is not None else 0.35
    r, height = 0.10, 0.15
    half = (0.12, 0.08, 0.12)
    y_robot, y_box = floor - 0.5 * height, floor - half[1]
    box_x = -0.3
    contact = box_x - half[0] - r  # the robot's centre when it touches the box
    edge = distance_m * 0.6 + 0.5
    t_touch = lead_in_s + (contact + edge) / speed_mps
    t_pushed = t_touch + push_m / speed_mps
    t_out = t_pushed + (contact + push_m + edge) / speed_mps
    robot = Cylinder(
        name="robot",
        trajectory=Waypoints(
            ((-edge, y_robot, distance_m), (contact, y_robot, distance_m),
             (contact + push_m, y_robot, distance_m), (-edge, y_robot, distance_m)),
            (lead_in_s, t_touch, t_pushed, t_out),
        ),
        radius_m=r, height_m=height, colour_bgr=ROBOT_BGR, stripe_bgr=(40.0, 60.0, 200.0),
        stripe_half_width_m=0.015,
    )  # fmt: skip
    box = Box(
        name="box",
        trajectory=Waypoints(
            ((box_x, y_box, distance_m), (box_x, y_box, distance_m),
             (box_x + push_m, y_box, distance_m)),
            (0.0, t_touch, t_pushed), hold=True,
        ),
        half_size_m=half, colour_bgr=BOX_BGR,
    )  # fmt: skip
    return _room(
        "robot_push_box", mode, hfov_deg, skew, t_out + after_s, [robot, box], seed, room,
        exposure_s, photometry, None,
    )  # fmt: skip


PRESETS: dict[str, Callable[..., Scene]] = {
    **_BASE_PRESETS,
    "lamp_ball": lamp_ball,
    "lamp_ball_side": partial(lamp_ball, "side"),
    "person_sit_walk": person_sit_walk,
    "person_approach": person_approach,
    "people_crossing": people_crossing,
    "robot_stop_go": robot_stop_go,
    "robot_push_box": robot_push_box,
}
