"""Tests of the independent stereo renderer, each against a closed form or a brute-force model."""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod_fakes.world import (
    Box,
    Clock,
    Cylinder,
    Lighting,
    Photometry,
    Quality,
    Rig,
    Room,
    Scene,
    Sphere,
    Trajectory,
    clocks_for_skew,
    crossing,
    fast_ball,
    load_scene,
    robot_ball,
    robot_box,
    robot_cylinder,
    write_scene,
)

BG = 50.0  # flat background grey level
FG = 250.0  # flat object grey level (ambient-only lighting)
FLAT_ROOM = Room(floor_height_m=None, texture="flat", flat_wall_bgr=(BG, BG, BG))
UNLIT = Lighting(ambient=1.0, diffuse=0.0)
NO_PHOTOMETRY = Photometry(left_gain=1.0, right_gain=1.0, drift_amplitude=0.0, noise_sigma=0.0)


def flat_scene(objects: tuple, rig: Rig | None = None, **kw: object) -> Scene:
    return Scene(
        rig=rig or Rig(160, 120, 60.0),
        objects=objects,
        lighting=UNLIT,
        photometry=NO_PHOTOMETRY,
        room=FLAT_ROOM,
        **kw,  # type: ignore[arg-type]
    )


def still(p: tuple[float, float, float]) -> Trajectory:
    return Trajectory(p)


def alpha(scene: Scene, eye: str, t_ns: int | None = None) -> np.ndarray:
    """Object coverage per pixel from a background-subtracted, noise-free render."""
    img = scene.render_radiance(eye, scene.t0_ns if t_ns is None else t_ns)
    return (img[..., 1].astype(np.float64) - BG) / (FG - BG)


def centroid(a: np.ndarray) -> tuple[float, float, float]:
    vv, uu = np.mgrid[0 : a.shape[0], 0 : a.shape[1]]
    return float((a * uu).sum() / a.sum()), float((a * vv).sum() / a.sum()), float(a.sum())


def sphere_ellipse(rig: Rig, eye: str, centre: np.ndarray, r: float) -> tuple[float, float, float]:
    """Exact image ellipse of a sphere: tangent cone d^T (p p^T - (|p|^2 - r^2) I) d = 0."""
    p = np.asarray(centre, float) - rig.camera_centre(eye)
    m = np.outer(p, p) - (p @ p - r * r) * np.eye(3)
    c = np.linalg.solve(m[:2, :2], -m[:2, 2])  # centre of the conic in normalised coordinates
    area = math.pi * abs(np.linalg.det(m)) / np.linalg.det(m[:2, :2]) ** 1.5
    f = rig.focal_px
    return rig.cx + f * c[0], rig.cy + f * c[1], area * f * f


def polygon_centroid(pts: np.ndarray) -> tuple[float, float, float]:
    hull = cv2.convexHull(pts.astype(np.float64).astype(np.float32)).reshape(-1, 2)
    x, y = hull[:, 0].astype(np.float64), hull[:, 1].astype(np.float64)
    cr = x * np.roll(y, -1) - np.roll(x, -1) * y
    a = cr.sum() / 2
    return (
        float(((x + np.roll(x, -1)) * cr).sum() / (6 * a)),
        float(((y + np.roll(y, -1)) * cr).sum() / (6 * a)),
        abs(float(a)),
    )


# --------------------------------------------------------------------------------------------


def test_pinhole_conventions() -> None:
    rig = Rig(640, 480, 42.0, 0.06)
    assert rig.cx == 319.5 and rig.cy == 239.5
    # The outer edge of the first / last column (u = -0.5, W - 0.5) is at +-hfov/2.
    half = math.radians(21.0)
    uv = rig.project("left", [[-0.03 - math.tan(half), 0.0, 1.0], [-0.03 + math.tan(half), 0, 1]])
    np.testing.assert_allclose(uv[:, 0], [-0.5, 639.5], atol=1e-9)
    p = np.array([0.2, -0.1, 2.5])
    d = rig.project("left", p)[0] - rig.project("right", p)[0]
    assert d == pytest.approx(rig.focal_px * 0.06 / 2.5, rel=1e-12)


