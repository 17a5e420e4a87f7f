"""One room seen by several rigs: a scene whose objects move in a room frame, rendered from
each rig's pose.

A rig's pose is ``(t, (rx, ry, rz))``: a point p of the rig frame is ``R p + t`` in the room,
``R = Rz(rz) Ry(ry) Rx(rx)`` (deg, right-handed), written out here from first principles.
Each rig's scene is the room scene with every object's motion moved into that rig's frame
(``p_rig = R^T (p_room - t)``, velocities and accelerations turned by ``R^T``); the objects
are spheres, whose look does not depend on the side they are seen from. Each rig keeps its own
wall and floor (the background is each rig's, as a room's walls are for a rig in one corner):
rigs at one height turned about Y only share the floor plane.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ._base import F64, Vec3
from .camera import Clock, Rig
from .files import write_scene
from .motion import Motion, Trajectory, Waypoints
from .scene import Scene
from .shapes import Sphere
from .textures import Room


@dataclass(frozen=True)
class RigPlacement:
    """A rig's name and pose in the room: translation (m) and turns about X, Y, Z (deg)."""

    name: str
    translation_m: Vec3 = (0.0, 0.0, 0.0)
    rotation_deg: Vec3 = (0.0, 0.0, 0.0)

    def rotation(self) -> F64:
        """R (3, 3) with p_room = R p_rig + t: Rz(rz) Ry(ry) Rx(rx)."""
        x, y, z = (math.radians(a) for a in self.rotation_deg)
        rx = np.array([[1, 0, 0], [0, math.cos(x), -math.sin(x)], [0, math.sin(x), math.cos(x)]])
        ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
        rz = np.array([[math.cos(z), -math.sin(z), 0], [math.sin(z), math.cos(z), 0], [0, 0, 1]])
        return np.asarray(rz @ ry @ rx, dtype=np.float64)

    def to_rig(self, p_room: F64) -> F64:
        """A room point (m) in this rig's frame."""
        return np.asarray(self.rotation().T @ (np.asarray(p_room) - np.asarray(self.translation_m)))

    def toml(self) -> str:
        """This rig's ``[[room.rigs]]`` entry of a room file."""
        t = ", ".join(f"{v:.6f}" for v in self.translation_m)
        r = ", ".join(f"{v:.6f}" for v in self.rotation_deg)
        return f'[[room.rigs]]\nname = "{self.name}"\ntranslation_m = [{t}]\nrotation_deg = [{r}]\n'


def _vec(a: F64) -> Vec3:
    x, y, z = (float(v) for v in a)
    return (x, y, z)


def _moved(motion: Motion, pl: RigPlacement) -> Motion:
    r_t = pl.rotation().T
    if isinstance(motion, Trajectory):
        return dataclasses.replace(
            motion,
            p0_m=_vec(pl.to_rig(np.asarray(motion.p0_m))),
            v_mps=_vec(r_t @ np.asarray(motion.v_mps)),
            g_mps2=_vec(r_t @ np.asarray(motion.g_mps2)),
        )
    assert isinstance(motion, Waypoints)
    points = tuple(_vec(pl.to_rig(np.asarray(p))) for p in motion.points_m)
    return dataclasses.replace(motion, points_m=points)


def rig_scene(room_scene: Scene, placement: RigPlacement) -> Scene:
    """The room scene as the rig at ``placement`` sees it (objects in its frame); its objects
    must be spheres (they look the same from any side)."""
    objects: list[Sphere] = []
    for obj in room_scene.objects:
        if not isinstance(obj, Sphere):
            raise ValueError(f"{obj.name}: a room seen by several rigs holds spheres only")
        objects.append(dataclasses.replace(obj, trajectory=_moved(obj.trajectory, placement)))
    return dataclasses.replace(
        room_scene, objects=tuple(objects), name=f"{room_scene.name}_{placement.name}"
    )


def room_toml(name: str, placements: list[RigPlacement]) -> str:
    """A room file (TOML) of the placements."""
    return f'[room]\nname = "{name}"\n\n' + "\n".join(p.toml() for p in placements)


