"""Recording what a source delivers, and replaying it back exactly."""

from __future__ import annotations

import io
import itertools
import json
import re
import signal
import subprocess
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

import stereod.sources.drivers as drivers
from stereod.cli import main
from stereod.errors import DeviceLost, InputError, InternalError, StereodError
from stereod.sources.frames import Driver, Eye, EyeSource, Frame, StereoSource, merged
from stereod.sources.record import record
from stereod.vision.calibration import canonical, save
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import Renderer, Scene, SyntheticDriver, scene_from_truth
from stereod_fakes.v4l2_kernel import FakeCamera, FakeKernel
from stereod_v4l2_minoru.driver import MinoruDriver

from .conftest import stereod
from .processes import start_stereod
from .test_replay import mcap_messages, temporaries, wait_for


@pytest.mark.parametrize("color", [False, True])
def test_replay_reproduces_recorded_frames_and_timestamps(tmp_path: Path, color: bool) -> None:
    """Grey frames stay grey and BGR frames stay BGR, bit for bit, and the manifest says which."""
    scene = {
        "duration_s": 1.0,
        "fps": 10,
        "skew_s": 0.013,
        "width_px": 160,
        "height_px": 120,
        "color": color,
    }
    cal = tmp_path / "cal.json"
    save(canonical(0.06, 60.0, 160, 120), cal)
    counts = record(SyntheticDriver(scene), tmp_path / "rec", calibration=cal)
    assert counts == {"left": 10, "right": 10}
    truth = [f for pair in Renderer(Scene(**scene)).frames() for f in pair]
    with ReplayDriver({"path": tmp_path / "rec"}).open() as src:
        got = list(merged(src.left, src.right))
    assert len(got) == len(truth)
    for g in got:
        want = next(t for t in truth if t.eye is g.eye and t.seq == g.seq)
        assert g.t_ns == want.t_ns
        assert np.array_equal(g.image, want.image), f"{g.eye} frame {g.seq} differs"
    man = json.loads((tmp_path / "rec" / "recording.json").read_text())
    assert man["calibration"] == json.loads(cal.read_text())
    assert man["color"] is color


def test_a_synthetic_scene_is_recorded_with_its_truth(tmp_path: Path) -> None:
    """Recording the synthetic driver keeps the scene beside the frames as ``truth.json``, as
    ``stereod synth`` does (``stereod demo --keep`` and ``record`` kept none); a looped scene,
    whose times run past it, and a live one, stamped on the host's clock, keep none."""
    options = {"duration_s": 0.4, "fps": 10, "width_px": 80, "height_px": 60}
    record(SyntheticDriver(options), tmp_path / "rec")
    assert scene_from_truth(tmp_path / "rec" / "truth.json") == Scene.model_validate(options)
    record(SyntheticDriver({**options, "loop": True}), tmp_path / "loop", seconds=0.2)
    assert not (tmp_path / "loop" / "truth.json").exists()
    record(SyntheticDriver({**options, "live": True}), tmp_path / "live", seconds=0.2)
    assert not (tmp_path / "live" / "truth.json").exists()


def test_live_record_stops_after_seconds(tmp_path: Path) -> None:
    driver = SyntheticDriver(
        {"duration_s": 10.0, "fps": 20, "live": True, "width_px": 80, "height_px": 60}
    )
    counts = record(driver, tmp_path / "rec", seconds=0.5)
    assert 8 <= counts["left"] <= 11 and 8 <= counts["right"] <= 11
    rows = (tmp_path / "rec" / "left.csv").read_text().splitlines()[1:]
    t = [int(r.split(",")[0]) for r in rows]
    assert all(b > a for a, b in itertools.pairwise(t))