@pytest.mark.parametrize("seed", range(8))
def test_sphere_silhouette_centroid_is_exact_ellipse_centre(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rig = Rig(160, 120, 60.0)
    centre = (rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), rng.uniform(0.8, 3.0))
    r = float(rng.uniform(0.03, 0.1))
    ball = Sphere(name="s", radius_m=r, trajectory=still(centre), colour_bgr=(FG, FG, FG))
    scene = flat_scene((ball,), rig)
    for eye in ("left", "right"):
        a = alpha(scene, eye)
        u, v, area = centroid(a)
        eu, ev, earea = sphere_ellipse(rig, eye, np.array(centre), r)
        assert math.hypot(u - eu, v - ev) < 0.05
        assert area == pytest.approx(earea, rel=5e-3)
        assert scene.coverage(eye, scene.t0_ns)["s"] == pytest.approx(area, rel=1e-3)


@pytest.mark.parametrize("du", [0.0, 0.13, 0.25, 0.5, 0.77])
def test_on_axis_sphere_centroid_tracks_subpixel_shift(du: float) -> None:
    """A sphere on the ray through (cx + du, cy + du/2) projects there (symmetric ellipse)."""
    rig = Rig(161, 121, 50.0)  # odd sizes: principal point on a pixel centre
    z = 1.5
    f = rig.focal_px
    cam = rig.camera_centre("left")
    d = np.array([du / f, 0.5 * du / f, 1.0])
    centre = cam + d / np.linalg.norm(d) * z
    ball = Sphere(name="s", radius_m=0.05, trajectory=still(tuple(centre)), colour_bgr=(FG,) * 3)
    u, v, _ = centroid(alpha(flat_scene((ball,), rig), "left"))
    eu, ev, _ = sphere_ellipse(rig, "left", centre, 0.05)
    assert abs(u - eu) < 0.05 and abs(v - ev) < 0.05
    assert abs(u - (rig.cx + du)) < 0.06 and abs(v - (rig.cy + du / 2)) < 0.06


def test_box_and_cylinder_silhouettes_match_projected_convex_hulls() -> None:
    rig = Rig(200, 150, 60.0)
    box = Box(name="b", half_size_m=(0.12, 0.07, 0.09), trajectory=still((0.25, 0.15, 1.4)))
    cyl = Cylinder(name="c", radius_m=0.1, height_m=0.15, trajectory=still((-0.3, 0.2, 1.6)))
    for solid in (box, cyl):
        solid = type(solid)(**{**solid.__dict__, "colour_bgr": (FG, FG, FG)})
        scene = flat_scene((solid,), rig)
        c = np.asarray(solid.trajectory.p0_m)
        if isinstance(solid, Box):
            h = np.asarray(solid.half_size_m)
            signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
            pts = c + signs * h
        else:
            ang = np.linspace(0, 2 * np.pi, 4000, endpoint=False)
            ring = np.stack([np.cos(ang), np.zeros_like(ang), np.sin(ang)], 1) * solid.radius_m
            pts = np.concatenate([c + ring + [0, y, 0] for y in (-0.075, 0.075)])
        for eye in ("left", "right"):
            u, v, area = centroid(alpha(scene, eye))
            eu, ev, earea = polygon_centroid(rig.project(eye, pts))
            assert math.hypot(u - eu, v - ev) < 0.05, (type(solid).__name__, eye)
            assert area == pytest.approx(earea, rel=5e-3)


