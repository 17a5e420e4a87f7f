"""End to end: `stereod` as a subprocess, received over a real Zenoh session on loopback."""

from __future__ import annotations

import json
import math
import os
import re
import resource
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import zenoh

from stereod.cli import main
from stereod.files.paths import MAX_TEXT_BYTES, MAX_TIMESTAMP_BYTES
from stereod.tracking.motion import angle_diff_deg, circular_median_deg
from stereod_fakes.synth import Ball, Renderer, Scene, write_scene
from tests.processes import start_stereod, stereod_command

from .conftest import ROOT, shared_data, stereod

pytestmark = pytest.mark.slow


class Collector:
    """Everything a subscriber receives on stereod/**, in arrival order."""

    def __init__(self, session: zenoh.Session, key: str = "stereod/**") -> None:
        self.samples: list[tuple[str, str, bytes]] = []
        self._lock = threading.Lock()
        self._sub = session.declare_subscriber(key, self._on)

    def _on(self, s: zenoh.Sample) -> None:
        with self._lock:
            self.samples.append((str(s.key_expr), str(s.kind), s.payload.to_bytes()))

    def messages(self, key: str) -> list[dict]:
        with self._lock:
            return [json.loads(p) for k, kind, p in self.samples if k == key and "PUT" in kind]

    def deletes(self) -> list[str]:
        with self._lock:
            return [k for k, kind, _ in self.samples if "DELETE" in kind]

    def wait_for(self, pred, timeout: float = 10.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if pred():
                return True
            time.sleep(0.05)
        return pred()


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory: pytest.TempPathFactory) -> tuple[Scene, Path]:
    scene = Scene(
        balls=[Ball(heading_deg=60, speed_mps=0.7)], skew_s=0.0, drift=0.02, noise_sigma=1.5
    )
    out = tmp_path_factory.mktemp("scene") / "rec"
    write_scene(scene, out)
    return scene, out


def fast_over(endpoint: str) -> list[str]:
    """Replay flags: as fast as possible, to the test's listener, once it subscribes."""
    return ["--rate", "0", "--connect", endpoint, "--wait-subscriber", "10"]


def test_run_waits_for_a_subscriber_as_replay_does(
    scene_dir: tuple[Scene, Path], endpoint: str, listener: zenoh.Session, tmp_path: Path
) -> None:
    """``stereod run --wait-subscriber`` with a file driver in its config: a subscriber that
    was there first gets every pair from the first (as fast as possible, nothing missed)."""
    scene, rec = scene_dir
    col = Collector(listener)
    cfg = tmp_path / "run.toml"
    cfg.write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{rec}"\n')
    res = stereod("run", "--config", str(cfg), *fast_over(endpoint))
    assert res.returncode == 0, res.stderr
    key = "stereod/minoru/objects"
    assert col.wait_for(lambda: len(col.messages(key)) == scene.n_frames)
    assert [m["seq"] for m in col.messages(key)] == list(range(scene.n_frames))


def test_replay_publishes_truthful_motion_over_zenoh(
    scene_dir: tuple[Scene, Path], endpoint: str, listener: zenoh.Session, tmp_path: Path
) -> None:
    scene, rec = scene_dir
    ball = scene.balls[0]
    col = Collector(listener)
    jsonl = tmp_path / "out.jsonl"
    res = stereod(
        "replay",
        str(rec),
        *fast_over(endpoint),
        "--jsonl",
        str(jsonl),
    )
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    key = "stereod/minoru/objects"
    written = [json.loads(line) for line in jsonl.read_text().splitlines()]
    assert len(written) == scene.n_frames
    assert col.wait_for(lambda: len(col.messages(key)) == len(written))
    received = col.messages(key)
    assert received == written, "what arrived differs from what was published"
    assert [m["seq"] for m in received] == list(range(scene.n_frames))

    valid = [o for m in received for o in m["objects"] if o["velocity_valid"]]
    assert len(valid) >= 10
    for m in received:
        for o in m["objects"]:
            truth = ball.position_m((m["t_ns"] - scene.t0_ns) / 1e9)
            bound = scene.rig.depth_error_one_px_m(truth[2])
            assert abs(o["position_m"][2] - truth[2]) <= bound
            assert np.linalg.norm(np.subtract(o["position_m"], truth)) < 0.05
    heading = circular_median_deg([o["heading_deg"] for o in valid])
    speed = np.median([o["speed_mps"] for o in valid])
    assert abs(angle_diff_deg(heading, 60.0)) < 2.0, f"heading {heading:.2f} deg, truth 60"
    assert speed == pytest.approx(0.7, rel=0.03), f"speed {speed:.3f} m/s, truth 0.7"

    # Per-track keys carry the same states, and the track's end is a DELETE.
    track = col.messages("stereod/minoru/objects/1")
    assert len(track) == sum(len(m["objects"]) for m in received)
    assert col.wait_for(lambda: "stereod/minoru/objects/1" in col.deletes())
    assert col.wait_for(
        lambda: any(s["state"] == "finished" for s in col.messages("stereod/minoru/status"))
    )
    final = [s for s in col.messages("stereod/minoru/status") if s["state"] == "finished"][-1]
    assert final["pairs"] == scene.n_frames and final["drops"] == {}
    assert "60 pairs" in res.stdout