def write_room(
    room_scene: Scene, placements: list[RigPlacement], out_dir: str | Path, name: str = "lab"
) -> Path:
    """Render the room from every placement into ``out_dir/<rig>/`` (as :func:`write_scene`)
    and write ``out_dir/room.toml``; returns ``out_dir``."""
    out = Path(out_dir)
    for pl in placements:
        write_scene(rig_scene(room_scene, pl), out / pl.name)
    (out / "room.toml").write_text(room_toml(name, placements))
    return out


THREE_RIGS = [
    RigPlacement("a"),
    RigPlacement("b", (2.0, 0.0, 0.0), (0.0, 10.0, 0.0)),
    RigPlacement("c", (-3.2, 0.0, 0.0), (0.0, -10.0, 0.0)),
]
"""Rigs a and b side by side, b turned 10 deg to the right (their views overlap from 0.9 to
1.7 m across, 3 m ahead); c far to the left turned left, its view disjoint from a's."""


def three_rig_room(
    *,
    duration_s: float = 4.5,
    lead_in_s: float = 0.8,
    speed_mps: float = 1.2,
    fps: float = 15.0,
    seed: int = 0,
) -> tuple[Scene, list[RigPlacement]]:
    """Three rigs and two balls rolling on the floor 3 m ahead: ``walker`` crosses from a's
        view through a and b's overlap into b's alone (a handover), ``lone`` rolls in c's view
        only. Both appear after ``lead_in_s`` (the background is learnt first). The scene's objects
    are in the room frame (rig a's)."""
    room = Room(wall_distance_m=8.0)
    assert room.floor_height_m is not None
    radius = 0.1
    y = room.floor_height_m - radius
    walker = Sphere(
        name="walker",
        trajectory=Trajectory(
            (-1.2, y, 3.0), (speed_mps, 0.0, 0.0), t_ref_s=lead_in_s, t_start_s=lead_in_s
        ),
        radius_m=radius,
        colour_bgr=(45.0, 125.0, 215.0),
    )
    lone = Sphere(
        name="lone",
        trajectory=Trajectory(
            (-3.6, y, 3.2), (0.0, 0.0, -0.3), t_ref_s=lead_in_s, t_start_s=lead_in_s
        ),
        radius_m=radius,
        colour_bgr=(200.0, 120.0, 50.0),
    )
    clock = Clock(period_s=1.0 / fps)
    scene = Scene(
        rig=Rig(320, 240, 60.0, 0.06),
        left_clock=clock,
        right_clock=clock,
        objects=(walker, lone),
        room=room,
        seed=seed,
        duration_s=duration_s,
        name="three_rigs",
    )
    return scene, list(THREE_RIGS)


CROSSING_RIGS = [
    RigPlacement("a"),
    RigPlacement("b", (4.0, 0.0, 4.0), (0.0, -90.0, 0.0)),
]
"""Rig a at the origin looking along +Z, rig b at (4, 0, 4) m looking along -X: views at right
angles, each one's depth the other's across (the overlap holds the balls of
:func:`crossing_room`)."""


def crossing_room(
    *, duration_s: float = 5.0, lead_in_s: float = 0.8, fps: float = 15.0, seed: int = 0
) -> tuple[Scene, list[RigPlacement]]:
    """Two rigs at right angles (:data:`CROSSING_RIGS`) and two balls rolling side by side at
    0.7 m/s through the overlap of their views for the whole scene after ``lead_in_s``: what a
    clock offset between the rigs is measured from. Room frame: rig a's."""
    room = Room(wall_distance_m=8.0)
    assert room.floor_height_m is not None
    radius = 0.1
    y = room.floor_height_m - radius
    v = (0.55, 0.0, 0.44)
    balls = tuple(
        Sphere(
            name=name,
            trajectory=Trajectory(start, v, t_ref_s=lead_in_s, t_start_s=lead_in_s),
            radius_m=radius,
            colour_bgr=colour,
        )
        for name, start, colour in (
            ("near", (0.0, y, 2.5), (45.0, 125.0, 215.0)),
            ("far", (-0.5, y, 3.125), (200.0, 120.0, 50.0)),
        )
    )
    clock = Clock(period_s=1.0 / fps)
    scene = Scene(
        rig=Rig(320, 240, 60.0, 0.06),
        left_clock=clock,
        right_clock=clock,
        objects=balls,
        room=room,
        seed=seed,
        duration_s=duration_s,
        name="crossing_rigs",
    )
    return scene, list(CROSSING_RIGS)
