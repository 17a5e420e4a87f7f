"""Piecewise-linear paths (stops) and the stop-and-go robot of the independent renderer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereod_fakes.world import (
    Cylinder,
    Rig,
    Scene,
    Waypoints,
    load_scene,
    robot_stop_go,
    write_scene,
)


def test_waypoints_move_at_constant_velocity_and_stop() -> None:
    path = Waypoints(((0.0, 0.3, 2.0), (1.0, 0.3, 2.0), (1.0, 0.3, 2.0), (1.0, 0.3, 1.0)),
                     (1.0, 3.0, 5.0, 6.0))  # fmt: skip
    assert not path.present(0.99) and path.present(1.0) and path.present(6.0)
    assert not path.present(6.01)
    p, v = path.state(2.5)
    np.testing.assert_allclose(p, (0.75, 0.3, 2.0))
    np.testing.assert_allclose(v, (0.5, 0.0, 0.0))
    p, v = path.state(4.0)
    np.testing.assert_allclose(p, (1.0, 0.3, 2.0))
    assert np.all(v == 0.0)
    np.testing.assert_allclose(path.state(5.5)[1], (0.0, 0.0, -1.0))
    np.testing.assert_allclose(path.state(7.0)[0], (1.0, 0.3, 1.0))
    with pytest.raises(ValueError, match="times_s"):
        Waypoints(((0.0, 0.0, 1.0), (1.0, 0.0, 1.0)), (1.0, 1.0))


def test_robot_stops_for_the_given_time_and_drives_on() -> None:
    scene = robot_stop_go(1.5, mode=(96, 72, 30.0))
    robot = scene.object("robot")
    assert isinstance(robot, Cylinder) and isinstance(robot.trajectory, Waypoints)
    t_in, t_stop, t_go, t_out = robot.trajectory.times_s
    assert t_go - t_stop == pytest.approx(1.5)
    speeds = {}
    for t_ns in scene.frame_times("left"):
        t = scene.time_s(t_ns)
        got = scene.truth(t_ns).get("robot")
        if got is not None:
            speeds[t] = float(np.linalg.norm(got[1]))
    moving = [s for t, s in speeds.items() if t_in < t < t_stop or t_go < t < t_out]
    still = [s for t, s in speeds.items() if t_stop < t < t_go]
    assert moving and all(s == pytest.approx(0.5) for s in moving)
    assert len(still) >= 40 and all(s == 0.0 for s in still)
    # It comes in from outside the view, stops in view, and leaves.
    first = scene.to_ns(t_in + 0.01)
    assert not any(scene.visible("robot", e, first) for e in ("left", "right"))
    stopped = [t for t in scene.frame_times("left") if t_stop < scene.time_s(t) < t_go]
    assert all(scene.visible("robot", e, stopped[0]) for e in ("left", "right"))
    img = scene.render_radiance("left", stopped[0])
    assert np.array_equal(scene.render_radiance("left", stopped[-1]), img)
    before = scene.to_ns(t_stop - 0.2)
    assert not np.array_equal(scene.render_radiance("left", before), img)


def test_waypoints_round_trip_through_scene_files(tmp_path: Path) -> None:
    path = Waypoints(((0.0, 0.2, 1.5), (0.1, 0.2, 1.5)), (0.0, 0.2))
    robot = Cylinder(name="r", trajectory=path, radius_m=0.05, height_m=0.1)
    scene = Scene(rig=Rig(32, 24, 60.0), objects=(robot,), duration_s=0.1)
    out = write_scene(scene, tmp_path / "rec")
    back = load_scene(out)
    assert back == scene
    assert isinstance(back.objects[0].trajectory, Waypoints)