def test_replay_plain_videos_with_timestamp_files(
    endpoint: str, listener: zenoh.Session, tmp_path: Path
) -> None:
    """Two plain videos with 20 ms of skew in their timestamp files."""
    scene = Scene(skew_s=0.02, balls=[Ball(heading_deg=90, speed_mps=0.4, centre_m=(0, 0, 1.5))])
    writers, stamps = {}, {"left": [], "right": []}
    for eye in ("left", "right"):
        writers[eye] = cv2.VideoWriter(
            str(tmp_path / f"{eye}.mkv"),
            cv2.VideoWriter.fourcc(*"FFV1"),
            scene.fps,
            (scene.width_px, scene.height_px),
            isColor=False,
        )
    for left, right in Renderer(scene).frames():
        for f in (left, right):
            writers[f.eye.value].write(f.image)
            stamps[f.eye.value].append(f.t_ns)
    for eye, w in writers.items():
        w.release()
        (tmp_path / f"{eye}.csv").write_text("t_ns\n" + "".join(f"{t}\n" for t in stamps[eye]))
    col = Collector(listener)
    res = stereod(
        "replay",
        "--left-video",
        str(tmp_path / "left.mkv"),
        "--right-video",
        str(tmp_path / "right.mkv"),
        "--left-ts",
        str(tmp_path / "left.csv"),
        "--right-ts",
        str(tmp_path / "right.csv"),
        *fast_over(endpoint),
    )
    assert res.returncode == 0, res.stderr
    assert col.wait_for(lambda: len(col.messages("stereod/minoru/objects")) == scene.n_frames)
    msgs = col.messages("stereod/minoru/objects")
    assert all(m["skew_ns"] == 20_000_000 for m in msgs)
    valid = [o for m in msgs for o in m["objects"] if o["velocity_valid"]]
    assert (
        valid
        and abs(angle_diff_deg(circular_median_deg([o["heading_deg"] for o in valid]), 90)) < 3
    )


