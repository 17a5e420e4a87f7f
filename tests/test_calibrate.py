"""Calibration from chessboards: real reference figures, synthetic truth, refusals, live."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod.errors import InputError, MissingInputError
from stereod.vision.calibrate import (
    CalibrationRejected,
    LiveCollector,
    calibrate,
    calibrate_files,
    detect_pairs,
    pairs_from_list,
    pairs_in_directory,
    read_image,
)
from stereod.vision.calibration import MIN_BOARD_CORNERS, Board, load, rotation_angle_deg
from stereod_fakes.rig import board_views, minoru_like, random_board_poses, write_board_recording
from stereod_fakes.synth import Scene, write_scene

from .conftest import shared_data, stereod
from .processes import start_stereod
from .test_cli import one_line_error

BOARD = Board(cols=9, rows=6, square=0.03)


def test_reproduces_opencv_sample_reference_figures() -> None:
    """DATA.md: with the sample's corner refinement (11 px window), mono RMS 0.408 / 0.458,
    and, intrinsics fixed, stereo RMS 0.447, |T| 3.345 squares, fx about 536 / 542, epipolar
    error 0.290 px. The joint refinement starts from those per-eye results and can only fit
    better: it gave 0.444 px, 3.338 squares, fx 535.7 / 539.6 and 0.262 px."""
    pairs = pairs_from_list(shared_data("opencv_stereo", "stereo_calib.xml"))
    r = calibrate_files(pairs, Board(cols=9, rows=6, square=1.0), window=11)
    q = r.quality
    assert q.pairs_used == 13
    assert q.rms_left_px == pytest.approx(0.408, abs=0.01)
    assert q.rms_right_px == pytest.approx(0.458, abs=0.01)
    assert 0.40 < q.rms_stereo_px <= 0.447 + 0.001
    assert r.calibration.baseline == pytest.approx(3.345, rel=0.005)
    assert r.calibration.array("K1")[0, 0] == pytest.approx(536, rel=0.01)
    assert r.calibration.array("K2")[0, 0] == pytest.approx(542, rel=0.01)
    assert q.epipolar_error_px <= 0.290 + 0.001
    assert r.problems == []
    # The window adapted to the squares' size fits the same images better.
    better = calibrate_files(pairs, Board(cols=9, rows=6, square=1.0))
    assert better.quality.rms_stereo_px < q.rms_stereo_px
    # The same pairs give the same calibration, to the bit, and so the same id (OpenCV's
    # threads summed in another order each run, and every run had an id of its own).
    again = calibrate_files(pairs, Board(cols=9, rows=6, square=1.0))
    assert again.calibration.id == better.calibration.id


def test_baseline_direction_of_a_rendered_rig_is_recovered() -> None:
    """The baseline's direction, not only its length: with each eye's intrinsics fixed after
    calibrating it alone, each principal point's error (1-2 px) turned T by 3.9 deg on these
    views (0.5-3.9 deg over 20 seeds of 20 views, stereo RMS 0.11-0.14 px throughout), and
    the published rig frame turns with T. Refined jointly, the worst of the 20 seeds is
    0.31 deg and 0.10 % in length: bounds of 0.5 deg and 0.5 %. The boards are rendered by
    casting each pixel's ray through the rig's true intrinsics and distortion (fakes.rig),
    nothing of the calibration code."""
    rig = minoru_like()
    views = board_views(rig, 640, 480, 9, 6, 0.03, random_board_poses(20, 9, 6, 0.03, seed=13))
    found, rejected, size = detect_pairs(views, BOARD)
    assert rejected == []
    r = calibrate(found, BOARD, size)
    assert r.problems == [] and r.quality.rms_stereo_px < 0.2
    t, truth = r.calibration.array("T").ravel(), rig.T.ravel()
    cos = float(t @ truth) / (np.linalg.norm(t) * np.linalg.norm(truth))
    off = np.degrees(np.arccos(min(1.0, cos)))
    assert off < 0.5, f"baseline direction off by {off:.2f} deg, T = {t}, true {truth}"
    assert np.linalg.norm(t) == pytest.approx(rig.baseline_m, rel=0.005)


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


def test_one_eyes_views_as_both_are_no_rig_and_no_force_keeps_them(tmp_path: Path) -> None:
    """The same real image as both eyes of every pair: the baseline comes out nil. It was a
    calibration file's error (exit 78, "the file is damaged"), though no file was read, and
    ``--force`` said the same. Now exit 65, naming the pairs, the baseline and what to give."""
    for n in ("01", "02", "03", "04", "05", "06", "08", "09"):
        image = shared_data("opencv_stereo", f"left{n}.jpg").read_bytes()
        (tmp_path / f"left{n}.jpg").write_bytes(image)
        (tmp_path / f"right{n}.jpg").write_bytes(image)
    out = tmp_path / "c.json"
    args = ["calibrate", "--pairs", str(tmp_path), "--board", "9x6", "--square", "0.025"]
    for force in ([], ["--force"]):
        one_line_error(
            stereod(*args, "--out", str(out), *force),
            65,
            rf"8 pairs from {tmp_path}: the board's views give no stereo rig \(T: baseline "
            r"\|T\| = .*, the same view in both eyes\?\): give pairs whose left and right",
        )
        assert not out.exists()


def test_opencv_finds_boards_of_three_inner_corners_a_side_and_no_fewer() -> None:
    """The limit --board enforces is OpenCV's own: 3x3 is found, 2 corners a side refused."""
    assert MIN_BOARD_CORNERS == 3
    poses = random_board_poses(1, 3, 3, 0.05, seed=1)
    (_, left, _), *_ = board_views(minoru_like(), 640, 480, 3, 3, 0.05, poses)
    assert cv2.findChessboardCorners(left, (3, 3))[0]
    for pattern in ((2, 3), (3, 2)):
        with pytest.raises(cv2.error, match="should have bigger than 2"):
            cv2.findChessboardCorners(left, pattern)


