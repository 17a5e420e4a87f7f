"""Replay driver on plain videos: real files, every inconsistency a clear error."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from stereod.errors import ConfigError, InputError, MissingInputError
from stereod_fakes.replay import ReplayDriver

from .conftest import shared_data


def write_video(path: Path, n: int, size: tuple[int, int] = (64, 48), fps: float = 15.0) -> Path:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter.fourcc(*"MJPG"), fps, size)
    for k in range(n):
        img = np.full((size[1], size[0], 3), (k * 7) % 255, np.uint8)
        w.write(img)
    w.release()
    return path


def write_ts(path: Path, times: list[int]) -> Path:
    path.write_text("t_ns\n" + "".join(f"{t}\n" for t in times))
    return path


def read_all(driver: ReplayDriver) -> tuple[list, list, list[str]]:
    with driver.open() as src:
        left = []
        while (f := src.left.read()) is not None:
            left.append(f)
        right = []
        while (f := src.right.read()) is not None:
            right.append(f)
        return left, right, src.problems()


def test_videos_with_fps(tmp_path: Path) -> None:
    l, r = write_video(tmp_path / "l.avi", 10), write_video(tmp_path / "r.avi", 10)
    left, right, problems = read_all(ReplayDriver({"left_video": l, "right_video": r, "fps": 20}))
    assert [f.t_ns for f in left] == [k * 50_000_000 for k in range(10)]
    assert [f.seq for f in right] == list(range(10))
    assert problems == []


def test_videos_with_timestamp_files(tmp_path: Path) -> None:
    l, r = write_video(tmp_path / "l.avi", 5), write_video(tmp_path / "r.avi", 5)
    lt = write_ts(tmp_path / "l.csv", [10, 20, 30, 40, 50])
    rt = write_ts(tmp_path / "r.csv", [12, 22, 32, 42, 52])
    _, right, _ = read_all(
        ReplayDriver({"left_video": l, "right_video": r, "left_ts": lt, "right_ts": rt})
    )
    assert [f.t_ns for f in right] == [12, 22, 32, 42, 52]


def test_loop_continues_timestamps(tmp_path: Path) -> None:
    l, r = write_video(tmp_path / "l.avi", 4), write_video(tmp_path / "r.avi", 4)
    with ReplayDriver({"left_video": l, "right_video": r, "fps": 10, "loop": True}).open() as src:
        got = [src.left.read() for _ in range(10)]
    times = [f.t_ns for f in got if f is not None]
    assert times == [k * 100_000_000 for k in range(10)]


def test_truncated_video_plays_what_decodes_and_says_so() -> None:
    tree = shared_data("video", "tree.avi")
    left, right, problems = read_all(
        ReplayDriver({"left_video": tree, "right_video": tree, "fps": 15})
    )
    assert len(left) == len(right) == 68
    assert problems and "truncated" in problems[0] and "444" in problems[0] and "68" in problems[0]


@pytest.mark.parametrize(
    ("options", "exc", "pattern"),
    [
        (
            {"left_video": "MISSING", "right_video": "R", "fps": 10},
            MissingInputError,
            "no such video file",
        ),
        (
            {"left_video": "TEXT", "right_video": "R", "fps": 10},
            InputError,
            "cannot open as a video|no frame decodes",
        ),
        (
            {"left_video": "L", "right_video": "SMALL", "fps": 10},
            InputError,
            "64x48 but .* is 32x24",
        ),
        (
            {"left_video": "L", "right_video": "SHORT", "fps": 10},
            InputError,
            "has 6 frames but .* has 4",
        ),
        (
            {"left_video": "L", "right_video": "R", "left_ts": "BADTS", "right_ts": "TS"},
            InputError,
            "not after",
        ),
        (
            {"left_video": "L", "right_video": "R", "left_ts": "TS", "right_ts": "TS4"},
            InputError,
            "6 frames but .* only 4 timestamps",
        ),
    ],
)
def test_bad_inputs_are_refused_up_front(
    tmp_path: Path, options: dict, exc: type, pattern: str
) -> None:
    files = {
        "L": write_video(tmp_path / "l.avi", 6),
        "R": write_video(tmp_path / "r.avi", 6),
        "SMALL": write_video(tmp_path / "small.avi", 6, size=(32, 24)),
        "SHORT": write_video(tmp_path / "short.avi", 4),
        "TEXT": tmp_path / "text.avi",
        "MISSING": tmp_path / "missing.avi",
        "BADTS": write_ts(tmp_path / "bad.csv", [1, 2, 3, 3, 4, 5]),
        "TS": write_ts(tmp_path / "ts.csv", [1, 2, 3, 4, 5, 6]),
        "TS4": write_ts(tmp_path / "ts4.csv", [1, 2, 3, 4]),
    }
    files["TEXT"].write_text("not a video\n")
    resolved = {k: files.get(v, v) if isinstance(v, str) else v for k, v in options.items()}
    with pytest.raises(exc, match=pattern):
        ReplayDriver(resolved).open()


@pytest.mark.parametrize(
    ("options", "pattern"),
    [
        ({}, "either path"),
        ({"left_video": "a"}, "both left_video and right_video"),
        ({"left_video": "a", "right_video": "b"}, "either fps or left_ts"),
        ({"left_video": "a", "right_video": "b", "fps": -1}, r"driver.options.fps"),
        ({"path": "x", "bogus": 1}, r"driver.options.bogus"),
    ],
)
def test_option_errors_name_the_field(options: dict, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        ReplayDriver(options)