def test_subscribe_prints_readably(
    scene_dir: tuple[Scene, Path], endpoint: str, listener: zenoh.Session
) -> None:
    _, rec = scene_dir
    sub = subprocess.Popen(
        stereod_command(
            "subscribe",
            "stereod/minoru/objects",
            "--connect",
            endpoint,
            "--duration",
            "60",
            "--count",
            "30",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    try:
        res = stereod("replay", str(rec), *fast_over(endpoint))
        assert res.returncode == 0, res.stderr
        out, err = sub.communicate(timeout=30)
    finally:
        sub.kill()
    assert sub.returncode == 0, err
    lines = out.splitlines()
    assert sum(line.startswith("stereod/minoru/objects: seq ") for line in lines) == 30
    assert any("pos (" in line and " m" in line for line in lines)


def test_subscribe_without_an_endpoint_connects_where_the_demo_listens() -> None:
    """Bare ``stereod subscribe`` looks for a daemon on tcp/127.0.0.1:7447, as ``view``
    does (a peer with no endpoint and no scouting would hear nothing)."""
    from stereod.bus.publish import open_session
    from stereod.daemon.config import ZenohConfig

    try:
        session = open_session(ZenohConfig(listen=["tcp/127.0.0.1:7447"]))
    except Exception:
        pytest.skip("tcp/127.0.0.1:7447 is in use on this machine")
    with session:
        pub = session.declare_publisher("stereod/minoru/status")
        sub = subprocess.Popen(
            stereod_command("subscribe", "--json", "--count", "1", "--duration", "20"),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        try:
            while sub.poll() is None:
                pub.put(b'{"probe": 1}')
                time.sleep(0.1)
            out, err = sub.communicate(timeout=10)
        finally:
            sub.kill()
    assert sub.returncode == 0, err
    assert json.loads(out.splitlines()[0]) == {"probe": 1}


def test_run_with_config_file_and_synthetic_driver(
    tmp_path: Path, endpoint: str, listener: zenoh.Session
) -> None:
    cfg = tmp_path / "stereod.toml"
    cfg.write_text(
        '[rig]\nname = "bench"\n'
        '[driver]\nname = "synthetic"\n[driver.options]\nduration_s = 2.0\nfps = 15\n'
        f'[zenoh]\nconnect = ["{endpoint}"]\n'
    )
    col = Collector(listener)
    res = stereod("run", "--config", str(cfg), "--rate", "0")
    assert res.returncode == 0, res.stderr
    assert col.wait_for(lambda: len(col.messages("stereod/bench/objects")) == 30)
    check = stereod("run", "--config", str(cfg), "--check")
    assert check.returncode == 0 and json.loads(check.stdout)["rig"]["name"] == "bench"


def test_run_on_a_truncated_recording_exits_65_as_replay_does(
    tmp_path: Path, endpoint: str
) -> None:
    """The daemon with the replay driver plays a video that decodes 68 of the 444 frames its
    header announces (DATA.md), says so in its log, and exits 65 as ``replay`` does: its input
    ended and was bad. A service must not report such a run as a success."""
    tree = shared_data("video", "tree.avi")
    right = shutil.copyfile(tree, tmp_path / "tree_right.avi")  # each eye its own file
    cfg = tmp_path / "stereod.toml"
    cfg.write_text(
        f'[driver]\nname = "replay"\n[driver.options]\nleft_video = "{tree}"\n'
        f'right_video = "{right}"\nfps = 15\n[zenoh]\nconnect = ["{endpoint}"]\n'
    )
    res = stereod("run", "--config", str(cfg), "--rate", "0")
    assert res.returncode == 65, res.stderr
    assert "truncated" in res.stderr and "444" in res.stderr and "68" in res.stderr


def test_run_on_a_live_camera_stopped_by_sigterm_exits_0_even_with_no_pairs(
    tmp_path: Path, endpoint: str, listener: zenoh.Session
) -> None:
    """A live source whose eyes never pair (here 33 ms apart, paired within 5 ms) is a
    problem for the status key, not bad input: ``systemctl stop`` (SIGTERM) still ends the
    daemon normally with 0, or the unit would be marked failed. The signal is sent once the
    daemon runs (its first status is out), however long a busy host takes to start it."""
    col = Collector(listener)
    cfg = tmp_path / "stereod.toml"
    cfg.write_text(
        '[driver]\nname = "synthetic"\n[driver.options]\nlive = true\nduration_s = 60.0\n'
        f"fps = 15\nskew_s = 0.0333\n[pairing]\ntolerance_ms = 5\n"
        f'[zenoh]\nconnect = ["{endpoint}"]\n'
    )
    proc = start_stereod("run", "--config", str(cfg))
    try:
        running = col.wait_for(lambda: bool(col.messages("stereod/minoru/status")), 120.0)
        assert running, "no status from the daemon in 120 s"
        time.sleep(1.0)  # frames flow meanwhile, none pairs
    finally:
        proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err


def one_line_error(res: subprocess.CompletedProcess[str], code: int, pattern: str) -> None:
    assert res.returncode == code, (res.returncode, res.stderr)
    lines = res.stderr.splitlines()
    assert "Traceback" not in res.stderr, res.stderr
    assert len(lines) == 1 and lines[0].startswith("stereod"), res.stderr
    assert __import__("re").search(pattern, lines[0]), lines[0]


def error_in_process(
    capsys: pytest.CaptureFixture[str], argv: list[str], code: int, pattern: str
) -> str:
    """``stereod ARGV`` run in this process must end with ``code`` and one stderr line
    matching ``pattern`` (for mistakes found before anything starts); that line."""
    try:
        got = main(argv)
    except SystemExit as exc:  # the parser's own errors
        got = exc.code  # type: ignore[assignment]
    err = capsys.readouterr().err
    assert got == code, (got, err)
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("stereod"), err
    assert __import__("re").search(pattern, lines[0]), lines[0]
    return lines[0]


def test_plain_video_flag_mistakes_are_usage_errors_naming_the_flags(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Plain-video flags that make no input are a bad command line (64) naming the flags; the
    same mistake in a config file stays a configuration error (78) naming its fields."""
    videos = ["--left-video", "L.mkv", "--right-video", "R.mkv"]
    for argv, pattern in (
        (["--left-video", "L.mkv", "--fps", "15"], "--left-video needs --right-video"),
        (["--right-video", "R.mkv", "--fps", "15"], "--right-video needs --left-video"),
        ([*videos, "--left-ts", "A"], "--left-ts needs --right-ts"),
        ([*videos, "--right-ts", "B"], "--right-ts needs --left-ts"),
        (
            [*videos, "--left-ts", "A", "--right-ts", "B", "--fps", "30"],
            "--fps and --left-ts/--right-ts are exclusive",
        ),
        (videos, "give --fps HZ or --left-ts/--right-ts"),
        (["REC", "--fps", "15"], "--fps: for plain videos only; a recording plays at the capture"),
        (["REC", "--left-ts", "A"], "--left-ts: for plain videos only"),
    ):
        line = error_in_process(capsys, ["replay", *argv], 64, pattern)
        assert "left_video" not in line and "driver.options" not in line, line
    cfg = tmp_path / "c.toml"
    cfg.write_text('[driver]\nname = "replay"\n[driver.options]\nleft_video = "L.mkv"\nfps = 15\n')
    error_in_process(
        capsys,
        ["run", "--check", "--config", str(cfg)],
        78,
        "driver.options: plain videos need both left_video and right_video",
    )


def test_a_recording_named_by_its_manifest_plays_as_its_folder(
    scene_dir: tuple[Scene, Path], tmp_path: Path
) -> None:
    """``stereod replay REC/recording.json`` plays the recording REC, as ``--help`` says; a
    config file whose driver path names the manifest is told to name the folder."""
    scene, rec = scene_dir
    jsonl = tmp_path / "run.jsonl"
    manifest = rec / "recording.json"
    res = stereod("replay", str(manifest), "--rate", "0", "--jsonl", str(jsonl), "-q")
    assert res.returncode == 0, res.stderr
    assert jsonl.read_text().count("\n") == scene.n_frames
    assert "recording.json names it too" in stereod("replay", "--help").stdout
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{manifest}"\n')
    one_line_error(
        stereod("run", "--config", str(cfg), "--rate", "0"),
        66,
        f"recording.json: that is a recording's manifest; give its folder, {rec}$",
    )


def test_a_flag_a_command_does_not_have_points_to_that_commands_help(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """The command's help lists its flags; the top-level help does not."""
    error_in_process(
        capsys,
        ["replay", "rec", "--speed", "2"],
        64,
        r"^stereod replay: unrecognized arguments: --speed 2 \(see stereod replay --help\)$",
    )
    error_in_process(
        capsys,
        ["calibration", "export", "cal.json", "--ros", "ros", "--bogus"],
        64,
        r"^stereod calibration export: .* --bogus \(see stereod calibration export --help\)$",
    )


def test_an_abbreviated_flag_is_refused_not_taken_for_the_flag_it_begins(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``--json out`` is no ``--jsonl out`` (argparse would take it for one, and write the
    JSONL to a file named as the next word)."""
    error_in_process(
        capsys,
        ["replay", "rec", "--json", "out"],
        64,
        r"^stereod replay: unrecognized arguments: --json out \(see stereod replay --help\)$",
    )


def _two_gigabytes_of_memory() -> None:
    """A child's address space capped, so that a reader without a bound fails fast (exit 70)
    instead of filling the machine's memory."""
    resource.setrlimit(resource.RLIMIT_AS, (2 * 2**30, 2 * 2**30))


def test_inputs_that_are_no_regular_files_or_far_too_large_are_refused_unread(
    scene_dir: tuple[Scene, Path], tmp_path: Path
) -> None:
    """A config, calibration or timestamp file that is a device (/dev/zero), a named pipe or
    a directory is refused by name (66) without being read (they used to be read without
    bound: MemoryError, exit 70, or a wait forever for a pipe's writer); one far larger than
    such a file can be is refused as bad content of its kind (config 78, timestamps 65)."""
    _, rec = scene_dir
    videos = ["--left-video", str(rec / "left.mkv"), "--right-video", str(rec / "right.mkv")]
    right_ts = ["--right-ts", str(rec / "right.csv"), "--rate", "0"]
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    big_toml, big_csv = tmp_path / "big.toml", tmp_path / "big.csv"
    for path, size in ((big_toml, MAX_TEXT_BYTES), (big_csv, MAX_TIMESTAMP_BYTES)):
        with path.open("wb") as fh:
            fh.truncate(size + 1)  # sparse: no disk space used
    for argv, code, pattern in (
        (["run", "--config", "/dev/zero", "--check"], 66, "/dev/zero: is a character device, "),
        (["run", "--config", str(fifo), "--check"], 66, "fifo: is a named pipe, not a config"),
        (["run", "--config", str(tmp_path), "--check"], 66, ": is a directory, not a config file"),
        (["run", "--config", str(big_toml), "--check"], 78, "larger than 16 MiB, too large for a"),
        (["replay", str(rec), "--calibration", "/dev/zero"], 66, "not a calibration file; give"),
        (["replay", *videos, "--left-ts", "/dev/zero", *right_ts], 66, "not a timestamp file"),
        (["replay", *videos, "--left-ts", str(big_csv), *right_ts], 65, "too large for a timest"),
    ):
        res = stereod(*argv, timeout=60, preexec_fn=_two_gigabytes_of_memory)
        one_line_error(res, code, pattern)


def test_bad_inputs_give_one_line_and_nonzero_exit(tmp_path: Path) -> None:
    one_line_error(stereod("replay", str(tmp_path / "nope")), 66, "no such recording directory")
    junk, junk2 = tmp_path / "junk.avi", tmp_path / "junk2.avi"
    junk.write_text("junk")
    junk2.write_text("junk")
    one_line_error(
        stereod("replay", "--left-video", str(junk), "--right-video", str(junk2), "--fps", "10"),
        65,
        "junk.avi: cannot open as a video|junk.avi: no frame decodes",
    )
    one_line_error(stereod("replay", str(tmp_path)), 66, "recording.json missing")
    one_line_error(stereod("replay"), 64, "nothing to replay")
    one_line_error(
        stereod("replay", "--left-video", "l.mp4", "--right-video", "r.mp4", "--fps", "10"),
        66,
        r"l\.mp4: no such video file \(the left eye's: --left-video .*r\.mp4: no such video "
        r"file \(the right eye's: --right-video",
    )
    bad = tmp_path / "bad.toml"
    bad.write_text("[detector]\nbeta = 3\n")
    one_line_error(stereod("run", "--config", str(bad)), 78, r"detector\.beta = 3")
    typo = tmp_path / "typo.toml"
    typo.write_text("[detector]\ntreshold = 30\n")
    one_line_error(
        stereod("run", "--config", str(typo)),
        78,
        r"detector\.treshold: unknown field \(did you mean threshold\?\)",
    )
    # Letters swapped, and a field of a list's item (a room's rig), are answered too.
    typo.write_text('[driver]\nname = "synthetic"\n[driver.options]\nfsp = 30\n')
    one_line_error(
        stereod("run", "--config", str(typo), "--check"),
        78,
        r"driver\.options\.fsp: unknown field \(did you mean fps\?\)",
    )
    room = tmp_path / "room.toml"
    room.write_text(
        '[room]\nname = "lab"\n[[room.rigs]]\nnmae = "a"\ntranslation_m = [0.0, 0.0, 0.0]\n'
        "rotation_deg = [0.0, 0.0, 0.0]\n"
    )
    one_line_error(
        stereod("fuse", "--room", str(room)),
        78,
        r"room\.rigs\.0\.nmae: unknown field \(did you mean name\?\)",
    )
    one_line_error(
        stereod("run", "--config", str(tmp_path / "none.toml")), 66, "no such config file"
    )
    one_line_error(
        stereod("run", "--driver", "warp"), 64, "command line: driver.name = 'warp': no such driver"
    )
    # A driver option from the environment is blamed on the environment, not on the file.
    synthetic = tmp_path / "synthetic.toml"
    synthetic.write_text('[driver]\nname = "synthetic"\n')
    env = {"STEREOD_DRIVER__OPTIONS__WIDTH_PX": "abc"}
    one_line_error(
        stereod("run", "--config", str(synthetic), "--check", env=env),
        78,
        r"environment STEREOD_DRIVER__OPTIONS__WIDTH_PX: driver\.options\.width_px = 'abc'",
    )
    # ... each option by its own variable, and one from the file by the file
    env = {"STEREOD_DRIVER__OPTIONS__BALLS": '[{"heading_deg": 60, "speed_mps": "x"}]'}
    one_line_error(
        stereod("run", "--config", str(synthetic), "--check", env=env),
        78,
        r"environment STEREOD_DRIVER__OPTIONS__BALLS: driver\.options\.balls\.0\.speed_mps = 'x'",
    )
    slow = tmp_path / "slow.toml"
    slow.write_text('[driver]\nname = "synthetic"\n[driver.options]\nfps = -3\n')
    one_line_error(
        stereod(
            "run", "--config", str(slow), "--check", env={"STEREOD_DRIVER__OPTIONS__SEED": "1"}
        ),
        78,
        rf"{re.escape(str(slow))}: driver\.options\.fps = -3",
    )
    # MCAP goes to a file: "-" is standard output for --jsonl only (it made a file named "-")
    for command in ("replay", "export", "record"):
        one_line_error(
            stereod(command, str(tmp_path / "rec"), "--mcap", "-"),
            64,
            r"--mcap: - \(standard output\) is for --jsonl: give the file's name",
        )
    # A driver named by the flag runs without the file's options (another driver's): what it
    # lacks is the flag's to give, not the file's fault.
    one_line_error(
        stereod("record", str(tmp_path / "rec"), "--driver", "replay", "--config", str(synthetic)),
        64,
        r"command line: --driver replay is given no options .*give either path",
    )
    one_line_error(
        stereod("replay", str(tmp_path), "--baseline", "-1"),
        64,
        r"--baseline: -1: must be in 0\.005\.\.10 m \(UVC camera",
    )
    env = {"STEREOD_RIG__BASELINE_M": "-1"}
    one_line_error(
        stereod("run", "--check", env=env),
        78,
        r"STEREOD_RIG__BASELINE_M: invalid config: rig\.baseline_m = '-1'",
    )


def test_truncated_video_finishes_and_says_so(tmp_path: Path) -> None:
    tree = shared_data("video", "tree.avi")
    right = shutil.copyfile(tree, tmp_path / "right.avi")  # each eye its own file
    res = stereod(
        "replay",
        "--left-video",
        str(tree),
        "--right-video",
        str(right),
        "--fps",
        "15",
        "--rate",
        "0",
        "--listen",
        "tcp/127.0.0.1:0",
    )
    assert res.returncode == 65, res.stderr
    assert "68 pairs" in res.stdout
    assert "Traceback" not in res.stderr
    assert "truncated" in res.stderr and "444" in res.stderr


def test_different_sizes_and_counts_between_eyes(tmp_path: Path) -> None:
    def video(name: str, n: int, size: tuple[int, int]) -> str:
        w = cv2.VideoWriter(str(tmp_path / name), cv2.VideoWriter.fourcc(*"MJPG"), 10, size)
        for _ in range(n):
            w.write(np.zeros((size[1], size[0], 3), np.uint8))
        w.release()
        return str(tmp_path / name)

    a, b, c = video("a.avi", 5, (64, 48)), video("b.avi", 5, (32, 24)), video("c.avi", 3, (64, 48))
    d = video("d.avi", 5, (64, 48))
    one_line_error(
        stereod("replay", "--left-video", a, "--right-video", b, "--fps", "10"),
        65,
        "must have one size",
    )
    one_line_error(
        stereod("replay", "--left-video", a, "--right-video", c, "--fps", "10"),
        65,
        "same number of frames",
    )
    ts = tmp_path / "ts.csv"
    ts.write_text("t_ns\n1\n5\n4\n6\n7\n")
    one_line_error(
        stereod(
            "replay",
            "--left-video",
            a,
            "--right-video",
            d,
            "--left-ts",
            str(ts),
            "--right-ts",
            str(ts),
        ),
        65,
        r"ts\.csv line 4: timestamp 4 is not after 5",
    )


def test_unwritable_jsonl_path(scene_dir: tuple[Scene, Path], tmp_path: Path) -> None:
    _, rec = scene_dir
    one_line_error(
        stereod("replay", str(rec), "--jsonl", str(tmp_path / "no" / "dir" / "x.jsonl")),
        73,
        r"x\.jsonl: cannot create the output file",
    )


def test_schema_command_prints_json_schema() -> None:
    res = stereod("schema", "stereod.objects/1")
    assert res.returncode == 0
    assert "velocity_mps" in json.loads(res.stdout)["$defs"]["ObjectState"]["properties"]


def test_synth_command_writes_recording_and_truth(tmp_path: Path) -> None:
    res = stereod(
        "synth",
        str(tmp_path / "s"),
        "--ball",
        "heading=200,speed=0.5,z=2",
        "--duration",
        "3",
        "--size",
        "320x240",
        "--skew-ms",
        "10",
    )
    assert res.returncode == 0, res.stderr
    truth = json.loads((tmp_path / "s" / "truth.json").read_text())
    assert truth["balls"][0]["heading_deg"] == 200 and truth["width_px"] == 320
    assert math.isclose(truth["skew_s"], 0.01)
    bad = stereod("synth", str(tmp_path / "t"), "--ball", "heading=x")
    one_line_error(bad, 64, "heading = 'x': 'x' is not a number")


def test_replay_with_calibration_file(scene_dir: tuple[Scene, Path], tmp_path: Path) -> None:
    """The canonical rig written as a calibration file gives the same positions, now marked
    calibrated with the file's id; a calibration for another image size is refused."""
    from stereod.vision.calibration import canonical, save

    scene, rec = scene_dir
    cal = canonical(scene.baseline_m, scene.hfov_deg, 640, 480)
    path = tmp_path / "cal.json"
    save(cal, path)
    out = tmp_path / "cal.jsonl"
    res = stereod(
        "replay",
        str(rec),
        "--rate",
        "0",
        "--calibration",
        str(path),
        "--jsonl",
        str(out),
        "--listen",
        "tcp/127.0.0.1:0",
    )
    assert res.returncode == 0, res.stderr
    msgs = [json.loads(line) for line in out.read_text().splitlines()]
    assert all(m["geometry"] == "calibrated" and m["calibration_id"] == cal.id for m in msgs)
    ball = scene.balls[0]
    errs = [
        np.linalg.norm(
            np.subtract(o["position_m"], ball.position_m((m["t_ns"] - scene.t0_ns) / 1e9))
        )
        for m in msgs
        for o in m["objects"]
        if o["state"] == "confirmed"
    ]
    assert errs and max(errs) < 0.02
    small = canonical(0.06, 60.0, 320, 240)
    save(small, tmp_path / "small.json")
    one_line_error(
        stereod("replay", str(rec), "--calibration", str(tmp_path / "small.json")),
        78,
        "made for 320x240 frames, the stream is 640x480",
    )


def test_the_crash_log_holds_arguments_that_are_not_utf8(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An argv with bytes that are not UTF-8 (as a shell passes ``$'caf\\xe9'``) is written
    to the crash log escaped; the log used to fail on it and stay empty."""
    from stereod.cli import crash_log

    monkeypatch.setenv("STEREOD_CRASH_DIR", str(tmp_path))
    monkeypatch.setattr("sys.argv", ["stereod", "plot", "--title", "caf\udce9"])
    try:
        raise RuntimeError("a bug")
    except RuntimeError as exc:
        path = crash_log(exc)
    assert path is not None
    text = path.read_text()
    assert text.splitlines()[0].endswith(": stereod plot --title caf\\udce9")
    assert "RuntimeError: a bug" in text


@pytest.mark.parametrize("argv", [["schema"], ["schema", "stereod.status/1"], ["run", "--check"]])
@pytest.mark.parametrize("buffered", [True, False])
def test_standard_output_on_a_full_disk_is_one_line_and_exit_74(
    argv: list[str], buffered: bool
) -> None:
    """``> /dev/full``: the user's output failed, not our code; it was an internal error (70,
    a crash log and "please report it"). Output smaller than the buffer fails only when it
    is flushed: that is done before the exit too (the interpreter's own flush said it in two
    lines of its own and exited 120), with Python's buffering or without."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if not buffered:
        env["PYTHONUNBUFFERED"] = "1"
    with open("/dev/full", "w") as full:
        res = subprocess.run(
            stereod_command(*argv), stdout=full, stderr=subprocess.PIPE, text=True, timeout=60,
            env=env,
        )  # fmt: skip
    assert res.returncode == 74, res.stderr
    assert res.stderr == "stereod: cannot write to standard output: No space left on device\n"


def test_standard_output_closed_is_no_error() -> None:
    """Started with stdout closed (``>&-``), ``print`` writes nothing and the command runs as
    before (watching stdout made it an internal error)."""
    res = subprocess.run(
        stereod_command("schema"), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        text=True, timeout=60, preexec_fn=lambda: os.close(1),
    )  # fmt: skip
    assert res.returncode == 0 and res.stderr == "", res.stderr


def test_run_with_a_file_source_ends_with_its_summary(tmp_path: Path) -> None:
    """``stereod run`` on the replay driver prints what it did at the end, as ``replay`` does
    (it printed nothing, so a newcomer could not tell whether anything was processed); a
    camera's daemon still prints none (its journal would get one at every stop)."""
    rec = write_scene(Scene(width_px=160, height_px=120, fps=15, duration_s=1.0), tmp_path / "r")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{rec}"\n')
    res = stereod("run", "--config", str(cfg), "--rate", "0")
    assert res.returncode == 0, res.stderr
    assert re.fullmatch(
        r"15 pairs from 15 left and 15 right frames, 15 messages published, \d+ object "
        r"observations in [\d.]+ s; drops: none\n",
        res.stdout,
    ), res.stdout


@pytest.mark.parametrize(
    "driver",
    [
        '[driver]\nname = "synthetic"\n[driver.options]\nwidth_px = 320\nheight_px = 240\n',
        '[driver]\nname = "v4l2_minoru"\n[driver.options]\nwidth = 320\nheight = 240\n',
    ],
    ids=["synthetic", "v4l2_minoru"],
)
def test_run_check_holds_the_calibration_against_the_frames_asked_for(
    tmp_path: Path, driver: str
) -> None:
    """A calibration made for 640x480 beside a driver asked for 320x240 fails ``run --check``
    as it fails the run (it passed the check, then the run exited 78); one of the asked size
    passes."""
    from stereod.vision.calibration import canonical, save

    save(canonical(0.06, 60.0, 640, 480), tmp_path / "big.json")
    save(canonical(0.06, 60.0, 320, 240), tmp_path / "small.json")
    for cal, code in (("big", 78), ("small", 0)):
        cfg = tmp_path / f"{cal}.toml"
        cfg.write_text(f'[rig]\ncalibration = "{tmp_path / cal}.json"\n{driver}')
        res = stereod("run", "--config", str(cfg), "--check")
        assert res.returncode == code, res.stderr
    one_line_error(
        stereod("run", "--config", str(tmp_path / "big.toml"), "--check"),
        78,
        "made for 640x480 frames, the stream is 320x240: calibrate at this size or change "
        f"the camera mode; it is rig.calibration in {tmp_path / 'big.toml'}",
    )


def test_run_check_holds_the_calibration_against_a_recording_and_two_videos(
    tmp_path: Path,
) -> None:
    """The replay driver's size is known once its recording's manifest (or the left video)
    is read: ``run --check`` passed a 640x480 calibration beside a 320x240 recording, and
    the run then exited 78."""
    from stereod.vision.calibration import canonical, save
    from stereod_fakes.synth import Ball, Scene, write_scene

    rec = write_scene(
        Scene(width_px=320, height_px=240, duration_s=0.4, balls=[Ball()]), tmp_path / "rec"
    )
    save(canonical(0.06, 60.0, 640, 480), tmp_path / "big.json")
    save(canonical(0.06, 60.0, 320, 240), tmp_path / "small.json")
    videos = sorted(p.name for p in rec.iterdir() if p.suffix in (".avi", ".mkv", ".mp4"))
    sources = {
        "recording": f'path = "{rec}"\n',
        "videos": f'left_video = "{rec / videos[0]}"\nright_video = "{rec / videos[1]}"\n'
        "fps = 15\n",
    }
    for name, options in sources.items():
        for cal, code in (("big", 78), ("small", 0)):
            cfg = tmp_path / f"{name}-{cal}.toml"
            cfg.write_text(
                f'[rig]\ncalibration = "{tmp_path / cal}.json"\n[driver]\nname = "replay"\n'
                f"[driver.options]\n{options}"
            )
            res = stereod("run", "--config", str(cfg), "--check")
            assert res.returncode == code, (name, cal, res.stderr)
            if code:
                assert "made for 640x480 frames, the stream is 320x240" in res.stderr


@pytest.mark.parametrize(
    "driver, env, shown",
    [
        ("synthetic", {"FPS": "15", "COLOR": "false"}, {"fps": 15.0, "color": False}),
        ("v4l2_minoru", {"FPS": "15"}, {"fps": 15.0, "pixel_format": "yuyv"}),
        ("replay", {"PATH": "rec", "LOOP": "true"}, {"path": "rec", "loop": True}),
    ],
)
def test_run_check_prints_the_driver_options_as_the_driver_read_them(
    tmp_path: Path, driver: str, env: dict[str, str], shown: dict[str, object]
) -> None:
    """Options from the environment are strings until the driver reads them: ``--check``
    prints what the run will use (it printed ``"fps": "15"``), and the V4L2 driver's pixel
    format as the bus's bandwidth chose it."""
    variables = {f"STEREOD_DRIVER__OPTIONS__{k}": v for k, v in env.items()}
    res = stereod("run", "--check", "--driver", driver, env=variables, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert json.loads(res.stdout)["driver"]["options"] == shown


def test_run_check_prints_the_log_level_the_run_logs_at(tmp_path: Path) -> None:
    """``STEREOD_LOG_LEVEL`` is no field of the configuration, but the run logs at it:
    ``--check`` prints that level (it printed the configured INFO)."""
    for env, level in (({}, "INFO"), ({"STEREOD_LOG_LEVEL": "debug"}, "DEBUG")):
        res = stereod("run", "--check", "--driver", "synthetic", env=env, cwd=tmp_path)
        assert res.returncode == 0, res.stderr
        assert json.loads(res.stdout)["daemon"]["log_level"] == level
