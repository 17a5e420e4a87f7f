"""Calibration from chessboards: real reference figures, synthetic truth, refusals, live."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod.calibrate import (
    CalibrationRejected,
    LiveCollector,
    calibrate,
    calibrate_files,
    detect_pairs,
    pairs_from_list,
    pairs_in_directory,
)
from stereod.calibration import Board, load, rotation_angle_deg
from stereod.errors import InputError, MissingInputError
from stereod_fakes.rig import board_views, minoru_like, random_board_poses, write_board_recording

from .conftest import shared_data, stereod

BOARD = Board(cols=9, rows=6, square=0.03)


def test_reproduces_opencv_sample_reference_figures() -> None:
    """DATA.md: with the sample's corner refinement (11 px window), mono RMS 0.408 / 0.458,
    stereo RMS 0.447, |T| 3.345 squares, epipolar error 0.290 px."""
    pairs = pairs_from_list(shared_data("opencv_stereo", "stereo_calib.xml"))
    r = calibrate_files(pairs, Board(cols=9, rows=6, square=1.0), window=11)
    q = r.quality
    assert q.pairs_used == 13
    assert q.rms_left_px == pytest.approx(0.408, abs=0.01)
    assert q.rms_right_px == pytest.approx(0.458, abs=0.01)
    assert q.rms_stereo_px == pytest.approx(0.447, abs=0.01)
    assert r.calibration.baseline == pytest.approx(3.345, abs=0.01)
    assert q.epipolar_error_px == pytest.approx(0.290, abs=0.01)
    assert r.problems == []
    # The window adapted to the squares' size fits the same images better.
    better = calibrate_files(pairs, Board(cols=9, rows=6, square=1.0))
    assert better.quality.rms_stereo_px < q.rms_stereo_px


def test_recovers_a_non_canonical_rig_from_rendered_boards() -> None:
    """Unequal focal lengths, radial and tangential distortion, a 0.9 deg relative rotation:
    the baseline within 1 % and the rotation within 0.2 deg."""
    rig = minoru_like()
    views = board_views(rig, 640, 480, 9, 6, 0.03, random_board_poses(30, 9, 6, 0.03, seed=2))
    found, rejected, size = detect_pairs(views, BOARD)
    assert rejected == [] and size == (640, 480)
    r = calibrate(found, BOARD, size)
    assert r.problems == []
    cal = r.calibration
    assert cal.baseline == pytest.approx(0.060, rel=0.01), f"baseline {cal.baseline:.5f} m"
    err = rotation_angle_deg(cal.array("R") @ rig.R.T)
    assert err < 0.2, f"relative rotation off by {err:.3f} deg"
    assert cal.array("K2")[0, 0] == pytest.approx(rig.right.fx, rel=0.005)


def test_swapped_eyes_and_too_few_pairs_are_refused() -> None:
    rig = minoru_like()
    views = board_views(rig, 640, 480, 9, 6, 0.03, random_board_poses(8, 9, 6, 0.03, seed=3))
    swapped = [(n, r, l) for n, l, r in views]
    found, _, size = detect_pairs(swapped, BOARD)
    problems = calibrate(found, BOARD, size).problems
    assert any("swapped" in p and "T.x" in p for p in problems), problems
    found, _, size = detect_pairs(views[:4], BOARD)
    problems = calibrate(found, BOARD, size).problems
    assert any("only 4 usable pairs" in p for p in problems), problems


def test_no_board_anywhere(tmp_path: Path) -> None:
    blank = np.full((120, 160), 128, np.uint8)
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"left{k}.png"), blank)
        cv2.imwrite(str(tmp_path / f"right{k}.png"), blank)
    with pytest.raises(CalibrationRejected, match="board was not found in both images of any"):
        calibrate_files(pairs_in_directory(tmp_path), BOARD)


def test_bad_image_inputs(tmp_path: Path) -> None:
    (tmp_path / "left0.png").write_text("not an image")
    cv2.imwrite(str(tmp_path / "right0.png"), np.zeros((10, 10), np.uint8))
    with pytest.raises(InputError, match=r"left0\.png: not a readable image"):
        calibrate_files(pairs_in_directory(tmp_path), BOARD)
    with pytest.raises(MissingInputError, match="no such folder"):
        pairs_in_directory(tmp_path / "nope")
    views = [
        ("a", np.zeros((48, 64), np.uint8), np.zeros((48, 64), np.uint8)),
        ("b", np.zeros((24, 32), np.uint8), np.zeros((24, 32), np.uint8)),
    ]
    with pytest.raises(InputError, match="b: left image is 32x24, earlier images are 64x48"):
        detect_pairs(views, BOARD)
    lst = tmp_path / "pairs.txt"
    lst.write_text("only_one.png\n")
    with pytest.raises(InputError, match="line 1: expected 'LEFT RIGHT'"):
        pairs_from_list(lst)


def test_live_collector_keeps_only_new_poses() -> None:
    rig = minoru_like()
    poses = random_board_poses(4, 9, 6, 0.03, seed=4)
    views = board_views(rig, 640, 480, 9, 6, 0.03, poses)
    c = LiveCollector(BOARD)
    kept = [c.offer(n, l, r) for n, l, r in views + views]
    assert kept == [True] * 4 + [False] * 4


@pytest.mark.slow
def test_live_calibration_from_a_moving_board_recording(tmp_path: Path) -> None:
    rig = minoru_like()
    rec = write_board_recording(rig, tmp_path / "board", random_board_poses(32, 9, 6, 0.03, seed=5))
    out = tmp_path / "cal.json"
    res = stereod(
        "calibrate",
        "--live",
        "--recording",
        str(rec),
        "--board",
        "9x6",
        "--square",
        "0.03",
        "--wanted",
        "16",
        "--out",
        str(out),
    )
    assert res.returncode == 0, res.stderr
    assert "pairs kept: 16/16" in res.stderr
    cal = load(out)
    assert cal.quality.pairs_used == 16
    assert cal.baseline == pytest.approx(0.060, rel=0.01)
    assert json.loads(out.read_text())["format"] == "stereod.calibration/1"


def test_cli_refuses_bad_calibration_unless_forced(tmp_path: Path) -> None:
    rig = minoru_like()
    for n, l, r in board_views(rig, 640, 480, 9, 6, 0.03, random_board_poses(4, 9, 6, 0.03, 6)):
        cv2.imwrite(str(tmp_path / f"left_{n}.png"), l)
        cv2.imwrite(str(tmp_path / f"right_{n}.png"), r)
    out = tmp_path / "c.json"
    args = [
        "calibrate",
        "--pairs",
        str(tmp_path),
        "--board",
        "9x6",
        "--square",
        "0.03",
        "--out",
        str(out),
    ]
    res = stereod(*args)
    assert res.returncode == 65 and not out.exists()
    assert "only 4 usable pairs" in res.stderr and "--force" in res.stderr
    res = stereod(*args, "--force")
    assert res.returncode == 0 and out.exists()
    assert "per pair" in res.stdout and "RMS reprojection error" in res.stdout