def test_antialiased_pixels_match_brute_force_coverage() -> None:
    """Every pixel equals bg + (fg - bg) * coverage, coverage by 32x32 point sampling."""
    rig = Rig(64, 48, 60.0)
    centres = [(0.05, 0.02, 0.9), (-0.08, -0.01, 1.4)]
    radii = [0.08, 0.1]
    balls = tuple(
        Sphere(name=f"s{i}", radius_m=r, trajectory=still(c), colour_bgr=(FG,) * 3)
        for i, (c, r) in enumerate(zip(centres, radii))
    )
    got = alpha(flat_scene(balls, rig), "right")
    n = 32
    offs = (np.arange(n) + 0.5) / n - 0.5
    u = (np.arange(64)[:, None] + offs).ravel()
    v = (np.arange(48)[:, None] + offs).ravel()
    f = rig.focal_px
    d = np.stack(
        np.broadcast_arrays(((u - rig.cx) / f)[None], ((v - rig.cy) / f)[:, None], 1.0), -1
    )
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    hit = np.zeros(d.shape[:2], bool)
    for c, r in zip(centres, radii):
        p = np.asarray(c) - rig.camera_centre("right")
        along = d @ p
        hit |= (p @ p - along**2 <= r * r) & (along > 0)
    want = hit.reshape(48, n, 64, n).mean(axis=(1, 3))
    assert np.abs(got - want).max() < 0.04
    assert abs(got.sum() - want.sum()) < 0.01 * want.sum()


def test_region_render_equals_full_frame_render(monkeypatch: pytest.MonkeyPatch) -> None:
    """Re-casting only the objects' regions gives exactly what casting every pixel gives."""
    base = crossing(seed=2, mode=(200, 150, 30.0))
    extra = (
        Box(
            name="box",
            half_size_m=(0.1, 0.05, 0.1),
            trajectory=still((0.1, 0.2, 1.2)),
            stripe_bgr=(0, 0, 255),
            stripe_half_width_m=0.01,
        ),
        Cylinder(name="cyl", radius_m=0.1, height_m=0.2, trajectory=still((-0.15, 0.25, 1.7))),
    )
    scene = replace(base, objects=base.objects + extra)
    t = scene.to_ns(base.objects[0].trajectory.t_ref_s)
    regional = {eye: scene.render_radiance(eye, t) for eye in ("left", "right")}
    cov = {eye: scene.coverage(eye, t) for eye in ("left", "right")}
    monkeypatch.setattr(Scene, "_pixel_rect", lambda self, eye, lo, hi, margin: (0, 150, 0, 200))
    for eye in ("left", "right"):
        assert np.array_equal(regional[eye], scene.render_radiance(eye, t))
        assert cov[eye] == scene.coverage(eye, t)
        assert all(a > 0 for a in cov[eye].values())


def test_background_texture_is_the_world_texture_at_each_ray_hit() -> None:
    rig = Rig(160, 120, 60.0, 0.06)
    scene = Scene(
        rig=rig,
        room=Room(wall_distance_m=4.0, floor_height_m=0.35),
        quality=Quality(background_supersample=1),
        seed=3,
    )
    f, zw, yf = rig.focal_px, 4.0, 0.35
    vv, uu = np.mgrid[0:120, 0:160]
    dx, dy = (uu - rig.cx) / f, (vv - rig.cy) / f
    horizon = rig.cy + f * yf / zw  # rows below it see the floor
    for eye in ("left", "right"):
        img = scene.background_radiance(eye)
        cam_x = rig.camera_centre(eye)[0]
        wall = vv < horizon
        want_wall = scene.wall_radiance(cam_x + zw * dx[wall], zw * dy[wall])
        s = yf / dy[~wall]
        want_floor = scene.floor_radiance(cam_x + s * dx[~wall], s)
        err_w = np.abs(img[wall] - want_wall)
        err_f = np.abs(img[~wall] - want_floor)
        assert np.median(err_w) < 0.3 and err_w.max() < 3.0
        assert np.median(err_f) < 0.3 and err_f.max() < 3.0
        assert img.std() > 20  # actually textured


