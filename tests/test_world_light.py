"""Lamps and cast shadows of the independent renderer, against closed forms."""

from __future__ import annotations

import json
import math

import numpy as np

from stereod_fakes.world import (
    Lamps,
    Photometry,
    PointLight,
    Quality,
    Rig,
    Room,
    Scene,
    Sphere,
    Trajectory,
    lamp_ball,
)

NO_PHOTOMETRY = Photometry(left_gain=1.0, right_gain=1.0, drift_amplitude=0.0, noise_sigma=0.0)
WALL = 200.0


def shadow_conic_centre(
    light: np.ndarray, centre: np.ndarray, r: float, axis: int, plane: float
) -> np.ndarray:
    """Centre of the shadow a sphere casts from a point light on the plane X[axis] = plane:
    the tangent cone (X-L)^T (a a^T - cos^2 I) (X-L) = 0 cut by the plane is a conic whose
    centre u solves M2 u = -h m (M2: the in-plane block, m: the cross terms, h: the height)."""
    dist = np.linalg.norm(centre - light)
    a = (centre - light) / dist
    m = np.outer(a, a) - (1.0 - (r / dist) ** 2) * np.eye(3)
    keep = [i for i in range(3) if i != axis]
    h = plane - light[axis]
    u = -h * np.linalg.solve(m[np.ix_(keep, keep)], m[keep, axis])
    pt = np.empty(3)
    pt[keep] = light[keep] + u
    pt[axis] = plane
    return pt


def conic_area(light: np.ndarray, centre: np.ndarray, r: float, axis: int, plane: float) -> float:
    """Area of the shadow ellipse (numerically, on a fine grid of the plane; test helper)."""
    dist = np.linalg.norm(centre - light)
    a = (centre - light) / dist
    cos_a = math.sqrt(1.0 - (r / dist) ** 2)
    g = np.linspace(-3.0, 3.0, 3001)
    xx, yy = np.meshgrid(g, g)
    pts = np.zeros((*xx.shape, 3))
    keep = [i for i in range(3) if i != axis]
    pts[..., keep[0]], pts[..., keep[1]] = xx, yy
    pts[..., axis] = plane
    d = pts - light
    inside = (d @ a) >= cos_a * np.linalg.norm(d, axis=-1)
    return float(inside.sum() * (g[1] - g[0]) ** 2)


def wall_scene(light: tuple[float, float, float], ball: Sphere, **kw: object) -> Scene:
    return Scene(
        rig=Rig(160, 120, 60.0),
        objects=(ball,),
        photometry=NO_PHOTOMETRY,
        room=Room(
            wall_distance_m=3.0,
            floor_height_m=None,
            texture="flat",
            flat_wall_bgr=(WALL, WALL, WALL),
        ),
        lamps=Lamps(ambient=0.0, points=(PointLight(light, intensity=1.0),)),
        **kw,  # type: ignore[arg-type]
    )