@pytest.mark.parametrize(
    ("source", "board"),
    [("--pairs", "1x1"), ("--pairs", "9x1"), ("--list", "2x2"), ("--live", "3x2")],
)
def test_board_of_fewer_than_three_corners_a_side_is_a_flag_error(
    tmp_path: Path, board: str, source: str
) -> None:
    where = [] if source == "--live" else [str(tmp_path)]
    res = stereod("calibrate", source, *where, "--board", board, "--square", "0.025")
    one_line_error(res, 64, rf"--board: '{board}': a board needs at least 3 inner corners a side")


def _pairs_calibration(*more: str) -> list[str]:
    pairs = shared_data("opencv_stereo")
    return ["calibrate", "--pairs", str(pairs), "--board", "9x6", "--square", "1", *more]


def test_an_output_that_cannot_be_written_is_refused_before_calibrating(tmp_path: Path) -> None:
    """A folder, one of the inputs (64), or a file in a folder that does not exist as --out
    (73): one line before any pair is looked at (nothing on stdout, no report), the input
    left as it was and no folder made (as for every output file: --jsonl, --mcap, plot -o)."""
    image = shared_data("opencv_stereo", "left01.jpg")
    before = image.read_bytes()
    for out, code, said in (
        (tmp_path, 73, "is a directory; give the name of a file"),
        (image, 64, "is an input of this run"),
        (tmp_path / "no" / "dir" / "c.json", 73, f"folder {tmp_path}/no/dir does not exist"),
    ):
        res = stereod(*_pairs_calibration("--out", str(out)))
        one_line_error(res, code, f"{out}: .*{said}")
        assert res.stdout == ""
    assert image.read_bytes() == before
    assert list(tmp_path.iterdir()) == []


def test_live_output_is_checked_before_collecting(tmp_path: Path) -> None:
    """With --live, before the stream is read: a folder as --out, or a file of the recording
    it reads (it used to read the whole stream and then fail, or not even say so)."""
    rec = write_scene(Scene(width_px=64, height_px=48, duration_s=0.4, fps=10), tmp_path / "rec")
    live = ["calibrate", "--live", "--recording", str(rec), "--board", "9x6", "--square", "1"]
    for out, code, said in (
        (rec, 73, "is a directory"),
        (rec / "left.csv", 64, "is an input of this run"),
    ):
        res = stereod(*live, "--out", str(out))
        one_line_error(res, code, f"{out}: .*{said}")


def test_an_image_without_its_partner_is_rejected_by_name(tmp_path: Path) -> None:
    """left05.jpg without right05.jpg, and right07.jpg without left07.jpg, are listed as
    rejected with the missing image (they used to be skipped without a word)."""
    for image in shared_data("opencv_stereo").glob("*.jpg"):
        if image.name not in ("right05.jpg", "left07.jpg"):
            (tmp_path / image.name).symlink_to(image)
    out = tmp_path / "out" / "c.json"
    out.parent.mkdir()
    res = stereod(
        "calibrate", "--pairs", str(tmp_path), "--board", "9x6", "--square", "1", "--out", str(out)
    )
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[0] == "pairs used: 11; rejected: 2"
    assert f"rejected: no right image ({tmp_path / 'right05.jpg'} not found)" in res.stdout
    assert f"rejected: no left image ({tmp_path / 'left07.jpg'} not found)" in res.stdout
    assert load(out).quality.pairs_rejected == 2