def test_wall_disparity_is_baseline_times_focal_over_depth() -> None:
    """With the wall at Z = f B / d (d integer), the pixel footprints of L[u] and R[u - d] are
    the same patch of wall, so the box-filtered images must agree exactly (and not at d +- 1)."""
    rig = Rig(320, 240, 60.0, 0.06)
    for d in (5, 8):
        zw = rig.focal_px * 0.06 / d
        scene = Scene(rig=rig, room=Room(wall_distance_m=zw, floor_height_m=None), seed=5)
        left = scene.background_radiance("left").astype(np.float64)
        right = scene.background_radiance("right").astype(np.float64)
        err = np.abs(left[:, d:] - right[:, :-d])
        assert np.median(err) < 0.02 and err.mean() < 0.05
        for wrong in (d - 1, d + 1):
            assert np.abs(left[:, wrong:] - right[:, :-wrong]).mean() > 20 * err.mean() + 0.5


def test_nearer_object_wins_and_full_occlusion_is_invisible() -> None:
    rig = Rig(160, 120, 60.0)
    cam = tuple(rig.camera_centre("left"))
    red = Sphere(
        name="red", radius_m=0.1, trajectory=still((cam[0], 0, 1.0)), colour_bgr=(0, 0, 200)
    )
    blue = Sphere(
        name="blue", radius_m=0.05, trajectory=still((cam[0], 0, 2.0)), colour_bgr=(200, 0, 0)
    )
    scene = flat_scene((red, blue), rig)
    img = scene.render_radiance("left", scene.t0_ns)
    np.testing.assert_allclose(img[60, 80], [0, 0, 200], atol=1e-3)
    assert not scene.visible("blue", "left", scene.t0_ns)
    assert scene.visible("red", "left", scene.t0_ns)
    # Swap depths: now the blue one is in front.
    red2 = Sphere(
        name="red", radius_m=0.2, trajectory=still((cam[0], 0, 2.0)), colour_bgr=(0, 0, 200)
    )
    blue2 = Sphere(
        name="blue", radius_m=0.05, trajectory=still((cam[0], 0, 1.0)), colour_bgr=(200, 0, 0)
    )
    scene2 = flat_scene((red2, blue2), rig)
    np.testing.assert_allclose(scene2.render_radiance("left", scene.t0_ns)[60, 80], [200, 0, 0])
    assert scene2.visible("red", "left", scene.t0_ns)


def test_lambert_shading_closed_form() -> None:
    light = Lighting(towards_light=(0.0, 0.0, -1.0), ambient=0.2, diffuse=0.8)
    rig = Rig(161, 121, 40.0)
    cam = rig.camera_centre("left")
    ball = Sphere(
        name="b", radius_m=0.2, trajectory=still((cam[0], 0.0, 1.5)), colour_bgr=(100,) * 3
    )
    scene = Scene(
        rig=rig, objects=(ball,), lighting=light, photometry=NO_PHOTOMETRY, room=FLAT_ROOM
    )
    img = scene.render_radiance("left", scene.t0_ns)
    assert img[60, 80, 0] == pytest.approx(100.0, abs=0.01)  # facing the light: 0.2 + 0.8
    # Pixel at normalised x: hit point on the sphere, normal . (0,0,-1) closed form.
    du = 20
    x = du / rig.focal_px
    dn = np.array([x, 0, 1]) / math.hypot(x, 1)
    along = dn[2] * 1.5
    s = along - math.sqrt(along**2 - (1.5**2 - 0.04))
    n = (s * dn - [0, 0, 1.5]) / 0.2
    assert img[60, 80 + du, 0] == pytest.approx(100 * (0.2 + 0.8 * -n[2]), abs=0.3)


def test_clock_skew_wanders_over_half_a_frame_each_way() -> None:
    scene = robot_ball(90, skew="wander", seed=1)
    left = np.array(scene.frame_times("left"))
    right = np.array(scene.frame_times("right"))
    period_ns = 1e9 / 30
    for t in (left, right):
        assert np.all(np.diff(t) > 0)
    nearest = left[np.argmin(np.abs(right[:, None] - left[None, :]), axis=1)]
    skew = (right - nearest) / period_ns
    assert -0.5 < skew.min() < -0.48 and 0.48 < skew.max() < 0.5
    assert np.all(np.diff(skew) > 0)  # drifts monotonically (constant period difference)
    t_s = (right - scene.t0_ns) * 1e-9
    np.testing.assert_allclose(skew, -0.5 + t_s / scene.duration_s, atol=1e-6)
    np.testing.assert_allclose(scene.skew_frames(), skew, atol=1e-9)
    fixed = robot_ball(90, skew=0.3)
    lf, rf = np.array(fixed.frame_times("left")), np.array(fixed.frame_times("right"))
    n = min(lf.size, rf.size)
    np.testing.assert_allclose((rf[:n] - lf[:n]) / period_ns, 0.3, atol=1e-6)
    neg = robot_ball(90, skew=-0.25)
    np.testing.assert_allclose(neg.skew_frames(), -0.25, atol=1e-6)


