"""Progress bars: drawn on a real terminal (a pseudo-terminal here), never into a pipe or a
systemd journal, and counting what the command really did."""

from __future__ import annotations

import fcntl
import io
import os
import pty
import re
import select
import struct
import subprocess
import termios
from pathlib import Path

import cv2

from stereod.cli.progress import Progress, enabled
from stereod_fakes.rig import board_views, minoru_like, random_board_poses
from tests.processes import ROOT, stereod_command

CLEAN_ENV = {k: v for k, v in os.environ.items() if k not in ("INVOCATION_ID", "JOURNAL_STREAM")}


def on_terminal(*args: str, env: dict[str, str] | None = None) -> tuple[int, str, str]:
    """Run ``stereod ARGS`` with stderr on a pseudo-terminal: (exit code, stdout, what the
    terminal showed)."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))  # rows, cols
    proc = subprocess.Popen(
        stereod_command(*args),
        cwd=ROOT,
        env={**CLEAN_ENV, "COLUMNS": "120", **(env or {})},
        stdout=subprocess.PIPE,
        stderr=slave,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    os.close(slave)
    shown = b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the terminal closed: the process ended
                break
            if not chunk:
                break
            shown += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    out, _ = proc.communicate(timeout=120)
    return proc.returncode, out, shown.decode("utf-8", "replace")


def last_bar(shown: str, desc: str) -> str:
    """The last state of the bar named ``desc`` on the terminal."""
    states = [s for s in re.split(r"[\r\n]", shown) if s.startswith(desc)]
    assert states, f"no {desc!r} bar in {shown!r}"
    return states[-1]


def test_enabled_only_on_a_terminal_outside_systemd() -> None:
    master, slave = pty.openpty()
    try:
        with os.fdopen(os.dup(slave), "w") as tty:
            assert enabled(tty, {})
            assert not enabled(tty, {"INVOCATION_ID": "0a1b"})
            assert not enabled(tty, {"JOURNAL_STREAM": "8:12345"})
        with open(os.devnull, "w") as null:
            assert not enabled(null, {})
        assert not enabled(io.StringIO(), {})
    finally:
        os.close(master)
        os.close(slave)
    # Off, a bar costs nothing and does nothing.
    with Progress("x", total=3, show=False) as bar:
        bar.update(1, a=1)
        bar.set(3)
        assert not bar.shown


def test_synth_shows_frames_on_a_terminal_and_nothing_elsewhere(tmp_path: Path) -> None:
    args = ("synth", str(tmp_path / "a"), "--duration", "3", "--size", "160x120")
    code, out, shown = on_terminal(*args)
    assert code == 0 and "wrote 45 stereo frames" in out
    assert re.search(r"100%.*45/45", last_bar(shown, "render"))
    # Into a pipe (CI, a log): no bar, and stderr stays empty.
    args = ("synth", str(tmp_path / "b"), "--duration", "3", "--size", "160x120")
    piped = subprocess.run(
        stereod_command(*args), cwd=ROOT, env=CLEAN_ENV, capture_output=True, text=True
    )
    assert piped.returncode == 0 and piped.stderr == ""
    # Under systemd (its journal), no bar even on a terminal.
    args = ("synth", str(tmp_path / "c"), "--duration", "3", "--size", "160x120")
    code, _, shown = on_terminal(*args, env={"JOURNAL_STREAM": "8:1234"})
    assert code == 0 and "render" not in shown


def test_replay_as_fast_as_possible_counts_pairs_and_frames(tmp_path: Path) -> None:
    rec = tmp_path / "rec"
    subprocess.run(
        stereod_command("synth", str(rec), "--duration", "3", "--size", "160x120"),
        cwd=ROOT,
        check=True,
        capture_output=True,
    )
    code, out, shown = on_terminal("replay", str(rec), "--rate", "0")
    assert code == 0 and out.startswith("45 pairs from 45 left and 45 right frames")
    bar = last_bar(shown, "replay")
    assert re.search(r"100%.*45/45", bar) and "frames=90" in bar, bar


def test_record_counts_seconds_frames_and_drops(tmp_path: Path) -> None:
    code, out, shown = on_terminal(
        "record", str(tmp_path / "rec"), "--driver", "synthetic", "--seconds", "2"
    )
    assert code == 0 and "recorded 30 left and 30 right frames" in out
    bar = last_bar(shown, "record")
    assert "frames=60" in bar and "drops=0" in bar, bar


def test_calibrate_says_per_pair_whether_the_board_was_found(tmp_path: Path) -> None:
    rig = minoru_like()
    views = board_views(rig, 640, 480, 9, 6, 0.03, random_board_poses(7, 9, 6, 0.03, 6))
    for n, left, right in views:
        cv2.imwrite(str(tmp_path / f"left_{n}.png"), left)
        cv2.imwrite(str(tmp_path / f"right_{n}.png"), right)
    blank = views[0][1] * 0 + 128  # a pair without a board
    cv2.imwrite(str(tmp_path / "left_zz.png"), blank)
    cv2.imwrite(str(tmp_path / "right_zz.png"), blank)
    args = ("--board", "9x6", "--square", "0.03", "--out", str(tmp_path / "c.json"), "--force")
    code, _, shown = on_terminal("calibrate", "--pairs", str(tmp_path), *args)
    assert code == 0, shown
    bar = last_bar(shown, "looking for the board")
    assert "8/8" in bar and "found=7" in bar and "rejected=1" in bar, bar
