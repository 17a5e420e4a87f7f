"""``stereod calibrate --room``: rig poses in the room from rendered chessboard views.

The views are rendered here with plain OpenCV: the board's squares projected by
``cv2.projectPoints`` into each rig's left camera (placed in the room by a known pose) and
filled. The truth of each rig frame is independent of stereod's: its origin is the midpoint of
the two camera centres, its axes those of the left camera turned by the rectification ``R1``.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod.fusion.room import RigPose, load_room
from stereod.vision.calibration import Board, Calibration, from_arrays, save

from .conftest import stereod
from .test_cli import one_line_error

W, H = 640, 480
COLS, ROWS, SQUARE = 9, 6, 0.05


def rot(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rz Ry Rx of angles in deg (written out here, not stereod's)."""
    x, y, z = (math.radians(a) for a in (rx, ry, rz))
    mx = np.array([[1, 0, 0], [0, math.cos(x), -math.sin(x)], [0, math.sin(x), math.cos(x)]])
    my = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    mz = np.array([[math.cos(z), -math.sin(z), 0], [math.sin(z), math.cos(z), 0], [0, 0, 1]])
    return mz @ my @ mx


def rig_calibration(
    k1: float, small_turn_deg: float, board: Board | None = None
) -> tuple[dict[str, np.ndarray], Calibration]:
    """A non-canonical rig: distortion and a slight turn between the eyes (R1 is no identity);
    ``board`` is recorded as the board it was calibrated with."""
    k = np.array([[600.0, 0, 322.0], [0, 598.0, 241.0], [0, 0, 1]])
    r = cv2.Rodrigues(np.array([0.0, math.radians(small_turn_deg), 0.01]))[0]
    arrays = {
        "K1": k,
        "D1": np.array([k1, 0.01, 0.0005, -0.0003, 0.0]),
        "K2": k,
        "D2": np.zeros(5),
        "R": r,
        "T": np.array([-0.06, 0.002, 0.001]),
    }
    return arrays, from_arrays((W, H), arrays, board=board)