def test_clocks_with_jitter_and_frame_order() -> None:
    left, right = clocks_for_skew(30.0, 0.0, 0.0, 2.0, jitter_s=0.002)
    scene = flat_scene((), Rig(32, 24), left_clock=left, right_clock=right, duration_s=2.0)
    for eye in ("left", "right"):
        t = np.array(scene.frame_times(eye))
        assert np.all(np.diff(t) > 0) and t[0] >= scene.t0_ns
        assert np.abs(np.diff(t) - 1e9 / 30).max() < 0.5 * 1e9 / 30
        assert np.abs(np.diff(t) - 1e9 / 30).max() > 1e5  # jitter present
    frames = list(scene.frames())
    keys = [(f.t_ns, f.eye != "left") for f in frames]
    assert keys == sorted(keys)
    for eye in ("left", "right"):
        assert [f.seq for f in frames if f.eye == eye] == list(range(len(scene.frame_times(eye))))
    # Ties between eyes: left first.
    tie = flat_scene((), Rig(32, 24), left_clock=Clock(0.1), right_clock=Clock(0.1), duration_s=0.3)
    assert [f.eye for f in tie.frames()] == ["left", "right"] * 3


def test_truth_velocity_is_derivative_of_position_and_presence() -> None:
    scene = fast_ball("radial", 15.0, seed=2)
    tr = scene.objects[0].trajectory
    assert not scene.truth(scene.to_ns(1.0))  # lead-in: nothing present
    present = [t for t in scene.all_frame_times() if scene.truth(t)]
    assert present
    h_ns = 100_000
    p0, v0, g = (np.asarray(a) for a in (tr.p0_m, tr.v_mps, tr.g_mps2))
    for t_ns in present:
        dt = scene.time_s(t_ns) - tr.t_ref_s
        p, v = scene.truth(t_ns)["ball"]
        np.testing.assert_allclose(p, p0 + v0 * dt + 0.5 * g * dt**2, atol=1e-12)
        before, after = scene.truth(t_ns - h_ns), scene.truth(t_ns + h_ns)
        if "ball" in before and "ball" in after:
            fd = (after["ball"][0] - before["ball"][0]) / (2 * h_ns * 1e-9)
            np.testing.assert_allclose(v, fd, atol=1e-6)
    h = 1e-4
    # Gravity: acceleration is +9.81 m/s^2 along +Y (down).
    t = scene.time_s(present[1])
    acc = (tr.state(t + h)[1] - tr.state(t - h)[1]) / (2 * h)
    np.testing.assert_allclose(acc, [0, 9.81, 0], atol=1e-6)
    held = Trajectory((0, 0, 1), (1, 0, 0), t_ref_s=1.0, t_start_s=1.0, t_end_s=2.0, hold=True)
    np.testing.assert_allclose(held.state(5.0)[0], [1, 0, 1])
    np.testing.assert_allclose(held.state(5.0)[1], 0)
    assert held.present(0.0)
    gone = Trajectory((0, 0, 1), t_start_s=1.0, t_end_s=2.0)
    assert not gone.present(0.5) and gone.present(1.5) and not gone.present(2.5)


