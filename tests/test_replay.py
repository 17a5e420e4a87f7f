"""Replay driver on plain videos: real files, every inconsistency a clear error; and where
``stereod replay`` writes its outputs (through a symbolic link, into a FIFO), and that a replay
stopped by a signal writes none of them."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import stat
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from stereod.errors import ConfigError, InputError, MissingInputError
from stereod.sources.frames import Eye, Frame
from stereod.sources.recording import Codec
from stereod.sources.recording_writer import RecordingWriter
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import Scene, write_scene

from .conftest import shared_data
from .processes import run_stereod, start_stereod


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


def test_frames_the_camera_lost_are_counted_as_it_would_count_them(tmp_path: Path) -> None:
    """A timestamp file's sequence numbers that jump (100, 101, 108: six frames the camera
    took and the recording lacks) are sequence gaps: the replayed eye counts them, as each
    frame after a gap is played, and the run's summary says so. Numbers that go back (a
    camera re-plugged counts from 0 again) are no gap."""
    l, r = write_video(tmp_path / "l.avi", 6), write_video(tmp_path / "r.avi", 6)
    lt = tmp_path / "l.csv"
    frame = 66_666_667  # ns, 15 Hz
    frames = [0, 1, 8, 9, 10, 11]  # the camera's frames that made it, by when it took them
    lt.write_text(
        "t_ns,seq\n"
        + "".join(f"{k * frame},{seq}\n" for k, seq in zip(frames, [100, 101, 108, 109, 0, 1]))
    )
    rt = write_ts(tmp_path / "r.csv", [k * frame + 1_000_000 for k in frames])
    options = {"left_video": l, "right_video": r, "left_ts": lt, "right_ts": rt}
    with ReplayDriver(options).open() as src:
        seqs = [f.seq for f in iter(src.left.read, None)]
        assert seqs == [100, 101, 108, 109, 0, 1]
        assert src.left.counters().drops == {"sequence_gap": 6}
        assert src.right.counters().drops == {}
    res = run_stereod(
        "replay", "--left-video", str(l), "--right-video", str(r), "--left-ts", str(lt),
        "--right-ts", str(rt), "--rate", "0", "--listen", "tcp/127.0.0.1:0",
    )  # fmt: skip
    assert res.returncode == 0, res.stderr
    assert "drops: left_sequence_gap 6" in res.stdout


def test_loop_continues_timestamps(tmp_path: Path) -> None:
    l, r = write_video(tmp_path / "l.avi", 4), write_video(tmp_path / "r.avi", 4)
    with ReplayDriver({"left_video": l, "right_video": r, "fps": 10, "loop": True}).open() as src:
        got = [src.left.read() for _ in range(10)]
    times = [f.t_ns for f in got if f is not None]
    assert times == [k * 100_000_000 for k in range(10)]


def test_a_loop_keeps_a_truncated_eye_in_step_with_the_other(tmp_path: Path) -> None:
    """One eye's video decodes only 4 of its 10 frames; each lap of a loop moves both eyes'
    stamps by the input's whole span (its timestamps), so lap after lap left frame k stays
    beside right frame k, not 6 frames off as each eye's own decoded span made it."""
    times = [k * 66_666_667 for k in range(10)]
    lt, rt = write_ts(tmp_path / "l.csv", times), write_ts(tmp_path / "r.csv", times)
    l, r = write_video(tmp_path / "l.avi", 10), write_video(tmp_path / "r.avi", 10)
    cut = tmp_path / "cut.avi"
    cap = cv2.VideoCapture(str(l))
    w = cv2.VideoWriter(str(cut), cv2.VideoWriter.fourcc(*"MJPG"), 15.0, (64, 48))
    for _ in range(4):
        ok, img = cap.read()
        assert ok
        w.write(img)
    w.release()
    cap.release()
    opts = {"left_video": cut, "right_video": r, "left_ts": lt, "right_ts": rt, "loop": True}
    with ReplayDriver(opts).open() as src:
        left = [src.left.read() for _ in range(12)]  # three laps of the 4 frames
        right = [src.right.read() for _ in range(30)]  # three laps of the 10
    right_at = {f.t_ns: f.seq for f in right if f is not None}
    for f in left:
        assert f is not None and right_at[f.t_ns] == f.seq, (f.t_ns, f.seq)
    assert {f.seq % 10 for f in left if f is not None} == {0, 1, 2, 3}