def test_record_and_devices_commands(tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        '[driver]\nname = "synthetic"\n[driver.options]\nduration_s = 0.5\nfps = 10\n'
        "width_px = 80\nheight_px = 60\n"
    )
    res = stereod("record", str(tmp_path / "rec"), "--config", str(cfg))
    assert res.returncode == 0, res.stderr
    assert "recorded 5 left and 5 right frames" in res.stdout
    res = stereod("devices", "--brief")
    assert res.returncode == 0 and res.stdout.strip(), res.stderr


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A real 24 MiB file system (tmpfs); skipped where mounting is not allowed."""
    mnt = tmp_path / "disk"
    mnt.mkdir()
    res = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=24m", "tmpfs", str(mnt)],
        capture_output=True,
        text=True,
    )
    if res.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here: {res.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], check=True)


def test_a_full_disk_stops_the_recording_and_keeps_what_was_recorded(
    tmp_path: Path, small_disk: Path
) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(  # noisy frames do not compress: about 100 KB each in FFV1
        '[driver]\nname = "synthetic"\n[driver.options]\nduration_s = 60\nfps = 15\n'
        "width_px = 320\nheight_px = 240\nnoise_sigma = 30\n"
    )
    out = small_disk / "rec"
    res = stereod("record", str(out), "--config", str(cfg))
    assert res.returncode == 73, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and "the disk is full" in lines[0], res.stderr
    man = json.loads((out / "recording.json").read_text())
    rows = (out / "left.csv").read_text().splitlines()[1:]
    assert 0 < man["left"]["frames"] == len(rows) < 900
    # What was kept replays whole. (Noise of sigma 30 is foreground at the default threshold:
    # the detector would rightly call every frame saturated, which is not what is tested.)
    quiet = tmp_path / "replay.toml"
    quiet.write_text("[detector]\nthreshold = 150.0\n")
    replay = stereod(
        "replay",
        str(out),
        "--rate",
        "0",
        "-q",
        "--listen",
        "tcp/127.0.0.1:0",
        "--config",
        str(quiet),
    )
    assert replay.returncode == 0, replay.stderr


def test_a_full_disk_stops_a_live_recording_with_73_and_no_success(
    tmp_path: Path, small_disk: Path
) -> None:
    """A camera-like source (one thread per eye) filling the disk: both eyes stop, the error
    is one line and exit 73, nothing on stdout says "recorded" and the --mcap is not written;
    the frames recorded so far are kept, the manifest counting exactly those."""
    cfg = tmp_path / "c.toml"
    cfg.write_text(  # noisy frames do not compress: about 100 KB each in FFV1
        '[driver]\nname = "synthetic"\n[driver.options]\nduration_s = 60\nfps = 30\n'
        "width_px = 320\nheight_px = 240\nnoise_sigma = 30\nlive = true\n"
    )
    out, cams = small_disk / "rec", tmp_path / "cams.mcap"
    res = stereod("record", str(out), "--config", str(cfg), "--mcap", str(cams))
    assert res.returncode == 73, res.stderr
    lines = res.stderr.splitlines()
    assert len(lines) == 1 and "the disk is full" in lines[0], res.stderr
    assert "frames recorded so far were kept" in lines[0]
    assert res.stdout == ""
    assert not cams.exists() and temporaries(tmp_path) == []
    assert [p.name for p in small_disk.iterdir()] == ["rec"]
    man = json.loads((out / "recording.json").read_text())
    for eye in ("left", "right"):
        rows = (out / f"{eye}.csv").read_text().splitlines()[1:]
        assert 0 < man[eye]["frames"] == len(rows) < 1800
    # Both eyes stop together: within a second of frames (a loaded host delays the second
    # eye's writer by more than a frame or two), far from the 60 s the source would run.
    assert abs(man["left"]["frames"] - man["right"]["frames"]) <= 30, man


class _FaultyEye(EyeSource):
    """An eye of another source whose read number ``at`` (from 0) fails: it raises ``fault``,
    or, when ``fault`` is a (height, width), delivers a frame of that size instead."""

    def __init__(self, inner: EyeSource, fault: BaseException | tuple[int, int], at: int) -> None:
        self.eye = inner.eye
        self._inner, self._fault, self._at, self._k = inner, fault, at, 0

    def read(self) -> Frame | None:
        frame = self._inner.read()
        k, self._k = self._k, self._k + 1
        if frame is None or k != self._at:
            return frame
        if isinstance(self._fault, BaseException):
            raise self._fault
        return Frame(frame.eye, np.zeros(self._fault, np.uint8), frame.t_ns, frame.seq)

    def interrupt(self) -> None:
        self._inner.interrupt()

    def close(self) -> None:
        self._inner.close()


class FaultyDriver(Driver):
    """The synthetic driver playing a 6 s scene live at 20 Hz (one thread per eye, as a
    camera), whose left eye fails at its frame 10 (see :class:`_FaultyEye`)."""

    name = "faulty"

    def __init__(self, fault: BaseException | tuple[int, int]) -> None:
        self.fault = fault
        self.inner = SyntheticDriver(
            {"duration_s": 6.0, "fps": 20, "width_px": 80, "height_px": 60, "live": True}
        )

    def open(self) -> StereoSource:
        src = self.inner.open()
        return StereoSource(_FaultyEye(src.left, self.fault, 10), src.right, src.info)


FAULTS = [
    pytest.param((30, 40), InputError, "left frame 10 is 40x30 px", id="wrong-size"),
    pytest.param(
        RuntimeError("decoder crashed"),
        InternalError,
        "internal error while recording the left eye: RuntimeError: decoder crashed",
        id="read-raises",
    ),
]


def recorded_frames(out: Path) -> dict[str, int]:
    """Frames per eye in the recording ``out``, checked against its timestamp files."""
    man = json.loads((out / "recording.json").read_text())
    for eye in ("left", "right"):
        assert man[eye]["frames"] == len((out / f"{eye}.csv").read_text().splitlines()) - 1
    return {eye: man[eye]["frames"] for eye in ("left", "right")}


@pytest.mark.parametrize(("fault", "error", "said"), FAULTS)
def test_a_failing_eye_stops_both_and_is_raised(
    tmp_path: Path, fault: BaseException | tuple[int, int], error: type[StereodError], said: str
) -> None:
    """One eye's failure, whatever it is, stops the other eye at once (not 110 frames later,
    at the scene's end) and is raised from record(); a bug is a one-line InternalError naming
    the eye, with the original as its cause. The frames written before it are kept."""
    out = tmp_path / "rec"
    with pytest.raises(error, match=re.escape(said)) as got:
        record(FaultyDriver(fault), out)
    assert "recording stopped, the frames recorded so far were kept" in str(got.value)
    if error is InternalError:
        assert got.value.__cause__ is fault
    counts = recorded_frames(out)
    assert counts["left"] == 10 and 0 < counts["right"] <= 13, counts


class _LostEye(EyeSource):
    """An eye of another source that is lost at its read number ``at`` and on every read
    after (a camera that opens, then fails each read); counts those reads."""

    def __init__(self, inner: EyeSource, at: int) -> None:
        self.eye, self._inner, self._at, self._k, self.lost = inner.eye, inner, at, 0, 0

    def read(self) -> Frame | None:
        self._k += 1
        if self._k > self._at:
            self.lost += 1
            raise DeviceLost("/dev/video0: read failed: Input/output error")
        return self._inner.read()

    def interrupt(self) -> None:
        self._inner.interrupt()


def test_a_camera_lost_on_every_read_is_retried_with_a_backoff(tmp_path: Path) -> None:
    """The recorder retried a lost camera at once, for ever: millions of times a second.
    Now at once, then after 0.1, 0.2, 0.4 s...; the other eye records on."""
    inner = FaultyDriver(RuntimeError("unused")).inner
    lost: list[_LostEye] = []

    class LostDriver(Driver):
        name = "lost"

        def open(self) -> StereoSource:
            src = inner.open()
            lost.append(_LostEye(src.left, 10))
            return StereoSource(lost[0], src.right, src.info)

    counts = record(LostDriver(), tmp_path / "rec", seconds=1.5)
    assert counts["left"] == 10 and counts["right"] >= 25, counts
    assert 3 <= lost[0].lost <= 7, lost[0].lost


@pytest.fixture
def own_signals() -> Iterator[None]:
    """The handlers of the signals a command sets in this process, given back after the test."""
    signums = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    saved = {s: signal.getsignal(s) for s in signums}
    yield
    for s, handler in saved.items():
        signal.signal(s, handler)


@pytest.mark.parametrize(
    ("fault", "code"),
    [pytest.param((30, 40), 65, id="wrong-size"), pytest.param(RuntimeError("x"), 70, id="bug")],
)
def test_a_failing_eye_ends_the_record_command_with_its_code(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    own_signals: None,
    fault: BaseException | tuple[int, int],
    code: int,
) -> None:
    """The command exits with the eye's error's code in one line (a bug's names its crash log,
    with the eye thread's traceback), prints no summary and writes no --mcap."""
    monkeypatch.setenv("STEREOD_CRASH_DIR", str(tmp_path))
    # the command imports its driver loader when it runs
    monkeypatch.setattr(drivers, "load_driver", lambda *_, **__: FaultyDriver(fault))
    cfg = synthetic_config(tmp_path / "c.toml", duration_s=1)
    out, cams = tmp_path / "rec", tmp_path / "cams.mcap"
    assert main(["record", str(out), "--config", str(cfg), "--mcap", str(cams)]) == code
    printed = capsys.readouterr()
    lines = printed.err.splitlines()
    assert len(lines) == 1 and "left" in lines[0], printed.err
    assert printed.out == ""
    assert not cams.exists() and temporaries(tmp_path) == []
    assert recorded_frames(out)["left"] == 10
    if code == 70:
        log = re.search(r"details in (\S+);", lines[0])
        assert log, lines[0]
        text = Path(log.group(1)).read_text()
        assert "RuntimeError: x" in text and "in eye_loop" in text  # the eye thread's traceback


def test_a_v4l2_camera_is_recorded_in_colour(tmp_path: Path) -> None:
    """The V4L2 driver delivers BGR by default: the recording keeps it, says so, and replays
    the very frames the camera gave (the fake kernel gives every run the same frames)."""
    opts = {"left": "/dev/fake0", "right": "/dev/fake1", "width": 64, "height": 48, "fps": 30}

    def camera() -> MinoruDriver:
        return MinoruDriver(
            opts, io=FakeKernel({"/dev/fake0": FakeCamera(), "/dev/fake1": FakeCamera()})
        )

    # The fake kernel has every frame ready at once: stop once both eyes have a few.
    stop, seen = threading.Event(), {Eye.LEFT: 0, Eye.RIGHT: 0}

    def count(frame: Frame) -> None:
        seen[frame.eye] += 1
        if min(seen.values()) >= 3:
            stop.set()

    out = tmp_path / "rec"
    counts = record(camera(), out, stop=stop, on_frame=count)
    assert json.loads((out / "recording.json").read_text())["color"] is True
    live = camera().open()
    try:
        with ReplayDriver({"path": out}).open() as replay:
            for got_eye, live_eye in ((replay.left, live.left), (replay.right, live.right)):
                n = 0
                while (got := got_eye.read()) is not None:
                    want = live_eye.read()
                    assert want is not None and got.image.shape == (48, 64, 3)
                    assert got.seq == want.seq and np.array_equal(got.image, want.image)
                    n += 1
                assert n == counts[got_eye.eye.value] >= 3
    finally:
        live.close()


def synthetic_config(path: Path, **options: object) -> Path:
    """A config whose driver is a small synthetic scene with ``options``."""
    lines = "".join(f"{k} = {json.dumps(v)}\n" for k, v in options.items())
    path.write_text(
        f'[driver]\nname = "synthetic"\n[driver.options]\nwidth_px = 80\nheight_px = 60\n{lines}'
    )
    return path


def test_record_through_symlinks_writes_where_they_lead(tmp_path: Path) -> None:
    """A recording directory that is a link to an empty folder, and an MCAP file that is a link
    to an earlier file: both are written where they lead, and the links stay."""
    cfg = synthetic_config(tmp_path / "c.toml", duration_s=0.5, fps=10)
    (tmp_path / "runs" / "today").mkdir(parents=True)
    rec = tmp_path / "rec"
    rec.symlink_to(tmp_path / "runs" / "today")
    cams = tmp_path / "runs" / "cams.mcap"
    cams.write_bytes(b"earlier recording")
    link = tmp_path / "cams.mcap"
    link.symlink_to(cams)
    res = stereod("record", str(rec), "--config", str(cfg), "--mcap", str(link))
    assert res.returncode == 0, res.stderr
    assert rec.is_symlink() and link.is_symlink(), "a symbolic link was replaced"
    assert json.loads((tmp_path / "runs" / "today" / "recording.json").read_text())["left"] == {
        "video": "left.mkv",
        "timestamps": "left.csv",
        "frames": 5,
    }
    assert mcap_messages(cams.read_bytes(), "/stereod/minoru/left/camera_info") == 5
    assert sorted(p.name for p in tmp_path.rglob(".*")) == []


def test_ctrl_c_ends_a_recording_normally(tmp_path: Path) -> None:
    """Ctrl-C is how a recording without --seconds ends: what was recorded is kept, the MCAP is
    written with it, the summary names the signal, and the exit code is 0."""
    cfg = synthetic_config(tmp_path / "c.toml", duration_s=600, fps=10, live=True)
    out, cams = tmp_path / "rec", tmp_path / "cams.mcap"
    proc = start_stereod("record", str(out), "--config", str(cfg), "--mcap", str(cams))
    wait_for(proc, lambda: bool(list(tmp_path.glob(".cams.mcap.*"))))  # made at the start

    def recorded() -> bool:  # a frame's row in the recording being written
        return any(len(p.read_text().splitlines()) > 1 for p in tmp_path.glob(".rec.*/left.csv"))

    wait_for(proc, recorded)
    proc.send_signal(signal.SIGINT)
    printed, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    said = re.match(
        rf"recorded (\d+) left and \d+ right frames to {out} \(stopped by SIGINT\)", printed
    )
    assert said, printed
    frames = json.loads((out / "recording.json").read_text())["left"]["frames"]
    assert int(said.group(1)) == frames
    assert mcap_messages(cams.read_bytes(), "/stereod/minoru/left/camera_info") == frames


def test_no_frame_keeps_no_recording(tmp_path: Path) -> None:
    """Stopped before the first frame, or from a source none of whose frames is usable, there
    is nothing to keep: no recording (an empty one, which replay refuses, was kept, and
    ``record`` exited 0), and the command says so in one line with exit 65."""
    stop = threading.Event()
    stop.set()
    options = {"duration_s": 0.4, "fps": 10, "width_px": 80, "height_px": 60}
    assert record(SyntheticDriver(options), tmp_path / "none", stop=stop) == {"left": 0, "right": 0}
    assert not (tmp_path / "none").exists()
    src = tmp_path / "src"
    record(SyntheticDriver(options), src)
    manifest = json.loads((src / "recording.json").read_text())
    manifest["color"] = not manifest["color"]  # every frame's check fails: none is usable
    (src / "recording.json").write_text(json.dumps(manifest))
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{src}"\n')
    out = tmp_path / "out"
    res = stereod("record", str(out), "--config", str(cfg))
    assert res.returncode == 65, res.stderr
    assert res.stderr.startswith(f"stereod: no frame recorded: {out} not written (")
    assert res.stderr.count("\n") == 1 and not out.exists()


def _log_times(data: bytes, topic: str) -> list[int]:
    return [m.log_time for _, _, m in make_reader(io.BytesIO(data)).iter_messages(topics=[topic])]


def test_record_mcap_and_a_later_export_stamp_every_frame_alike(tmp_path: Path) -> None:
    """A synthetic source has no UTC clock: the offset ``--mcap`` stamps frames with is kept in
    the manifest, so ``stereod export`` of the recording gives the very same stamps."""
    cfg = synthetic_config(tmp_path / "c.toml", duration_s=0.5, fps=10)
    rec, cams, later = tmp_path / "rec", tmp_path / "cams.mcap", tmp_path / "later.mcap"
    res = stereod("record", str(rec), "--config", str(cfg), "--mcap", str(cams))
    assert res.returncode == 0, res.stderr
    manifest = json.loads((rec / "recording.json").read_text())
    assert manifest["utc_offset_ns"] is not None
    res = stereod("export", str(rec), "--mcap", str(later), "--no-images", "-q")
    assert res.returncode == 0, res.stderr
    for eye in ("left", "right"):
        topic = f"/stereod/minoru/{eye}/camera_info"
        recorded = _log_times(cams.read_bytes(), topic)
        assert len(recorded) == 5
        assert _log_times(later.read_bytes(), topic) == recorded


def test_recording_a_damaged_recording_keeps_what_decodes_and_says_what_is_lost(
    tmp_path: Path,
) -> None:
    """The replay driver reading a recording whose left video is cut in half: the new
    recording keeps the frames that decode, and the run ends as ``replay`` of the same input
    does, one line naming the truncated file and exit 65 (it said nothing and exited 0)."""
    src = tmp_path / "src"
    scene = {"duration_s": 2.0, "fps": 15, "width_px": 80, "height_px": 60}
    record(SyntheticDriver(scene), src)
    video = src / "left.mkv"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    cfg = tmp_path / "c.toml"
    cfg.write_text(f'[driver]\nname = "replay"\n[driver.options]\npath = "{src}"\n')
    res = stereod("record", str(tmp_path / "out"), "--config", str(cfg))
    assert res.returncode == 65, res.stderr
    assert (
        res.stderr.count("\n") == 1
        and "left.mkv: truncated: the manifest says 30 frames" in res.stderr
    )
    kept = re.search(r"recorded (\d+) left and (\d+) right frames", res.stdout)
    assert kept is not None and 0 < int(kept[1]) < 30 and int(kept[2]) == 30, res.stdout
    assert (tmp_path / "out" / "recording.json").exists()
