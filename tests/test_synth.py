"""Synthetic renderer: what it draws is where the canonical rig sees the truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereod.errors import MissingInputError
from stereod.sources.frames import Eye
from stereod.vision.detect import Detector
from stereod.vision.detect_params import DetectorParams
from stereod_fakes.synth import (
    Ball,
    Renderer,
    Scene,
    SyntheticDriver,
    scene_from_truth,
    write_scene,
)

from .conftest import stereod
from .test_cli import one_line_error


def test_ball_is_drawn_where_a_spheres_silhouette_is_centred() -> None:
    # A sphere's silhouette is centred on f X / (Z - r^2 / Z), not on the projection of its
    # centre f X / Z: for this large, near ball the two are 3 px apart.
    x, y, z, radius = 0.2, -0.1, 1.0, 0.15
    scene = Scene(
        noise_sigma=0.0,
        balls=[Ball(centre_m=(x, y, z), radius_m=radius, t_on_s=0.0, t_off_s=9)],
    )
    r = Renderer(scene)
    rig = scene.rig
    near_z = z - radius**2 / z
    for eye, x_cam in ((Eye.LEFT, x + rig.baseline_m / 2), (Eye.RIGHT, x - rig.baseline_m / 2)):
        empty = r.background(eye)[..., 0]
        img = r.render(eye, scene.balls[0].t_mid_s).astype(float)
        diff = np.abs(img - empty) > 20
        ys, xs = np.nonzero(diff)
        assert xs.mean() == pytest.approx(rig.focal_px * x_cam / near_z + rig.cx_px, abs=0.3)
        assert ys.mean() == pytest.approx(rig.focal_px * y / near_z + rig.cy_px, abs=0.3)
        assert abs(xs.mean() - (rig.focal_px * x_cam / z + rig.cx_px)) > 2.0
        r_px = rig.focal_px * radius / np.sqrt(z**2 - radius**2)
        assert diff.sum() == pytest.approx(np.pi * r_px**2, rel=0.05)


def test_wall_has_the_disparity_of_its_distance() -> None:
    scene = Scene(wall_m=3.0, noise_sigma=0.0)
    r = Renderer(scene)
    left, right = r.background(Eye.LEFT)[..., 0], r.background(Eye.RIGHT)[..., 0]
    d = scene.rig.baseline_m * scene.rig.focal_px / 3.0
    shift = int(round(d))
    # A wall point at left column x is at right column x - d.
    err = np.abs(left[:, 100 + shift : 500 + shift] - right[:, 100:500]).mean()
    assert err < 2.0


def test_skew_renders_right_eye_later() -> None:
    scene = Scene(skew_s=0.02)
    frames = list(Renderer(scene).frames())
    assert frames[3][1].t_ns - frames[3][0].t_ns == 20_000_000
    assert frames[3][0].t_ns == scene.t0_ns + round(3 / scene.fps * 1e9)


def test_detector_finds_rendered_ball_within_a_tenth_of_a_pixel() -> None:
    scene = Scene(noise_sigma=1.5, balls=[Ball(t_on_s=1.0, t_off_s=3.0)])
    det = Detector(DetectorParams())
    errs = []
    for left, _ in Renderer(scene).frames():
        blobs = det.detect(left.image)
        t = (left.t_ns - scene.t0_ns) / 1e9
        if scene.balls[0].visible(t) and len(blobs) == 1:
            uv = scene.rig.project(scene.balls[0].position_m(t)[None])[0][0]
            errs.append(np.linalg.norm(blobs.centroid_px[0] - uv))
    assert len(errs) >= 25
    assert np.median(errs) < 0.1, f"median centroid error {np.median(errs):.3f} px"


def test_write_scene_and_truth_round_trip(tmp_path: Path) -> None:
    scene = Scene(duration_s=0.4, fps=10)
    write_scene(scene, tmp_path / "s")
    assert scene_from_truth(tmp_path / "s" / "truth.json") == scene
    assert (tmp_path / "s" / "recording.json").is_file()


def test_a_truth_file_that_cannot_be_read_names_it_and_the_reason(tmp_path: Path) -> None:
    """A folder stands for any file the OS will not read (the tests run as root)."""
    (tmp_path / "truth.json").mkdir()
    with pytest.raises(MissingInputError, match=r"truth.json: cannot read the truth file: Is a"):
        scene_from_truth(tmp_path / "truth.json")


def test_synthetic_driver_streams_the_scene() -> None:
    with SyntheticDriver({"duration_s": 0.5, "fps": 10, "skew_s": 0.01}).open() as src:
        lf = [src.left.read() for _ in range(6)]
        assert lf[-1] is None
        rf = src.right.read()
        assert rf is not None and rf.t_ns - lf[0].t_ns == 10_000_000


@pytest.mark.parametrize("prerender", [False, True])
def test_a_looped_scene_shows_the_same_frames_each_lap(prerender: bool) -> None:
    """``loop = true`` plays the scene again and again: each lap's frames are the first lap's
    (the ball comes back; without sensor noise, to the bit), and only their timestamps go on,
    a lap later each time."""
    options = {"duration_s": 0.5, "fps": 10, "loop": True, "prerender": prerender, "noise_sigma": 0}
    ball = {"heading_deg": 90, "speed_mps": 0.5, "t_mid_s": 0.25, "t_on_s": 0.0, "t_off_s": 0.5}
    with SyntheticDriver({**options, "balls": [ball]}).open() as src:
        frames = [src.left.read() for _ in range(15)]
    assert all(f is not None for f in frames)
    for k in range(5):
        first, again, third = frames[k], frames[k + 5], frames[k + 10]
        assert first is not None and again is not None and third is not None
        np.testing.assert_array_equal(again.image, first.image)
        np.testing.assert_array_equal(third.image, first.image)
        assert again.t_ns - first.t_ns == third.t_ns - again.t_ns == 500_000_000
    assert not np.array_equal(frames[0].image, frames[2].image)  # (the ball moves in a lap)


@pytest.mark.parametrize(
    ("size", "more"),
    [("321x241", []), ("320x241", ["--codec", "mjpg", "--color"]), ("1x1", [])],
)
def test_synth_refuses_a_size_the_video_writer_would_crop(
    tmp_path: Path, size: str, more: list[str]
) -> None:
    """OpenCV's video writer drops an odd last column or row: such a size is a flag error
    naming it and an even one, and nothing is written (it used to write 320x240 videos under a
    manifest saying 321x241, which replay then refused)."""
    res = stereod("synth", str(tmp_path / "s"), "--size", size, "--duration", "3", *more)
    one_line_error(res, 64, rf"--size: {size} px cannot be recorded: .*even .*such as \d+x\d+")
    assert list(tmp_path.iterdir()) == []


def test_synth_at_an_even_size_replays_at_that_size(tmp_path: Path) -> None:
    """162x122 is even but not a multiple of 4: the frames are stored as they are."""
    rec = tmp_path / "s"
    res = stereod("synth", str(rec), "--size", "162x122", "--duration", "3", "--codec", "mjpg")
    assert res.returncode == 0, res.stderr
    res = stereod("replay", str(rec), "--rate", "0")
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("45 pairs from 45 left and 45 right frames"), res.stdout


def test_synth_refuses_a_run_of_no_frame(tmp_path: Path) -> None:
    """0.1 Hz for 3 s is no frame: refused (it used to write a recording replay cannot open)."""
    res = stereod("synth", str(tmp_path / "s"), "--fps", "0.1", "--duration", "3")
    one_line_error(res, 64, r"--duration 3 s at --fps 0.1 Hz is not one frame.* at least 10 s")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("ball", "pattern"),
    [
        ("z=-1", r"z = -1 m is behind the camera; z must be between 0\.115 and 3\.95 m"),
        ("z=10", r"z = 10 m is at or behind the wall at 4 m; z must be between 0\.115 and 3\.95"),
        ("heading=90,z=3.98", r"reaches through the wall at 4 m; z must be between"),
        ("radius=5", r"5 m at z = 1\.8 m holds the camera; radius must be between"),
        ("radius=0.7,z=1", r"more than the 640x480 view; radius must be between 0\.0022 and 0\.43"),
        ("radius=0.001", r"too small to detect .*; radius must be between 0\.004 and 0\.78 m"),
    ],
)
def test_synth_refuses_a_ball_that_cannot_be_seen(tmp_path: Path, ball: str, pattern: str) -> None:
    """A ball behind the camera or the wall (4 m away), around the camera, wider than the view
    or too small for the detector is a flag error naming the --ball key and its range, and
    nothing is written (such scenes used to be rendered, with nothing in them to track)."""
    res = stereod("synth", str(tmp_path / "s"), "--ball", "heading=60", "--ball", ball)
    one_line_error(res, 64, rf"--ball '{ball}': a ball of radius .*{pattern}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("ball", "pattern"),
    [
        ("heading=60,z=1.8,z=2", r"z is given twice: give it once"),
        ("heading=60,speed", r"expected key=value, got 'speed'"),
        ("heading=60,spin=1", r"unknown key 'spin'"),
    ],
)
def test_a_ball_spec_that_is_not_one_ball_is_a_flag_error(
    tmp_path: Path, ball: str, pattern: str
) -> None:
    """A key given twice (the last one was kept without a word), one without a value or an
    unknown one: exit 64, one line, nothing written."""
    res = stereod("synth", str(tmp_path / "s"), "--ball", ball)
    one_line_error(res, 64, rf"--ball.*{pattern}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("size", "pattern"),
    [
        (
            "2x2",
            r"the default ball, a ball of radius 0\.05 m .* too small to detect .*larger --size",
        ),
        ("100000x100000", r"width_px = 100000: Input should be less than or equal to 4096"),
    ],
)
def test_synth_names_the_size_when_the_size_is_what_is_off(
    tmp_path: Path, size: str, pattern: str
) -> None:
    """A view too small for the default ball, or too large to render, is ``--size``'s error
    (it named a ``--ball ''`` the user never gave, or the scene's field); nothing is written."""
    res = stereod("synth", str(tmp_path / "s"), "--size", size)
    one_line_error(res, 64, rf"--size {size}: {pattern}")
    assert list(tmp_path.iterdir()) == []
    # what a larger view would not mend is not the size's: a travel through the camera
    res = stereod(
        "synth", str(tmp_path / "s"), "--size", "320x240", "--travel", "20", "--duration", "30"
    )
    one_line_error(res, 64, r"^stereod: the default ball \(no --ball given\): at the start")
    assert "--size" not in res.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("ball", "pattern"),
    [  # at mid-travel at 1.8 m (or z), in view for the default 1.6 s from 1.2 s to 2.8 s
        ("heading=0,speed=3", r"start of its travel \(1\.2 s\) it is at z = -0\.6 m, at or behind"),
        ("heading=180,speed=3", r"start of its travel \(1\.2 s\) it is at z = 4\.2 m, through the"),
        ("heading=0,speed=2,z=2.5", r"end of its travel \(2\.8 s\) it is at z = 4\.1 m, through"),
    ],
)
def test_synth_refuses_a_ball_whose_travel_reaches_the_camera_or_the_wall(
    tmp_path: Path, ball: str, pattern: str
) -> None:
    """A ball placed well at mid-travel whose straight path takes it through the camera or
    the wall (its depth at each end of the travel: z -/+ speed x 0.8 s) is a flag error
    saying where and what to change, and nothing is written; one that leaves the view across
    it is a scene like any other."""
    res = stereod("synth", str(tmp_path / "s"), "--ball", ball)
    one_line_error(res, 64, rf"--ball '{ball}': at the {pattern}.*shorter --travel")
    assert list(tmp_path.iterdir()) == []
    res = stereod("synth", str(tmp_path / "t"), "--ball", "heading=90,speed=3", "--size", "160x120")
    assert res.returncode == 0, res.stderr


def test_a_prerendered_scene_that_cannot_fit_in_memory_is_refused_when_read() -> None:
    """``run --check`` reads the options; a scene whose frames could never be held (here 54.9
    TiB an eye) is refused there, naming the option and what to change, not when it opens."""
    from stereod.errors import ConfigError
    from stereod_fakes.synth import SyntheticDriver

    big = {"width_px": 4096, "height_px": 4096, "fps": 1000, "duration_s": 3600}
    # 2 eyes x 3600 s x 1000 Hz x 4096 x 4096 x 3 bytes = 3.38e5 GiB
    with pytest.raises(ConfigError, match=r"prerender: 3600000 frames .* need 3\.38e\+05 GiB"):
        SyntheticDriver({**big, "prerender": True})
    SyntheticDriver(big)  # rendered as it is read: nothing held