def test_truncated_video_plays_what_decodes_and_says_so(tmp_path: Path) -> None:
    tree = shared_data("video", "tree.avi")
    other = shutil.copyfile(tree, tmp_path / "right.avi")  # each eye its own file
    left, right, problems = read_all(
        ReplayDriver({"left_video": tree, "right_video": other, "fps": 15})
    )
    assert len(left) == len(right) == 68
    assert problems and "truncated" in problems[0] and "444" in problems[0] and "68" in problems[0]


def lossless_recording(path: Path, n: int = 12) -> list[np.ndarray]:
    """An FFV1 recording of ``n`` pairs of random colour frames (64x48); the left frames."""
    rng = np.random.default_rng(7)
    lefts = []
    with RecordingWriter(path, 64, 48, fps=30.0, codec=Codec.FFV1, color=True) as w:
        for k in range(n):
            t = 1_000_000_000 + k * 33_000_000
            lefts.append(rng.integers(0, 256, (48, 64, 3), np.uint8))
            w.write(Frame(Eye.LEFT, lefts[-1], t, k))
            w.write(Frame(Eye.RIGHT, rng.integers(0, 256, (48, 64, 3), np.uint8), t + 1000, k))
    return lefts


def damage(path: Path, at: float) -> None:
    """Invert 8 bytes of a file at the share ``at`` of its length, as a failing disk might."""
    data = bytearray(path.read_bytes())
    k = int(len(data) * at)
    data[k : k + 8] = bytes(b ^ 0xFF for b in data[k : k + 8])
    path.write_bytes(data)


def test_a_damaged_lossless_recording_plays_only_the_pixels_it_recorded(tmp_path: Path) -> None:
    """Bytes of the left video inverted half-way: FFmpeg still decodes frames from there on,
    into other pixels. Each of those differs from the CRC-32 recorded for it, so it is left
    out and named, with the file and what to do; every frame played is the one recorded, and
    the right eye plays whole."""
    rec = tmp_path / "rec"
    lefts = lossless_recording(rec)
    damage(rec / "left.mkv", 0.5)
    left, right, problems = read_all(ReplayDriver({"path": rec}))
    assert 0 < len(left) < 12 and len(right) == 12
    for f in left:
        assert np.array_equal(f.image, lefts[f.seq]), f"left frame {f.seq} is not as recorded"
    said = [p for p in problems if "decoded into pixels that differ from the CRC-32" in p]
    assert len(said) == 1 and said[0].startswith(f"{rec / 'left.mkv'}: "), problems
    assert "(the video or left.csv is damaged)" in said[0] and "restore the recording" in said[0]


def with_one_crc_changed(rec: Path, frame: int) -> None:
    """Change frame ``frame``'s CRC-32 in the left eye's CSV (as a damaged frame would make
    its pixels differ from it)."""
    csv = rec / "left.csv"
    head, *rows = csv.read_text().splitlines()
    t, seq, crc = rows[frame].split(",")
    rows[frame] = f"{t},{seq},{(int(crc) + 1) % 2**32}"
    csv.write_text("\n".join([head, *rows]) + "\n")


def test_one_frame_whose_checksum_differs_is_left_out_and_the_run_exits_65(tmp_path: Path) -> None:
    """One frame's CRC-32 differs: that frame alone is left out, the replay runs to its end
    and exits 65 saying which frame (and nothing about timestamps that disagree: its partner
    merely has none), and the MCAP export writes every other frame, pixel for pixel, and exits
    65 the same way."""
    rec = tmp_path / "rec"
    lefts = lossless_recording(rec)
    with_one_crc_changed(rec, 3)
    left, _, problems = read_all(ReplayDriver({"path": rec}))
    assert [f.seq for f in left] == [0, 1, 2, *range(4, 12)]
    assert problems == [
        f"{rec / 'left.mkv'}: frame 3 decoded into pixels that differ from the CRC-32 recorded "
        "for them in left.csv (the video or left.csv is damaged); left out; restore the "
        "recording from a copy, or remove 'crc32' from left.csv's header to use it unchecked"
    ]
    res = run_stereod("replay", str(rec), "--rate", "0", "-q")
    assert res.returncode == 65, res.stderr
    last = res.stderr.splitlines()[-1]  # (random frames are all foreground: said before it)
    assert last.startswith("stereod: ") and "left.mkv: frame 3 decoded" in last
    assert "timestamps disagree" not in res.stderr
    out = tmp_path / "out.mcap"
    res = run_stereod("export", str(rec), "--mcap", str(out), "--png", "-q")
    assert res.returncode == 65 and "left.mkv: frame 3 decoded" in res.stderr, res.stderr
    assert "not exported" in res.stderr
    reader = make_reader(io.BytesIO(out.read_bytes()), decoder_factories=[DecoderFactory()])
    images = [
        cv2.imdecode(np.frombuffer(bytes(decoded.data), np.uint8), cv2.IMREAD_UNCHANGED)
        for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=True)
        if channel.topic.endswith("/left/image/compressed")
    ]
    assert len(images) == 11
    for img, k in zip(images, [0, 1, 2, *range(4, 12)], strict=True):
        assert np.array_equal(img, lefts[k]), f"exported left frame {k} is not as recorded"