def test_sphere_shadow_on_the_wall_is_the_cone_section_ellipse() -> None:
    light = np.array([-1.2, -0.2, 0.4])
    centre = np.array([-0.5, 0.05, 1.6])
    r = 0.12
    ball = Sphere(name="ball", trajectory=Trajectory(tuple(centre)), radius_m=r)
    scene = wall_scene(tuple(light), ball, quality=Quality(shadow_supersample=8))
    rig = scene.rig
    lit = scene.background_radiance("left")[..., 1].astype(np.float64)
    img = scene.render_radiance("left", scene.t0_ns)[..., 1].astype(np.float64)
    shadow = 1.0 - img / lit
    # Keep the wall only: drop the pixels whose rays can meet the ball (and their neighbours).
    f = rig.focal_px
    vv, uu = np.mgrid[0 : rig.height_px, 0 : rig.width_px]
    cam = rig.camera_centre("left")
    rays = np.stack([(uu - rig.cx) / f, (vv - rig.cy) / f, np.ones(uu.shape)], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    oc = centre - cam
    gap = np.linalg.norm(np.cross(rays, oc), axis=-1)
    shadow[gap < r + 2.0 * np.linalg.norm(oc) / f] = 0.0
    assert shadow.max() > 0.99 and shadow.min() > -1e-4
    expected = shadow_conic_centre(light, centre, r, axis=2, plane=3.0)
    area_m2 = conic_area(light, centre, r, axis=2, plane=3.0)
    # The wall is parallel to the image: the image of the ellipse is scaled by f / Z.
    eu = rig.cx + f * (expected[0] - cam[0]) / 3.0
    ev = rig.cy + f * expected[1] / 3.0
    mass = shadow.sum()
    assert abs((shadow * uu).sum() / mass - eu) < 0.05
    assert abs((shadow * vv).sum() / mass - ev) < 0.05
    assert abs(mass - area_m2 * (f / 3.0) ** 2) < 0.01 * mass
    # Without lamps the same scene has no shadow at all (today's unlit look).
    unlit = Scene(rig=rig, objects=(ball,), photometry=NO_PHOTOMETRY, room=scene.room)
    bg = unlit.background_radiance("left")
    seen = unlit.render_radiance("left", unlit.t0_ns)
    far = gap > r + 2.0 * np.linalg.norm(oc) / f
    assert np.array_equal(seen[far], bg[far])


def test_overhead_lamp_shadow_on_the_floor_is_the_disc_under_the_ball() -> None:
    floor = 0.35
    r, height = 0.1, 1.2  # the lamp is right above the centre of the ball
    centre = np.array([0.05, floor - 0.3, 1.5])  # floating 0.2 m above the floor
    light = centre + np.array([0.0, -height, 0.0])
    ball = Sphere(name="ball", trajectory=Trajectory(tuple(centre)), radius_m=r)
    scene = Scene(
        rig=Rig(160, 120, 60.0),
        objects=(ball,),
        photometry=NO_PHOTOMETRY,
        room=Room(floor_height_m=floor, texture="flat", flat_floor_bgr=(WALL, WALL, WALL)),
        lamps=Lamps(ambient=0.0, points=(PointLight(tuple(light), intensity=1.0),)),
    )
    rig = scene.rig
    f = rig.focal_px
    lit = scene.background_radiance("left")[..., 1].astype(np.float64)
    img = scene.render_radiance("left", scene.t0_ns)[..., 1].astype(np.float64)
    vv, uu = np.mgrid[0 : rig.height_px, 0 : rig.width_px]
    dy = (vv - rig.cy) / f
    on_floor = dy * 4.0 > floor
    cam = rig.camera_centre("left")
    s = np.where(on_floor, floor / np.where(on_floor, dy, 1.0), np.inf)
    fx, fz = cam[0] + s * (uu - rig.cx) / f, s
    # Closed form: a cone of half angle asin(r / h) about the vertical: a disc of radius
    # (h + drop) tan(asin(r / h)) centred under the lamp.
    drop = floor - centre[1]
    radius = (height + drop) * math.tan(math.asin(r / height))
    dist = np.hypot(fx - centre[0], fz - centre[2])
    step = s * s / (f * floor)  # floor distance between neighbouring rows, m
    rays = np.stack([(uu - rig.cx) / f, dy, np.ones(uu.shape)], axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    gap = np.linalg.norm(np.cross(rays, centre - cam), axis=-1)
    # Floor pixels well clear of the ball's image (its edge pixels are re-cast finely).
    clear = on_floor & (gap > r + 0.05)
    inside = clear & (dist < radius - 1.5 * step)
    outside = clear & (dist > radius + 1.5 * step)
    assert inside.sum() > 20 and outside.sum() > 1000
    assert np.all(img[inside] < 1e-3 * lit[inside])
    assert np.all(img[outside] == lit[outside])


def test_lamps_light_objects_with_lambert_and_ambient() -> None:
    centre = np.array([0.0, 0.0, 1.5])
    r = 0.25
    light = np.array([0.6, -0.8, 0.7])
    col = 200.0
    ball = Sphere(name="ball", trajectory=Trajectory(tuple(centre)), radius_m=r,
                  colour_bgr=(col, col, col))  # fmt: skip
    ambient, intensity, ref = 0.2, 0.9, 2.0
    scene = Scene(
        rig=Rig(120, 90, 60.0),
        objects=(ball,),
        photometry=NO_PHOTOMETRY,
        room=Room(floor_height_m=None, texture="flat"),
        lamps=Lamps(ambient=ambient, points=(PointLight(tuple(light), intensity, ref),)),
    )
    rig = scene.rig
    img = scene.render_radiance("left", scene.t0_ns)[..., 0].astype(np.float64)
    cam = rig.camera_centre("left")
    f = rig.focal_px
    checked = 0
    for u, v in ((60, 45), (70, 38), (52, 50), (64, 40), (58, 55)):
        d = np.array([(u - rig.cx) / f, (v - rig.cy) / f, 1.0])
        oc = cam - centre
        b = oc @ d
        disc = b * b - (d @ d) * (oc @ oc - r * r)
        assert disc > 0.0
        p = cam + (-b - math.sqrt(disc)) / (d @ d) * d
        n = (p - centre) / r
        to_l = light - p
        cos = max(0.0, n @ to_l / np.linalg.norm(to_l))
        expected = col * (ambient + intensity * ref**2 * cos / (to_l @ to_l))
        assert abs(img[v, u] - expected) < 0.01 * expected
        checked += 1
    assert checked == 5


def test_lamp_presets_cast_a_shadow_on_the_floor_next_to_the_ball() -> None:
    over = lamp_ball("overhead", mode=(160, 120, 30.0))
    side = lamp_ball("side", mode=(160, 120, 30.0))
    for scene in (over, side):
        t = scene.to_ns(scene.objects[0].trajectory.t_ref_s)
        darker = (scene.background_radiance("left") - scene.render_radiance("left", t)).sum(2)
        ball = scene.truth(t)["ball"][0]
        u, v = scene.rig.project("left", ball)
        rows, cols = np.nonzero(darker > 5.0)
        assert rows.size > 10
        assert rows.max() > v  # the shadow reaches below the ball's centre in the image
        if scene is side:  # lamp on the left: the long shadow stretches to the right
            assert cols.max() > u + 8
        else:
            assert cols.max() < u + 8


def test_lamps_survive_scene_json() -> None:
    for scene in (lamp_ball("side", soft=True), lamp_ball("overhead")):
        back = Scene.from_dict(json.loads(json.dumps(scene.to_dict())))
        assert back == scene and back.lamps == scene.lamps
    assert Scene.from_dict(json.loads(json.dumps(Scene().to_dict()))).lamps is None