def test_photometry_gain_drift_and_noise() -> None:
    phot = Photometry(1.0, 1.03, 0.10, 4.0, 0.0, 3.0)
    room = Room(floor_height_m=None, texture="flat", flat_wall_bgr=(100, 100, 100))
    scene = Scene(rig=Rig(160, 120), photometry=phot, room=room, duration_s=4.0)
    for t_s, drift in ((0.0, 1.0), (1.0, 1.1), (3.0, 0.9)):
        t_ns = scene.to_ns(t_s)
        left = scene.render("left", t_ns).astype(np.float64)
        right = scene.render("right", t_ns).astype(np.float64)
        assert left.dtype == np.float64 and left.shape == (120, 160, 3)
        assert left.mean() == pytest.approx(100 * drift, abs=0.1)
        assert right.mean() == pytest.approx(103 * drift, abs=0.1)
        assert left.std() == pytest.approx(math.sqrt(9 + 1 / 12), rel=0.05)
    a = scene.render("left", scene.t0_ns)
    assert np.array_equal(a, scene.render("left", scene.t0_ns))  # seeded
    assert not np.array_equal(a, scene.render("left", scene.t0_ns + 1))


def test_motion_blur_centroid_is_mean_projection_over_exposure() -> None:
    rig = Rig(160, 120, 60.0)
    traj = Trajectory((-0.2, 0.05, 1.2), (2.0, 0.0, -1.0), t_ref_s=0.0)
    ball = Sphere(name="s", radius_m=0.06, trajectory=traj, colour_bgr=(FG,) * 3)
    scene = flat_scene((ball,), rig, exposure_s=0.02)
    t_ns = scene.to_ns(0.05)
    u, v, _ = centroid(alpha(scene, "left", t_ns))
    ts = 0.05 + np.linspace(0, 0.02, 2001)
    areas_c = np.array([sphere_ellipse(rig, "left", traj.position(t), 0.06) for t in ts])
    w = areas_c[:, 2]  # blur averages coverage, so weight each instant by its area
    eu, ev = (areas_c[:, 0] * w).sum() / w.sum(), (areas_c[:, 1] * w).sum() / w.sum()
    assert math.hypot(u - eu, v - ev) < 0.05
    # The timestamp is the start of the exposure: the blur is centred ~mid-exposure.
    start = sphere_ellipse(rig, "left", traj.position(0.05), 0.06)
    assert abs(u - start[0]) > 1.5  # 0.02 s * 2 m/s * f / Z / 2 ~ 2.3 px
    np.testing.assert_allclose(scene.truth(t_ns)["s"][0], traj.position(0.05))


def test_write_scene_round_trips_losslessly(tmp_path: Path) -> None:
    left, right = clocks_for_skew(20.0, -0.5, 0.5, 0.5)
    objs = (
        Sphere(name="a", radius_m=0.1, trajectory=Trajectory((-0.3, 0.1, 1.5), (1.0, 0, 0))),
        Box(
            name="b",
            half_size_m=(0.1, 0.1, 0.1),
            trajectory=Trajectory((0.2, 0.2, 2.0), t_start_s=0.2),
            colour_bgr=(30, 200, 30),
        ),
    )
    scene = Scene(
        rig=Rig(96, 72, 60.0),
        left_clock=left,
        right_clock=right,
        objects=objs,
        duration_s=0.5,
        seed=4,
    )
    out = write_scene(scene, tmp_path / "s")
    frames = list(scene.frames())
    for eye in ("left", "right"):
        cap = cv2.VideoCapture(str(out / f"{eye}.mkv"))
        decoded = []
        while True:
            ok, img = cap.read()
            if not ok:
                break
            decoded.append(img)
        cap.release()
        mine = [f for f in frames if f.eye == eye]
        assert len(decoded) == len(mine) > 5
        for d, m in zip(decoded, mine):
            assert np.array_equal(d, m.image)
        with (out / f"{eye}.csv").open() as fh:
            rows = list(csv.reader(fh))
        assert rows[0] == ["t_ns", "seq"]
        assert [(int(a), int(b)) for a, b in rows[1:]] == [(m.t_ns, m.seq) for m in mine]
    with (out / "truth.csv").open() as fh:
        truth = list(csv.DictReader(fh))
    times = sorted({f.t_ns for f in frames})
    expected = sum(len(scene.truth(t)) for t in times)
    assert len(truth) == expected
    row = truth[-1]
    p, v = scene.truth(int(row["t_ns"]))[row["object"]]
    np.testing.assert_allclose([float(row[k]) for k in ("x_m", "y_m", "z_m")], p, atol=1e-8)
    np.testing.assert_allclose(
        [float(row[k]) for k in ("vx_mps", "vy_mps", "vz_mps")], v, atol=1e-8
    )
    meta = json.loads((out / "scene.json").read_text())
    assert meta["derived"]["focal_px"] == pytest.approx(scene.rig.focal_px)
    assert load_scene(out) == scene


