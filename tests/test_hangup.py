"""SIGHUP (a closed terminal, ``kill -HUP``) ends a one-shot command exactly as SIGTERM does:
real ``stereod`` processes, real signals. ``record`` keeps what it recorded (exit 0),
``export``, ``synth`` and a replay stop as interrupted (129) and leave no ``.part`` file and
every existing output as it was, a looping replay ends normally. The daemon's SIGHUP is a
reload: tests/test_reload.py."""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from stereod_fakes.synth import Ball, Scene, write_scene

from .processes import start_stereod

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def long_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recording long enough that no command gets through it before the signal."""
    scene = Scene(width_px=160, height_px=120, fps=15, duration_s=30, balls=[Ball()])
    return write_scene(scene, tmp_path_factory.mktemp("long") / "rec")


@pytest.fixture(scope="module")
def export_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A recording whose export takes long enough to be caught writing on a loaded host:
    about 0.6 s of writing at 320x240 (0.15 s at 160x120 was sometimes over before the
    signal came)."""
    scene = Scene(width_px=320, height_px=240, fps=15, duration_s=30, balls=[Ball()])
    return write_scene(scene, tmp_path_factory.mktemp("export") / "rec")


def parts(folder: Path) -> list[Path]:
    """Temporary outputs (files or folders) left in ``folder``."""
    return sorted(p for p in folder.iterdir() if p.name.endswith(".part"))


def hang_up_when(
    proc: subprocess.Popen, started: Callable[[], bool], then: signal.Signals | None = None
) -> tuple[int, str]:
    """Send SIGHUP once ``started()`` (the command is writing its output), and ``then`` a
    second later if given, then wait for the process; its exit code and stderr. The wait for
    the start is bounded only so that a broken command fails the test instead of hanging
    it."""
    deadline = time.monotonic() + 120
    while not started():
        assert proc.poll() is None, f"ended before the signal: {proc.communicate()}"
        assert time.monotonic() < deadline, "the command never started writing"
        time.sleep(0.01)
    proc.send_signal(signal.SIGHUP)
    if then is not None:
        time.sleep(1.0)
        assert proc.poll() is None, f"ended on the SIGHUP: {proc.communicate()}"
        proc.send_signal(then)
    _, err = proc.communicate(timeout=120)
    return proc.returncode, err


def test_export_ends_as_interrupted_and_keeps_the_old_file(
    export_recording: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run.mcap"
    out.write_bytes(b"the previous export")
    proc = start_stereod("export", str(export_recording), "--mcap", str(out), cwd=tmp_path)
    code, err = hang_up_when(proc, lambda: bool(parts(tmp_path)))
    assert code == 129, err
    assert err.splitlines() == [f"stereod: export interrupted by SIGHUP; {out} left as it was"]
    assert out.read_bytes() == b"the previous export"
    assert parts(tmp_path) == []


def test_synth_ends_as_interrupted_and_leaves_nothing(tmp_path: Path) -> None:
    proc = start_stereod(
        "synth", str(tmp_path / "out"), "--duration", "60", "--size", "320x240", cwd=tmp_path
    )
    code, err = hang_up_when(proc, lambda: bool(parts(tmp_path)))
    assert code == 129, err
    assert err.splitlines() == ["stereod: synth interrupted by SIGHUP"]
    assert list(tmp_path.iterdir()) == []


def test_record_keeps_what_it_recorded(long_recording: Path, tmp_path: Path) -> None:
    """As SIGTERM: the normal end of a recording without --seconds. The frames recorded are
    in the folder, with their timestamps and the manifest, and the summary says SIGHUP."""
    config = tmp_path / "c.toml"
    config.write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{long_recording}"\n')
    out = tmp_path / "new"
    proc = start_stereod("record", str(out), "--config", str(config), cwd=tmp_path)

    def some_frames() -> bool:
        found = parts(tmp_path)
        return bool(found) and len((found[0] / "left.csv").read_text().splitlines()) > 3

    deadline = time.monotonic() + 120
    while not some_frames():
        assert proc.poll() is None and time.monotonic() < deadline, "no frame recorded"
        time.sleep(0.05)
    proc.send_signal(signal.SIGHUP)
    printed, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    assert "(stopped by SIGHUP)" in printed
    manifest = json.loads((out / "recording.json").read_text())
    for eye in ("left", "right"):
        with (out / f"{eye}.csv").open() as fh:
            rows = list(csv.DictReader(fh))
        assert len(rows) == manifest[eye]["frames"] > 0
    assert parts(tmp_path) == []


def test_replay_ends_as_interrupted(long_recording: Path, tmp_path: Path) -> None:
    jsonl = tmp_path / "run.jsonl"
    jsonl.write_text("the previous run\n")
    proc = start_stereod(
        "replay", str(long_recording), "--rate", "1", "-q", "--jsonl", str(jsonl), cwd=tmp_path
    )
    code, err = hang_up_when(proc, lambda: bool(parts(tmp_path)))
    assert code == 129, err
    assert "replay interrupted by SIGHUP" in err and len(err.splitlines()) == 1, err
    assert jsonl.read_text() == "the previous run\n"
    assert parts(tmp_path) == []


def test_looping_replay_ends_normally(long_recording: Path, tmp_path: Path) -> None:
    """With --loop a signal is the normal end: SIGHUP too (it used to be ignored, and the
    replay ran for ever); the JSONL of what played is kept (once something played: stopped
    before its first pair, the replay writes no file)."""
    jsonl = tmp_path / "run.jsonl"
    proc = start_stereod(
        "replay", str(long_recording), "--loop", "-q", "--jsonl", str(jsonl), cwd=tmp_path
    )
    code, err = hang_up_when(proc, lambda: any(p.stat().st_size for p in parts(tmp_path)))
    assert code == 0, err
    assert jsonl.exists()
    assert parts(tmp_path) == []


def catches_sighup(pid: int) -> bool:
    """Whether process ``pid`` has a handler of its own for SIGHUP (bit 1 of SigCgt)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & 1 << (signal.SIGHUP - 1))
    return False


def test_a_hang_up_during_start_up_ends_a_one_shot_command_before_it_writes(
    long_recording: Path, tmp_path: Path
) -> None:
    """SIGHUP while the command is still importing (its entry point remembers it, nothing
    else can act yet) ends the command as interrupted as soon as it knows what it is, its
    output untouched (it used to be ignored: the replay ran to its end and replaced the
    file)."""
    out = tmp_path / "run.jsonl"
    out.write_text("the previous run\n")
    proc = start_stereod("replay", str(long_recording), "-q", "--jsonl", str(out), cwd=tmp_path)
    code, err = hang_up_when(proc, lambda: catches_sighup(proc.pid))
    assert code == 129, err
    assert "replay interrupted by SIGHUP" in err
    assert out.read_text() == "the previous run\n" and parts(tmp_path) == []


def test_a_hang_up_during_start_up_leaves_the_fusion_node_running(tmp_path: Path) -> None:
    """The fusion node reloads on SIGHUP; one during its start-up asks for nothing it will not
    read anyway, and it runs on (it used to end with 129), to end normally on SIGTERM."""
    from .conftest import free_endpoint
    from .fuse_procs import ROOM

    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    proc = start_stereod("fuse", "--room", str(room), "--listen", free_endpoint())
    code, err = hang_up_when(proc, lambda: catches_sighup(proc.pid), then=signal.SIGTERM)
    assert code == 0, err