def left_in_rig(arrays: dict[str, np.ndarray], r1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) of the left camera in the rig frame: p_rig = R1 (p_left - m), m the midpoint of
    the camera centres (left at 0, right at -R^T T in the left camera's frame)."""
    m = -arrays["R"].T @ arrays["T"] / 2.0
    return r1, -r1 @ m


def render(
    board_r: np.ndarray,
    board_t: np.ndarray,
    cam_r: np.ndarray,
    cam_t: np.ndarray,
    k: np.ndarray,
    d: np.ndarray,
) -> np.ndarray:
    """The left camera's grey image of the board (room pose board_r, board_t) seen from a
    camera at room pose cam_r, cam_t: white margin, black and white squares."""
    r = cam_r.T @ board_r
    t = cam_r.T @ (board_t - cam_t)
    rvec = cv2.Rodrigues(r)[0]
    img = np.full((H, W), 90, np.uint8)

    def poly(corners: np.ndarray, value: int) -> None:
        px, _ = cv2.projectPoints(corners.astype(np.float64), rvec, t, k, d)
        cv2.fillConvexPoly(img, np.round(px.reshape(-1, 2) * 16).astype(np.int32), value, 16, 4)

    s = SQUARE
    poly(np.array([[-s, -s, 0], [(COLS + 1) * s, -s, 0], [(COLS + 1) * s, (ROWS + 1) * s, 0],
                   [-s, (ROWS + 1) * s, 0]]), 255)  # fmt: skip
    for i in range(COLS + 1):
        for j in range(ROWS + 1):
            if (i + j) % 2 == 0:
                x0, y0 = (i - 1) * s, (j - 1) * s
                sq = [[x0, y0, 0], [x0 + s, y0, 0], [x0 + s, y0 + s, 0], [x0, y0 + s, 0]]
                poly(np.array(sq), 0)
    return img


RIGS = {
    "a": ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    "b": ((1.1, 0.05, 0.1), (2.0, -28.0, 1.5)),
    "c": ((-0.9, -0.2, 0.3), (-4.0, 22.0, -3.0)),
}


def board_poses(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Board poses about 2 m in front of rig a, facing the rigs (its normal along -Z)."""
    rng = np.random.default_rng(7)
    out = []
    for _ in range(n):
        r = rot(180.0 + rng.uniform(-15, 15), rng.uniform(-15, 15), rng.uniform(-10, 10))
        centre = np.array([0.1, 0.0, 1.9]) + rng.uniform(-0.15, 0.15, 3)
        out.append((r, centre - r @ np.array([COLS * SQUARE / 2, ROWS * SQUARE / 2, 0.0])))
    return out


def write_views(
    tmp: Path,
    n: int,
    rigs: dict[str, tuple],
    keep: dict[str, set[int]] | None = None,
    board: Board | None = None,
) -> list[str]:
    """Each rig's calibration file (recording ``board`` when given) and its folder of rendered
    left-eye views (those of ``keep[rig]`` when given); --rig args."""
    args = []
    poses = board_poses(n)
    for idx, (name, (t, angles)) in enumerate(rigs.items()):
        arrays, cal = rig_calibration(-0.05 - 0.02 * idx, 0.5 + 0.3 * idx, board)
        save(cal, tmp / f"cal_{name}.json")
        rr, rt = rot(*angles), np.asarray(t)
        lr, lt = left_in_rig(arrays, cal.array("R1"))
        cam_r, cam_t = rr @ lr, rr @ lt + rt
        folder = tmp / f"views_{name}"
        folder.mkdir()
        for v, (br, bt) in enumerate(poses):
            if keep is not None and v not in keep[name]:
                continue
            img = render(br, bt, cam_r, cam_t, arrays["K1"], arrays["D1"])
            cv2.imwrite(str(folder / f"view{v:02d}.png"), img)
        args += ["--rig", f"{name}={tmp / f'cal_{name}.json'}:{folder}"]
    return args


def test_room_poses_from_three_rigs_match_the_truth(tmp_path: Path) -> None:
    """Three rigs at known poses see 8 boards: each rig's translation within 3 mm and angles
    within 0.1 deg of the truth; reprojection under 0.3 px; the loop b-c closes within 3 mm
    and 0.1 deg."""
    args = write_views(tmp_path, 8, RIGS)
    out = tmp_path / "room.toml"
    res = stereod(
        "calibrate", "--room", str(out), *args, "--board", "9x6", "--square", "0.05",
        "--room-name", "lab",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    room = load_room(out)
    assert room.name == "lab" and [r.name for r in room.rigs] == ["a", "b", "c"]
    for rig in room.rigs:
        t, angles = RIGS[rig.name]
        assert np.abs(np.subtract(rig.translation_m, t)).max() < 0.003, (rig.name, rig)
        assert np.abs(np.subtract(rig.rotation_deg, angles)).max() < 0.1, (rig.name, rig)
    lines = res.stdout.splitlines()
    for name in "abc":
        line = next(x for x in lines if x.startswith(f"rig {name}:"))
        assert "8 views" in line
        rms = float(line.split("reprojection RMS ")[1].split()[0])
        assert rms < 0.3, line
    loop = next(x for x in lines if x.startswith("loop b-c"))
    mm = float(loop.split("closure error ")[1].split()[0])
    deg = float(loop.split("mm, ")[1].split()[0])
    assert mm < 3.0 and deg < 0.1, loop


def run_room(tmp: Path, args: list[str]) -> tuple[str, dict[str, RigPose]]:
    """Run ``calibrate --room``; its stdout and the written rigs by name."""
    out = tmp / "room.toml"
    res = stereod("calibrate", "--room", str(out), *args, "--board", "9x6", "--square", "0.05")
    assert res.returncode == 0, res.stderr
    return res.stdout, {r.name: r for r in load_room(out).rigs}


def check_poses(rigs: dict[str, RigPose], mm: float, deg: float) -> None:
    """Each rig's pose within ``mm`` and ``deg`` of the truth (per component)."""
    for name, rig in rigs.items():
        t, angles = RIGS[name]
        got_t, got_r = rig.translation_m, rig.rotation_deg
        assert np.abs(np.subtract(got_t, t)).max() < mm / 1000, (name, rig)
        assert np.abs(np.subtract(got_r, angles)).max() < deg, (name, rig)


def test_a_rig_chained_through_another(tmp_path: Path) -> None:
    """Rig c shares four views with b only: its pose is chained a -> b -> c, within 5 mm and
    0.25 deg (two links of four views each: their errors add); with no pair outside the
    chain there is no loop to close."""
    keep = {"a": {0, 1, 2, 3}, "b": set(range(8)), "c": {4, 5, 6, 7}}
    stdout, rigs = run_room(tmp_path, write_views(tmp_path, 8, RIGS, keep))
    check_poses(rigs, 5.0, 0.25)
    assert "no loop" in stdout and "loop b-c" not in stdout


def test_a_loop_of_separate_views_closes(tmp_path: Path) -> None:
    """Each pair of rigs shares its own four views (a-b, b-c, a-c): poses within 5 mm and
    0.25 deg; the loop b-c, measured apart from the chain a-b, a-c, closes within 8 mm and
    0.4 deg (three links' errors), and is not exactly 0 (independent views)."""
    keep = {"a": {0, 1, 2, 3, 8, 9, 10, 11}, "b": set(range(8)), "c": set(range(4, 12))}
    stdout, rigs = run_room(tmp_path, write_views(tmp_path, 12, RIGS, keep))
    check_poses(rigs, 5.0, 0.25)
    loop = next(x for x in stdout.splitlines() if x.startswith("loop b-c"))
    mm = float(loop.split("closure error ")[1].split()[0])
    deg = float(loop.split("mm, ")[1].split()[0])
    assert 0.0 < mm < 8.0 and deg < 0.4, loop


def test_a_rig_mounted_upside_down(tmp_path: Path) -> None:
    """Rig b rolled 180 deg sees the board upside down: its corners are still numbered from
    the board's own corner (9x6 has an odd number of squares one way), so its pose comes out
    right: within 3 mm and 0.1 deg of (0.3, 0, 0) m, (0, -3, 180) deg."""
    rigs = {"a": RIGS["a"], "b": ((0.3, 0.0, 0.0), (0.0, -3.0, 180.0))}
    _, got = run_room(tmp_path, write_views(tmp_path, 6, rigs))
    b = got["b"]
    assert np.abs(np.subtract(b.translation_m, (0.3, 0.0, 0.0))).max() < 0.003
    rz = b.rotation_deg[2] % 360.0
    assert (
        abs(rz - 180.0) < 0.1 and np.abs(np.subtract(b.rotation_deg[:2], (0.0, -3.0))).max() < 0.1
    )


def test_a_square_other_than_the_rigs_calibrations_is_refused_unless_forced(
    tmp_path: Path,
) -> None:
    """The board's poses scale with --square and no RMS changes, so twice the true square put
    rig b twice as far away, silently. The rigs' calibrations record the square (0.05): a
    --square of 0.10 is refused (exit 65, the rig, the file and the square to give named,
    nothing written); with --force, for a room board that really is another one, it is
    written and rig b lands twice as far from rig a as it is, as the message says."""
    board = Board(cols=COLS, rows=ROWS, square=SQUARE)
    args = write_views(tmp_path, 4, {k: RIGS[k] for k in "ab"}, board=board)
    out = tmp_path / "room.toml"
    cmd = ["calibrate", "--room", str(out), *args, "--board", "9x6", "--square", "0.1"]
    one_line_error(
        stereod(*cmd),
        65,
        r"--square 0\.1 but rig a's calibration .*cal_a\.json was made with squares of 0\.05: "
        r"the room's distances scale with --square \(by 2 here\) and no RMS shows it; give "
        r"--square 0\.05, or --force if the room's board is another board than the rig's; "
        r"nothing written to .*room\.toml",
    )
    assert not out.exists()
    forced = stereod(*cmd, "--force")
    assert forced.returncode == 0 and "going on (--force)" in forced.stderr
    b = {r.name: r for r in load_room(out).rigs}["b"]
    # twice as far (within 1 %: the rigs' half baselines, in the calibrations' unit, are not)
    far = float(np.linalg.norm(b.translation_m)) / float(np.linalg.norm(RIGS["b"][0]))
    assert far == pytest.approx(2.0, rel=0.01)
    _, rigs = run_room(tmp_path, args)  # --square 0.05, the recorded one
    check_poses(rigs, 3.0, 0.1)


def test_views_of_different_instants_are_refused(tmp_path: Path) -> None:
    """Rig b's images of two views swapped (not of one instant): exit 65, the view named."""
    args = write_views(tmp_path, 3, {k: RIGS[k] for k in "ab"})
    b = tmp_path / "views_b"
    (b / "view00.png").rename(b / "tmp.png")
    (b / "view01.png").rename(b / "view00.png")
    (b / "tmp.png").rename(b / "view01.png")
    out = tmp_path / "room.toml"
    res = stereod("calibrate", "--room", str(out), *args, "--board", "9x6", "--square", "0.05")
    one_line_error(res, 65, r"view view0[01]\.png: rigs a and b disagree")
    assert not out.exists()


def test_a_rig_without_a_shared_view_is_one_line(tmp_path: Path) -> None:
    """A rig whose images share no name with the others' is refused (exit 65, as the docs say
    of every refusal; it was 78, a configuration's), nothing written."""
    args = write_views(tmp_path, 2, {k: RIGS[k] for k in "ab"})
    for p in (tmp_path / "views_b").iterdir():
        p.rename(p.with_name("other_" + p.name))
    out = tmp_path / "room.toml"
    res = stereod("calibrate", "--room", str(out), *args, "--board", "9x6", "--square", "0.05")
    one_line_error(res, 65, r"rig b shares no board view")
    assert not out.exists()


def test_a_board_found_in_no_image_is_refused_with_65(tmp_path: Path) -> None:
    """--board 8x6 for a 9x6 board: no rig finds it; a refusal, exit 65 (it was 78)."""
    args = write_views(tmp_path, 2, {k: RIGS[k] for k in "ab"})
    out = tmp_path / "room.toml"
    res = stereod("calibrate", "--room", str(out), *args, "--board", "8x6", "--square", "0.05")
    one_line_error(res, 65, r"rig a: the 8x6 board was found in none of its 2 images")
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "pattern"),
    [
        (["--rig", "a=x.json"], r"NAME=CAL:DIR"),
        (["--rig", "a=x.json:y"], r"two --rig"),
        (
            ["--rig", "a=x.json:y", "--rig", "b=x.json:y", "--out", "z.json"],
            r"--out z\.json: "
            r"--room writes the room file it names \(.*r\.toml\); drop --out",
        ),
    ],
)
def test_bad_rig_arguments_are_one_line(tmp_path: Path, extra: list[str], pattern: str) -> None:
    res = stereod(
        "calibrate", "--room", str(tmp_path / "r.toml"), *extra, "--board", "9x6",
        "--square", "0.05",
    )  # fmt: skip
    one_line_error(res, 64, pattern)


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--min-pairs", "9"], "rig a saw the board in 8 views, fewer than --min-pairs 9"),
        (["--max-rms", "0.01"], "rig a's reprojection RMS of its own views is "),
    ],
)
def test_a_room_calibration_that_fails_its_limits_is_refused_unless_forced(
    tmp_path: Path, extra: list[str], said: str
) -> None:
    """--min-pairs (views a rig saw the board in) and --max-rms hold for --room as for a rig's
    calibration: exit 65 and nothing written (they were accepted, then ignored), or written
    with --force and said."""
    args = write_views(tmp_path, 8, {k: RIGS[k] for k in "ab"})
    out = tmp_path / "room.toml"
    cmd = ["calibrate", "--room", str(out), *args, "--board", "9x6", "--square", "0.05", *extra]
    res = stereod(*cmd)
    assert res.returncode == 65, res.stderr
    (line,) = res.stderr.splitlines()
    assert line.startswith("stereod: room calibration is clearly bad: ") and said in line, line
    assert line.endswith(f"not written to {out} (use --force to write it anyway)")
    assert not out.exists()
    forced = stereod(*cmd, "--force")
    assert forced.returncode == 0 and "written anyway (--force)" in forced.stderr
    assert [r.name for r in load_room(out).rigs] == ["a", "b"]


def test_the_default_limits_pass_a_good_room_and_a_stereo_calibration_needs_3_pairs(
    tmp_path: Path,
) -> None:
    args = write_views(tmp_path, 3, {k: RIGS[k] for k in "ab"})
    _, rigs = run_room(tmp_path, args)  # 3 views a rig: the least --room takes by default
    assert set(rigs) == {"a", "b"}
    res = stereod(
        "calibrate", "--pairs", str(tmp_path), "--board", "9x6", "--square", "0.05",
        "--min-pairs", "2",
    )  # fmt: skip
    one_line_error(res, 64, r"--min-pairs 2: a stereo calibration needs 3 pairs or more")