def test_a_loop_whose_every_frame_is_left_out_ends_instead_of_spinning(tmp_path: Path) -> None:
    """Every CRC-32 of the left eye differs: a looping replay has nothing to loop, so the
    left eye ends, said (it used to restart that video for ever), the right eye ends its lap
    with nothing left to pair with, and the replay exits 65."""
    rec = tmp_path / "rec"
    lossless_recording(rec, n=4)
    for k in range(4):
        with_one_crc_changed(rec, k)
    driver = ReplayDriver({"path": rec, "loop": True})
    with driver.open() as src:
        assert src.left.read() is None
        assert any("every frame of a lap was left out" in p for p in src.problems())
    res = run_stereod("replay", str(rec), "--loop", "--rate", "0", "-q", timeout=60)
    assert res.returncode == 65, res.stderr


def test_a_lossless_recording_without_checksums_still_plays_bit_exact(tmp_path: Path) -> None:
    """A recording made before the ``crc32`` column existed (``t_ns,seq``) plays as it did."""
    rec = tmp_path / "rec"
    lefts = lossless_recording(rec)
    for eye in ("left", "right"):
        csv = rec / f"{eye}.csv"
        csv.write_text(
            "".join(",".join(r.split(",")[:2]) + "\n" for r in csv.read_text().splitlines())
        )
    assert (rec / "left.csv").read_text().startswith("t_ns,seq\n")
    left, right, problems = read_all(ReplayDriver({"path": rec}))
    assert problems == [] and len(right) == 12
    assert all(np.array_equal(f.image, lefts[f.seq]) for f in left) and len(left) == 12


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
        (
            {"left_video": "a", "right_video": "b", "fps": 10, "left_ts": "c", "right_ts": "d"},
            "exclusive: give fps .* or the two timestamp files, not both",
        ),
        ({"left_video": "a", "right_video": "a", "fps": 10}, "one file: each eye needs its own"),
        ({"left_video": "a", "right_video": "b", "fps": -1}, r"driver.options.fps"),
        ({"path": "x", "bogus": 1}, r"driver.options.bogus"),
    ],
)
def test_option_errors_name_the_field(options: dict, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        ReplayDriver(options)


def test_one_video_as_both_eyes_is_refused_through_a_link_and_from_the_flags(
    tmp_path: Path,
) -> None:
    video = write_video(tmp_path / "v.avi", 4)
    (tmp_path / "link.avi").symlink_to(video)
    with pytest.raises(ConfigError, match="one file: each eye needs its own video"):
        ReplayDriver({"left_video": video, "right_video": tmp_path / "link.avi", "fps": 10})
    r = run_stereod(
        "replay", "--left-video", str(video), "--right-video", str(video), "--fps", "10"
    )
    assert r.returncode == 64, r.stderr
    assert "--left-video and --right-video are one file" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr


# -- `stereod replay`: where its outputs go, and a run a signal stops ----------------------------

PAIRS = 45
"""Stereo pairs in the recording of :func:`rec` (3 s at 15 Hz)."""
LOOPBACK = ["--listen", "tcp/127.0.0.1:0"]


@pytest.fixture(scope="module")
def rec(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small synthetic recording, replayed as fast as possible in about a second."""
    scene = Scene(width_px=160, height_px=120, fps=15, duration_s=PAIRS / 15)
    return write_scene(scene, tmp_path_factory.mktemp("replay") / "rec")


def test_a_readout_longer_than_the_frame_period_is_said_and_the_run_goes_on(rec: Path) -> None:
    """``readout_s`` 0.1 s against frames 1/15 s apart (the recording's): a rolling shutter
    reads a frame within its period, so the run says so once (a notice: exit 0); 0.05 s is
    said nothing of."""
    env = {**os.environ, "STEREOD_RIG__READOUT_S": "0.1"}
    res = run_stereod("replay", str(rec), "--rate", "0", *LOOPBACK, env=env)
    assert res.returncode == 0, res.stderr
    said = [line for line in res.stderr.splitlines() if "rig.readout_s" in line]
    assert said and "longer than the frame period 0.0667 s (15 Hz)" in said[0], res.stderr
    env["STEREOD_RIG__READOUT_S"] = "0.05"
    res = run_stereod("replay", str(rec), "--rate", "0", *LOOPBACK, env=env)
    assert res.returncode == 0 and "rig.readout_s" not in res.stderr, res.stderr


class FifoReader:
    """A named pipe at ``path`` and a thread reading all that is written into it, as the
    program at the other end of a ``mkfifo`` would."""

    def __init__(self, path: Path) -> None:
        os.mkfifo(path)
        self.path = path
        self._data = b""
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        with self.path.open("rb") as fh:  # waits for a writer
            self._data = fh.read()

    def is_fifo(self) -> bool:
        return stat.S_ISFIFO(os.lstat(self.path).st_mode)

    def data(self) -> bytes:
        """What was written, once the writer is done (call after it ended). A writer that never
        opened the pipe leaves it empty: the read is then ended by opening it here."""
        with contextlib.suppress(OSError):  # ENXIO: the reader is done already
            os.close(os.open(self.path, os.O_WRONLY | os.O_NONBLOCK))
        self._thread.join()
        return self._data


def mcap_messages(data: bytes, topic: str) -> int:
    """Messages on ``topic`` in an MCAP file's bytes."""
    return sum(1 for _ in make_reader(io.BytesIO(data)).iter_messages(topics=[topic]))


def temporaries(folder: Path) -> list[str]:
    """Temporary output files left in ``folder``."""
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".part"))


def wait_for(proc: subprocess.Popen, ready: Callable[[], bool]) -> None:
    """Wait until ``ready()``, failing at once if ``proc`` ends first (a minute at most)."""
    deadline = time.monotonic() + 60
    while not ready():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            out, err = proc.communicate()
            pytest.fail(f"never ready (exit {proc.returncode}): {out} {err}")
        time.sleep(0.02)


def test_outputs_go_through_a_symlink_and_into_a_fifo(rec: Path, tmp_path: Path) -> None:
    """A symbolic link is written through (its target replaced, the link kept) and a FIFO is
    written in place (its reader gets the whole MCAP): neither becomes a regular file."""
    target = tmp_path / "runs" / "run.jsonl"
    target.parent.mkdir()
    target.write_text("previous run\n")
    link = tmp_path / "latest.jsonl"
    link.symlink_to(target)
    fifo = FifoReader(tmp_path / "run.mcap")
    res = run_stereod(
        "replay", str(rec), "--rate", "0", "-q", "--jsonl", str(link), "--mcap", str(fifo.path),
        *LOOPBACK,
    )  # fmt: skip
    assert link.is_symlink() and link.resolve() == target, "the symbolic link was replaced"
    assert fifo.is_fifo(), "the FIFO was replaced by a regular file"
    assert res.returncode == 0, res.stderr
    assert len(target.read_text().splitlines()) == PAIRS
    assert mcap_messages(fifo.data(), "/stereod/minoru/objects") == PAIRS
    assert temporaries(tmp_path) == temporaries(target.parent) == []


@pytest.mark.parametrize("flag", ["--jsonl", "--mcap"])
def test_a_fifo_with_no_reader_is_refused_not_waited_for(
    rec: Path, tmp_path: Path, flag: str
) -> None:
    """Opening a FIFO for writing waits for its reader, and no signal could end that wait: a
    FIFO with no reader is refused in one line (73) instead, and stays a FIFO."""
    fifo = tmp_path / "out"
    os.mkfifo(fifo)
    res = run_stereod("replay", str(rec), "--rate", "0", "-q", flag, str(fifo), *LOOPBACK)
    assert res.returncode == 73, res.stderr
    assert res.stderr.endswith("out: a named pipe with no reader; start its reader first\n")
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


@pytest.fixture
def previous(tmp_path: Path) -> dict[Path, bytes]:
    """A JSONL and an MCAP file of an earlier run, which an interrupted one must not touch."""
    files = {tmp_path / "run.jsonl": b"earlier run\n", tmp_path / "run.mcap": b"earlier mcap"}
    for path, data in files.items():
        path.write_bytes(data)
    return files


def test_ctrl_c_while_playing_leaves_the_outputs_and_exits_130(
    rec: Path, tmp_path: Path, previous: dict[Path, bytes]
) -> None:
    jsonl, mcap = previous
    proc = start_stereod(
        "replay", str(rec), "--rate", "0.05", "--jsonl", str(jsonl), "--mcap", str(mcap),
        *LOOPBACK,
    )  # fmt: skip
    # The MCAP's temporary file is made at the first pair; at 1/20 of real time the input's
    # end is a minute away.
    wait_for(proc, lambda: bool(list(tmp_path.glob(".run.mcap.*"))))
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    (line,) = err.splitlines()
    assert re.fullmatch(
        rf"stereod: replay interrupted by SIGINT after \d+ pairs?; {jsonl} and {mcap} left as "
        r"they were \(.*\)",
        line,
    ), line
    assert " pairs from " in out
    assert {p: p.read_bytes() for p in previous} == previous
    assert temporaries(tmp_path) == []


def test_sigterm_while_waiting_for_a_subscriber_leaves_the_jsonl(
    rec: Path, tmp_path: Path, previous: dict[Path, bytes]
) -> None:
    jsonl = next(iter(previous))
    proc = start_stereod(
        "replay", str(rec), "--rate", "0", "-q", "--rig", "nobody_subscribes",
        "--wait-subscriber", "600", "--jsonl", str(jsonl), *LOOPBACK,
    )  # fmt: skip
    wait_for(proc, lambda: bool(list(tmp_path.glob(".run.jsonl.*.part"))))
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert out == "" and err.startswith(
        f"stereod: replay interrupted by SIGTERM after 0 pairs; {jsonl} left as it was"
    ), err
    assert jsonl.read_bytes() == previous[jsonl]
    assert temporaries(tmp_path) == []


def _stdout_read_then_closed(*args: str) -> tuple[int, str]:
    """``stereod replay ARGS | head -1``: its exit code and stderr, once the first line (the
    first pair's message) was read and stdout closed."""
    proc = start_stereod("replay", *args, *LOOPBACK)
    assert proc.stdout is not None and proc.stderr is not None
    assert json.loads(proc.stdout.readline())["seq"] == 0
    proc.stdout.close()
    with proc.stderr:
        err = proc.stderr.read()
    proc.wait(60)
    return proc.returncode, err


@pytest.mark.parametrize("mcap", [None, "/dev/null"])
def test_jsonl_into_stdout_whose_reader_stops_ends_the_replay_quietly(
    rec: Path, mcap: str | None
) -> None:
    """``replay --jsonl /dev/stdout | head -1``: the replay ends when ``head`` has its line,
    quietly with 0 as any command whose stdout's reader stops; an ``--mcap`` written in place
    loses nothing either."""
    extra = ["--mcap", mcap] if mcap else []
    assert _stdout_read_then_closed(
        str(rec), "--rate", "0.2", "--jsonl", "/dev/stdout", *extra
    ) == (0, "")


def test_jsonl_reader_gone_leaves_the_mcap_file_and_says_so(
    rec: Path, tmp_path: Path, previous: dict[Path, bytes]
) -> None:
    """With ``--mcap`` into a file as well, that file would hold part of the input: it is left
    as it was, and the replay says so (141, what a shell reports for a command SIGPIPE
    ended)."""
    mcap = tmp_path / "run.mcap"
    code, err = _stdout_read_then_closed(
        str(rec), "--rate", "0.2", "--jsonl", "/dev/stdout", "--mcap", str(mcap)
    )
    assert code == 141, err
    stopped = re.fullmatch(
        r"stereod: replay stopped after (\d+) pairs?: /dev/stdout: its reader closed it; "
        rf"{re.escape(str(mcap))} left as it was \(.*\)\n",
        err,
    )
    assert stopped, err
    # Each line is flushed as it is written, so the reader's going is seen a few pairs later
    # (at a pair each 0.33 s), not once 8 kB of lines have been buffered (about 16 pairs).
    assert int(stopped[1]) < 10, err
    assert {p: p.read_bytes() for p in previous} == previous and temporaries(tmp_path) == []


def test_a_looping_replay_ends_normally_when_its_jsonl_reader_goes(
    rec: Path, tmp_path: Path
) -> None:
    """``replay --loop`` has no end of its own; its JSONL reader going away ends it as a
    signal would, normally: 0, and the MCAP of what played is written."""
    mcap = tmp_path / "run.mcap"
    code, err = _stdout_read_then_closed(
        str(rec), "--loop", "--rate", "0.2", "--jsonl", "/dev/stdout", "--mcap", str(mcap)
    )
    assert (code, err) == (0, "")
    assert mcap_messages(mcap.read_bytes(), "/stereod/minoru/objects") >= 1


def test_summaries_go_to_stderr_when_the_jsonl_is_stdout(rec: Path) -> None:
    """``replay --jsonl /dev/stdout | jq``: every line on stdout is a message, the summary
    line is on stderr."""
    res = run_stereod("replay", str(rec), "--rate", "0", "--jsonl", "/dev/stdout", *LOOPBACK)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert [json.loads(line)["seq"] for line in lines] == list(range(PAIRS))
    assert f"{PAIRS} pairs from " in res.stderr


def test_a_named_pipe_whose_reader_dies_is_an_error(rec: Path, tmp_path: Path) -> None:
    """A named pipe's reader that goes away mid-run (it crashed) is not ``| head``: one line
    and 73."""
    fifo = tmp_path / "out.jsonl"
    os.mkfifo(fifo)

    def read_one_line() -> None:
        with fifo.open("rb") as fh:
            fh.readline()

    reader = threading.Thread(target=read_one_line)
    reader.start()
    res = run_stereod("replay", str(rec), "--rate", "0.2", "-q", "--jsonl", str(fifo), *LOOPBACK)
    reader.join()
    assert res.returncode == 73, res.stderr
    assert res.stderr == f"stereod: {fifo}: its reader closed it\n"


def test_a_loop_stopped_before_its_first_pair_leaves_both_outputs_as_they_were(
    tmp_path: Path,
) -> None:
    """A looping replay waiting for a subscriber, stopped before any pair, writes neither
    output: a previous run's JSONL and MCAP stay whole (the JSONL used to be emptied while
    the MCAP was kept), and the summary says both were not written."""
    from .conftest import free_endpoint
    from .sockets import process_sockets

    rec = tmp_path / "rec"
    lossless_recording(rec, n=4)
    jsonl, mcap = tmp_path / "run.jsonl", tmp_path / "run.mcap"
    jsonl.write_text("earlier\n")
    mcap.write_text("earlier\n")
    endpoint = free_endpoint()
    port = int(endpoint.rsplit(":", 1)[1])
    proc = start_stereod(
        "replay", str(rec), "--loop", "--wait-subscriber", "60", "--listen", endpoint,
        "--jsonl", str(jsonl), "--mcap", str(mcap),
    )  # fmt: skip
    deadline = time.monotonic() + 30
    while not any(s.listening and s.port == port for s in process_sockets(proc.pid)):
        assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.3)  # its signal handlers are set before the session opens
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert jsonl.read_text() == "earlier\n" and mcap.read_text() == "earlier\n", (out, err)
    assert f"no pair was processed: {jsonl} and {mcap} not written" in out + err


def test_jsonl_dash_is_standard_output_not_a_file_named_dash(tmp_path: Path) -> None:
    """``--jsonl -`` writes the messages to standard output, the summary to stderr, and makes
    no file named ``-`` (it did)."""
    rec = tmp_path / "rec"
    lossless_recording(rec, n=4)
    res = run_stereod("replay", str(rec), "--rate", "0", "--jsonl", "-", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert lines and all(json.loads(line)["schema"] == "stereod.objects/1" for line in lines)
    assert " pairs from " in res.stderr
    assert not (tmp_path / "-").exists()