def test_inputs_the_os_will_not_read_name_the_path_and_the_reason(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """As for a user without root's override after chmod 000 (the tests run as root)."""
    (tmp_path / "pairs.txt").write_text("left01.png right01.png\n")

    def denied(path: Path, *args: object) -> None:
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(Path, "read_bytes", denied)
    monkeypatch.setattr(Path, "iterdir", denied)
    with pytest.raises(MissingInputError, match=r"pairs\.txt: cannot read the list: Permission"):
        pairs_from_list(tmp_path / "pairs.txt")
    with pytest.raises(MissingInputError, match=rf"{tmp_path}: cannot list the folder: Permission"):
        pairs_in_directory(tmp_path)


def test_sigterm_while_collecting_leaves_no_file_and_exits_143(tmp_path: Path) -> None:
    """``timeout``, systemd and ``kill`` stop a command with SIGTERM: a live calibration so
    stopped says so in one line, writes nothing and leaves no temporary file behind."""
    cfg = tmp_path / "live.toml"
    cfg.write_text(
        '[driver]\nname = "synthetic"\n[driver.options]\n'
        "width_px = 160\nheight_px = 120\nlive = true\nloop = true\n"
    )
    proc = start_stereod(
        *("calibrate", "--live", "--config", str(cfg), "--board", "9x6", "--square", "0.025"),
        *("--out", str(tmp_path / "c.json")),
    )
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob(".c.json.*.part")) and time.monotonic() < deadline:
            time.sleep(0.05)  # collecting, its output made
        assert list(tmp_path.glob(".c.json.*.part")), "calibrate never started collecting"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=90)  # a guard against a hang, not a measurement
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()  # its pipes closed here, not left to a later test
    assert proc.returncode == 143, err
    assert (
        err.splitlines()[-1]
        == f"stereod: calibrate interrupted by SIGTERM; {tmp_path}/c.json left as it was"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["live.toml"]


def test_a_square_that_makes_the_baseline_impossible_is_named(tmp_path: Path) -> None:
    """--square 0.001 on OpenCV's sample pairs: |T| is 3.345 squares (DATA.md), so 3.3 mm,
    under the 5 mm a rig can have. The message blamed pairs not taken at once; it now gives
    the baseline and names --square."""
    res = stereod(
        "calibrate", "--pairs", str(shared_data("opencv_stereo")), "--board", "9x6",
        "--square", "0.001", "--out", str(tmp_path / "c.json"),
    )  # fmt: skip
    one_line_error(
        res,
        65,
        r"the baseline came out [\d.]+ mm with --square 0\.001, outside a rig's 0\.005\.\.10 m: "
        r"every length of the result scales with --square",
    )
    mm = float(res.stderr.split("came out ")[1].split(" mm")[0])
    assert mm == pytest.approx(3.345, rel=0.01)
    assert not (tmp_path / "c.json").exists()


def test_the_rms_refusal_names_the_worst_pair(tmp_path: Path) -> None:
    """Pair 05 given pair 06's right image (not of one instant): its epipolar error is tens of
    px where the others' are under one before the fit is spoilt; the refusal names it and no
    longer suggests --square, which cannot change an RMS."""
    for p in shared_data("opencv_stereo").glob("*.jpg"):
        (tmp_path / p.name).write_bytes(p.read_bytes())
    (tmp_path / "right05.jpg").write_bytes(shared_data("opencv_stereo", "right06.jpg").read_bytes())
    res = stereod(
        "calibrate", "--pairs", str(tmp_path), "--board", "9x6", "--square", "0.025",
        "--out", str(tmp_path / "c.json"),
    )  # fmt: skip
    one_line_error(
        res, 65, r"stereo RMS [\d.]+ px is above 1 px; the worst pair is left05\.jpg \(epipolar"
    )
    assert "--square" not in res.stderr


def test_an_image_cut_short_is_called_damaged_and_libjpeg_stays_quiet(tmp_path: Path) -> None:
    """A real JPEG truncated to 12 kB of its 25 kB: libjpeg printed "Premature end of JPEG
    file" past OpenCV's silenced log, and the pair was blamed on the board. Now one line
    names the file as damaged (65); a PNG without its IEND chunk likewise."""
    for n in ("01", "02", "03", "04"):
        for eye in ("left", "right"):
            src = shared_data("opencv_stereo", f"{eye}{n}.jpg").read_bytes()
            (tmp_path / f"{eye}{n}.jpg").write_bytes(src)
    (tmp_path / "left04.jpg").write_bytes((tmp_path / "left04.jpg").read_bytes()[:12000])
    res = stereod(
        "calibrate", "--pairs", str(tmp_path), "--board", "9x6", "--square", "0.025",
        "--out", str(tmp_path / "c.json"),
    )  # fmt: skip
    one_line_error(
        res, 65, r"left04\.jpg: a damaged image \(the JPEG stops before its end marker: cut short\)"
    )
    png = tmp_path / "p.png"
    cv2.imwrite(str(png), np.zeros((48, 64), np.uint8))
    png.write_bytes(png.read_bytes()[:-20])
    with pytest.raises(InputError, match=r"p\.png: a damaged image \(the PNG stops before"):
        read_image(png)
