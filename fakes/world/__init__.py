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
height), with seeded procedural colour textures defined in world coordinates (bilinear
over a ``Room.texel_m`` grid: multi-octave value noise, palette blends, posters, floor tiles),
so the parallax between the eyes is exact.
Objects (spheres, upright cylinders, axis-aligned boxes, capsules of any orientation;
centre = centre of the volume) translate without rotating, along a :class:`Trajectory` or a
piecewise-linear :class:`Waypoints` path (stops).  A :class:`Person` is an object made of
capsules and a sphere, scripted by :class:`Act` steps (sit and wave, stand up, walk with
swinging arms and legs, stand still; see ``people.py``); its truth centre is the torso's
centroid, and ``Scene.truth_details`` adds the volume centroid of the figure and its
axis-aligned extent.  Photometry: ``image = clip(round(radiance * eye_gain * drift(t) +
noise))`` with Gaussian noise seeded by (seed, eye, t_ns), so any frame can be re-rendered
identically.

Light
-----
Without lamps (``Scene.lamps = None``, the default) the wall and floor are unlit and the
objects are Lambertian under one directional light plus ambient, without shadows; such
scenes render bit-identically to the renderer before lamps existed.  With :class:`Lamps`
(point lights, and rectangular area lights sampled on a grid; inverse-square falloff) every
surface (wall, floor, objects) is ``albedo * (ambient + sum of visible irradiance *
max(0, n . l))``, visibility being a shadow ray from the surface point to each lamp sample
tested against every solid: hard shadows from point lamps, soft ones from area lamps
(``background.py`` says how the shadowed pixels of the wall and floor are sampled).

Transport
---------
``Scene.transport`` (:class:`Transport`, all off by default) models the webcam: a rolling
shutter (row r starts ``r * readout_s / H`` after row 0 and is cast at its own instants),
100 Hz mains flicker integrated over each row's exposure, 4:2:2 chroma (YUYV) and MJPEG; see
``transport.py``.  ``t_ns`` and the truth stay the instant row 0 starts exposing;
``readout_s`` is written to scene.json and truth.csv.

Cost
----
A frame in which nothing moves during its readout and exposure is kept, and the next frame
with the same content reuses it, so long stops render once.  People and shadows cost more
than balls: at 320x240 a walking person takes about 0.3 s per frame, 0.9 s under a lamp, and
7 s with an exact rolling shutter (each row is cast on its own; ``Quality.rolling_band_rows``
trades exactness for time).

Modules: ``scene`` (Scene, timing, truth, rendering), ``files`` (write_scene, load_scene),
``shapes``, ``motion``, ``people``, ``light``, ``background`` (wall, floor, shadows),
``raycast`` (object regions), ``camera`` (rig, clocks, photometry, quality), ``textures``,
``transport``, ``presets`` and ``presets_room``, ``rooms`` (one room seen by several
rigs, each from its pose), ``cli``.
"""

from __future__ import annotations

from ._base import EYES, MODE_320x240_30, MODE_640x480_15
from .camera import Clock, Photometry, Quality, RenderedFrame, Rig, clocks_for_skew
from .cli import main
from .files import load_scene, write_scene
from .light import AreaLight, Lamps, Lighting, PointLight
from .motion import Trajectory, Waypoints
from .people import Act, Person
from .presets import crossing, fast_ball, robot_ball, robot_box, robot_cylinder
from .presets_room import (
    PRESETS,
    lamp_ball,
    people_crossing,
    person_approach,
    person_sit_walk,
    robot_push_box,
    robot_stop_go,
)
from .scene import Scene
from .shapes import Box, Capsule, Cylinder, Shape, Sphere
from .textures import Room
from .transport import Transport

__all__ = [
    "EYES",
    "PRESETS",
    "Act",
    "AreaLight",
    "Box",
    "Capsule",
    "Clock",
    "Cylinder",
    "Lamps",
    "Lighting",
    "MODE_320x240_30",
    "MODE_640x480_15",
    "Person",
    "Photometry",
    "PointLight",
    "Quality",
    "RenderedFrame",
    "Rig",
    "Room",
    "Scene",
    "Shape",
    "Sphere",
    "Trajectory",
    "Transport",
    "Waypoints",
    "clocks_for_skew",
    "crossing",
    "fast_ball",
    "lamp_ball",
    "load_scene",
    "main",
    "people_crossing",
    "person_approach",
    "person_sit_walk",
    "robot_ball",
    "robot_box",
    "robot_cylinder",
    "robot_push_box",
    "robot_stop_go",
    "write_scene",
]