def test_presets_cover_the_hard_cases() -> None:
    for mode, hfov in (((320, 240, 30.0), 60.0), ((640, 480, 15.0), 42.0)):
        for scene, from_outside in (
            (robot_ball(90, mode=mode, hfov_deg=hfov), True),
            (robot_ball(225, 0.8, mode=mode, hfov_deg=hfov), hfov < 50),
            (robot_cylinder(270, mode=mode, hfov_deg=hfov), True),
            (robot_box(60, mode=mode, hfov_deg=hfov), True),
        ):
            (obj,) = scene.objects
            tr = obj.trajectory
            assert 1.0 <= tr.t_start_s <= 1.5
            first = scene.to_ns(tr.t_start_s)
            if from_outside:
                assert not any(scene.visible(obj.name, e, first) for e in ("left", "right"))
            assert np.linalg.norm(scene.truth(first)[obj.name][1]) > 0.3  # moving from the start
            mid = scene.to_ns(tr.t_ref_s)
            assert all(scene.visible(obj.name, e, mid) for e in ("left", "right"))
            assert np.linalg.norm(scene.truth(mid)[obj.name][1]) > 0.3
            assert obj.trajectory.position(tr.t_ref_s)[1] + obj.half_extent_m()[1] == pytest.approx(
                0.35
            )  # stands on the floor
    # The lit side of the ball is about as bright as parts of the wall behind it.
    scene = robot_ball(90, seed=3)
    t_mid = scene.to_ns(scene.objects[0].trajectory.t_ref_s)
    img = scene.render_radiance("left", t_mid)
    grey = img @ np.array([0.114, 0.587, 0.299])
    ball = scene.render_radiance("left", t_mid) - scene.background_radiance("left")
    on_ball = np.abs(ball).sum(axis=2) > 1e-3
    lit = np.percentile(grey[on_ball], 95)
    wall = grey[: int(scene.rig.cy)]
    assert np.percentile(wall, 10) < lit < np.percentile(wall, 90)
    assert np.percentile(grey[on_ball], 5) < 0.6 * lit  # and it has a dark side
    radial = robot_ball(0, 0.5)
    tr = radial.objects[0].trajectory
    start = radial.to_ns(tr.t_start_s)
    assert radial.visible("ball", "left", start) and radial.truth(start)["ball"][1][2] > 0
    assert not radial.truth(radial.to_ns(tr.t_start_s - 0.01))
    # Crossing: the near ball occludes much of the far one at mid-time, in both eyes.
    cross = crossing(seed=1)
    t_mid = cross.to_ns(cross.objects[0].trajectory.t_ref_s)
    alone = replace(cross, objects=cross.objects[1:])
    for eye in ("left", "right"):
        occluded = cross.coverage(eye, t_mid)["far"]
        assert 0 < occluded < 0.6 * alone.coverage(eye, t_mid)["far"]
    # Fast balls stay in view for several frames of each eye.
    for direction in ("lateral", "radial"):
        for mode in ((320, 240, 30.0), (640, 480, 15.0)):
            fb = fast_ball(direction, 20.0, mode=mode, hfov_deg=42.0)
            for eye in ("left", "right"):
                seen = [t for t in fb.frame_times(eye) if fb.visible("ball", eye, t)]
                assert len(seen) >= 3, (direction, mode, eye)
            assert fb.objects[0].trajectory.g_mps2 == (0.0, 9.81, 0.0)
