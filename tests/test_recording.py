"""Recording format: lossless round trip, timestamp files, manifest validation."""

from __future__ import annotations

import contextlib
import json
import signal
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from stereod.errors import InputError, Interrupted, MissingInputError, OutputError
from stereod.files.stop import clear_stop, raise_stop
from stereod.sources.frames import Eye, Frame
from stereod.sources.recording import (
    Codec,
    read_frame_index,
    read_manifest,
    read_timestamps,
)
from stereod.sources.recording_writer import RecordingWriter
from stereod.vision.calibration import canonical
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import Scene, write_scene

from .conftest import ROOT, stereod
from .test_cli import one_line_error


def random_frames(n: int, color: bool, seed: int = 0) -> list[tuple[Frame, Frame]]:
    rng = np.random.default_rng(seed)
    shape = (48, 64, 3) if color else (48, 64)
    out = []
    for k in range(n):
        t = 5_000_000_000 + k * 33_366_666
        out.append(
            (
                Frame(Eye.LEFT, rng.integers(0, 256, shape, np.uint8), t, 100 + k),
                Frame(Eye.RIGHT, rng.integers(0, 256, shape, np.uint8), t + 7_654_321, 200 + 2 * k),
            )
        )
    return out


@pytest.mark.parametrize("color", [False, True])
def test_ffv1_round_trip_is_bit_exact_with_times_and_sequences(tmp_path: Path, color: bool) -> None:
    frames = random_frames(12, color)
    with RecordingWriter(
        tmp_path / "rec",
        64,
        48,
        fps=30.0,
        codec=Codec.FFV1,
        color=color,
        settings={"exposure": 100},
        utc_offset_ns=123,
    ) as w:
        for left, right in frames:
            w.write(left)
            w.write(right)
    man = read_manifest(tmp_path / "rec")
    assert (man.left.frames, man.right.frames, man.settings, man.utc_offset_ns) == (
        12,
        12,
        {"exposure": 100},
        123,
    )
    with ReplayDriver({"path": tmp_path / "rec"}).open() as src:
        for eye, idx in ((src.left, 0), (src.right, 1)):
            for k in range(12):
                got = eye.read()
                want = frames[k][idx]
                assert got is not None
                assert (got.t_ns, got.seq, got.eye) == (want.t_ns, want.seq, want.eye)
                assert np.array_equal(got.image, want.image), f"{eye.eye} frame {k} differs"
            assert eye.read() is None
        assert src.problems() == []


@pytest.mark.parametrize("color", [False, True])
def test_a_lossless_recording_keeps_each_frames_crc32(tmp_path: Path, color: bool) -> None:
    """Beside each FFV1 frame, zlib's CRC-32 of the pixels it was given (row-major bytes);
    a lossy MJPG recording, whose pixels come back changed, has no such column."""
    frames = random_frames(5, color, seed=3)
    for codec in Codec:
        with RecordingWriter(
            tmp_path / codec.value, 64, 48, fps=30.0, codec=codec, color=color
        ) as w:
            for left, right in frames:
                w.write(left)
                w.write(right)
    for eye, idx in (("left", 0), ("right", 1)):
        csv = tmp_path / "ffv1" / f"{eye}.csv"
        assert csv.read_text().splitlines()[0] == "t_ns,seq,crc32"
        want = [zlib.crc32(pair[idx].image.tobytes()) for pair in frames]
        _, seq, crc = read_frame_index(csv)
        assert crc is not None and crc.tolist() == want
        assert seq.tolist() == [pair[idx].seq for pair in frames]
        mjpg = tmp_path / "mjpg" / f"{eye}.csv"
        assert mjpg.read_text().splitlines()[0] == "t_ns,seq"
        assert read_frame_index(mjpg)[2] is None


def test_a_checksum_that_is_no_crc32_is_refused_naming_the_line(tmp_path: Path) -> None:
    p = tmp_path / "left.csv"
    p.write_text("t_ns,seq,crc32\n10,0,123\n20,1,4294967296\n")
    with pytest.raises(
        InputError, match=r"left\.csv line 3: expected a CRC-32 .* '20,1,4294967296'"
    ):
        read_frame_index(p)
    assert read_timestamps(p)[0].tolist() == [10, 20]  # a plain video's timestamps: ignored
    p.write_text("t_ns,seq,crc32\n10,0\n")
    with pytest.raises(InputError, match=r"line 2: expected a CRC-32"):
        read_frame_index(p)
    p.write_text("t_ns,seq\n10,0\n")
    assert read_frame_index(p)[2] is None


def test_a_column_it_does_not_know_is_named_in_a_warning(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """A misspelt ``crc32`` would turn the frames' check off: it is said, and ignored."""
    p = tmp_path / "left.csv"
    p.write_text("t_ns,seq,crc\n10,0,123\n")
    with caplog.at_level("WARNING", logger="stereod.sources.recording"):
        assert read_frame_index(p)[2] is None
    assert "left.csv: ignoring columns this stereod does not read there: 'crc'" in caplog.text
    for header, named in (
        ("t_ns,sequence,crc32", "'sequence'"),
        ("t_ns,crc32", "'crc32'"),
    ):
        caplog.clear()
        p.write_text(f"{header}\n10,123\n")
        with caplog.at_level("WARNING", logger="stereod.sources.recording"):
            assert read_frame_index(p)[2] is None
        assert f"does not read there: {named} (a recording's columns" in caplog.text
    caplog.clear()
    p.write_text("t_ns,seq,crc32\n10,0,123\n")
    with caplog.at_level("WARNING", logger="stereod.sources.recording"):
        assert read_frame_index(p)[2] is not None
    assert caplog.text == ""


def test_timestamp_file_errors_name_file_and_line(tmp_path: Path) -> None:
    p = tmp_path / "ts.csv"
    p.write_text("t_ns\n100\n200\n150\n")
    with pytest.raises(InputError, match=r"ts.csv line 4: timestamp 150 is not after 200"):
        read_timestamps(p)
    p.write_text("time\n1\n")
    with pytest.raises(InputError, match="header 't_ns'"):
        read_timestamps(p)
    p.write_text("t_ns\n1\nabc\n")
    with pytest.raises(InputError, match="line 3: expected an integer"):
        read_timestamps(p)
    with pytest.raises(MissingInputError, match="no such timestamp file"):
        read_timestamps(tmp_path / "nope.csv")
    p.write_text("t_ns,seq\n10,4\n20,6\n")
    t, seq = read_timestamps(p)
    assert t.tolist() == [10, 20] and seq.tolist() == [4, 6]
    # a camera re-plugged during a recording counts its frames from 0 again
    p.write_text("t_ns,seq\n10,0\n20,1\n30,2\n40,0\n50,1\n")
    assert read_timestamps(p)[1].tolist() == [0, 1, 2, 0, 1]
    # As an editor may save it: a byte-order mark first, blank lines at the end.
    p.write_bytes(b"\xef\xbb\xbft_ns,seq\r\n10,4\r\n20,6\r\n\r\n\n")
    t, seq = read_timestamps(p)
    assert t.tolist() == [10, 20] and seq.tolist() == [4, 6]
    p.write_text("t_ns\n1\n\n2\n")  # a blank line between frames is not an end
    with pytest.raises(InputError, match="line 3: expected an integer"):
        read_timestamps(p)


def test_manifest_errors(tmp_path: Path) -> None:
    with pytest.raises(MissingInputError, match="no such recording directory"):
        read_manifest(tmp_path / "missing")
    with pytest.raises(MissingInputError, match=r"recording\.json missing"):
        read_manifest(tmp_path)
    (tmp_path / "recording.json").write_text('{"format": "stereod.recording/1", "width": -1}')
    with pytest.raises(
        InputError, match=r"recording\.json: width = -1: Input should be greater than 0"
    ):
        read_manifest(tmp_path)
    # A misspelt "format" is no manifest of this kind, not a newer one.
    (tmp_path / "recording.json").write_text('{"fromat": "stereod.recording/1", "width": 8}')
    with pytest.raises(InputError, match=r"recording\.json: format: required field is missing"):
        read_manifest(tmp_path)


def test_a_manifest_whose_calibration_is_no_calibration_is_refused(tmp_path: Path) -> None:
    """The calibration a recording stores is checked when the manifest is read, so replay and
    export refuse a bad one alike, naming what is wrong with it."""
    cal = canonical(0.06, 60.0, 64, 48).model_dump(mode="json")
    with RecordingWriter(tmp_path / "rec", 64, 48, fps=30.0, calibration=cal) as w:
        for left, right in random_frames(2, False):
            w.write(left)
            w.write(right)
    assert read_manifest(tmp_path / "rec").calibration == cal
    path = tmp_path / "rec" / "recording.json"
    data = json.loads(path.read_text())
    del data["calibration"]["K1"]
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"calibration: not a valid calibration: K1: required"):
        read_manifest(tmp_path / "rec")


def test_a_newer_manifest_with_fields_this_version_does_not_know_is_read(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Fields are only added within ``stereod.recording/1``: a manifest from a newer stereod
    with a new field, at the top and in an eye's entry, reads as before and one warning names
    both fields."""
    with RecordingWriter(tmp_path / "rec", 64, 48, fps=30.0, codec=Codec.FFV1) as w:
        for left, right in random_frames(2, False):
            w.write(left)
            w.write(right)
    path = tmp_path / "rec" / "recording.json"
    before = read_manifest(tmp_path / "rec")
    data = json.loads(path.read_text())
    data["lens"] = "M12"
    data["left"]["exposure_us"] = 100
    path.write_text(json.dumps(data))
    assert read_manifest(tmp_path / "rec") == before
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and str(path) in warned[0] and "left.exposure_us, lens" in warned[0]
    data["format"] = "stereod.recording/2"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"format = 'stereod\.recording/2': this stereod reads"):
        read_manifest(tmp_path / "rec")
    data["format"] = "stereod.calibration/1"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"not a stereod\.recording file"):
        read_manifest(tmp_path / "rec")


@pytest.mark.parametrize("color", [False, True])
def test_a_writer_left_to_decide_keeps_what_the_first_frame_is(tmp_path: Path, color: bool) -> None:
    """``color=None``: BGR frames are stored as BGR, grey as grey, bit for bit, and the manifest
    says which; a recording that got no frame is grey."""
    frames = random_frames(3, color)
    with RecordingWriter(tmp_path / "rec", 64, 48, fps=30.0, color=None) as w:
        for left, right in frames:
            w.write(left)
            w.write(right)
    assert read_manifest(tmp_path / "rec").color is color
    with ReplayDriver({"path": tmp_path / "rec"}).open() as src:
        got = [src.left.read() for _ in frames]
    assert all(g is not None and np.array_equal(g.image, f.image) for g, (f, _) in zip(got, frames))
    with RecordingWriter(tmp_path / "empty", 64, 48, fps=30.0, color=None):
        pass
    man = read_manifest(tmp_path / "empty")
    assert (man.color, man.left.frames) == (False, 0)
    assert sorted(p.name for p in (tmp_path / "empty").iterdir()) == [
        "left.csv",
        "left.mkv",
        "recording.json",
        "right.csv",
        "right.mkv",
    ]


def test_a_frame_of_another_size_names_the_eye_frame_and_what_was_kept(tmp_path: Path) -> None:
    (left, right), (bad, _) = random_frames(2, False)
    bad = Frame(Eye.LEFT, bad.image[:24, :32], bad.t_ns, bad.seq)
    with pytest.raises(InputError) as got, RecordingWriter(tmp_path / "rec", 64, 48, fps=30.0) as w:
        w.write(left)
        w.write(right)
        w.write(bad)
    assert str(got.value) == (
        f"left frame 101 is 32x24 px, the recording {tmp_path / 'rec'} is 64x48 px: its source "
        "changed the frame size; recording stopped, the frames recorded so far were kept"
    )
    assert (read_manifest(tmp_path / "rec").left.frames, len(list(tmp_path.iterdir()))) == (1, 1)


@pytest.mark.parametrize("codec", list(Codec))
def test_writer_refuses_an_odd_size_before_writing(tmp_path: Path, codec: Codec) -> None:
    with pytest.raises(OutputError, match=r"65x48 px cannot be recorded: .* such as 64x48"):
        RecordingWriter(tmp_path / "rec", 65, 48, fps=30.0, codec=codec)
    assert list(tmp_path.iterdir()) == []


def test_record_refuses_an_odd_size_before_writing(tmp_path: Path) -> None:
    """A driver delivering 321x241 frames: one line, exit 73, nothing written (the video
    writer used to crop them to 320x240 under a manifest saying 321x241)."""
    config = tmp_path / "c.toml"
    config.write_text(
        '[driver]\nname = "synthetic"\n[driver.options]\n'
        "duration_s = 0.5\nwidth_px = 321\nheight_px = 241\n"
    )
    res = stereod("record", str(tmp_path / "rec"), "--config", str(config))
    one_line_error(res, 73, r"rec: 321x241 px cannot be recorded: .*such as 320x240")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


UNREADABLE = """\
import errno, io, os, sys
from stereod.cli import main
target, stat_too = sys.argv[1], sys.argv[2] == "1"
def guard(call):
    def guarded(path, *args, **kwargs):
        if isinstance(path, (str, os.PathLike)) and (
            os.fspath(path) == target or os.fspath(path).startswith(target + os.sep)
        ):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(path))
        return call(path, *args, **kwargs)
    return guarded
os.open, io.open = guard(os.open), guard(io.open)
os.listdir, os.scandir = guard(os.listdir), guard(os.scandir)
if stat_too:
    os.stat = guard(os.stat)
sys.exit(main(sys.argv[3:]))
"""
"""``stereod ARGS`` with ``target`` unreadable as by ``chmod 000`` for a user without
root's override (the tests run as root): opening or listing it, or anything under it, is
refused; with ``stat_too`` (a folder) so is looking it up. OpenCV's own reads are not
affected."""


@pytest.mark.parametrize(
    ("unreadable", "folder", "said"),
    [
        ("", True, r"rec/recording\.json: cannot read the manifest: Permission denied"),
        ("recording.json", False, r"rec/recording\.json: cannot read the manifest: Permission"),
        ("left.csv", False, r"rec/left\.csv: cannot read timestamp file: Permission denied"),
        ("right.mkv", False, r"rec/right\.mkv: cannot read video file: Permission denied"),
    ],
)
def test_unreadable_recording_is_one_line_and_exit_66(
    tmp_path: Path, unreadable: str, folder: bool, said: str
) -> None:
    rec = write_scene(Scene(width_px=64, height_px=48, duration_s=0.4, fps=10), tmp_path / "rec")
    target = rec / unreadable if unreadable else rec
    guard = [sys.executable, "-c", UNREADABLE, str(target), "1" if folder else "0"]
    res = subprocess.run(
        [*guard, "replay", str(rec), "--rate", "0", "-q"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    one_line_error(res, 66, said)


@pytest.mark.parametrize("command", ["replay", "export"])
def test_an_unlisted_recording_with_mcap_is_one_line_and_exit_66(
    tmp_path: Path, command: str
) -> None:
    """``--mcap`` is checked against every file of the recording, which must be listed first."""
    rec = write_scene(Scene(width_px=64, height_px=48, duration_s=0.4, fps=10), tmp_path / "rec")
    guard = [sys.executable, "-c", UNREADABLE, str(rec), "0"]  # chmod 000: stat works
    res = subprocess.run(
        [*guard, command, str(rec), "--mcap", str(tmp_path / "run.mcap")],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    one_line_error(res, 66, r"rec: cannot list the recording: Permission denied")


@pytest.mark.parametrize("more_frames", [False, True])
def test_a_stop_whose_exception_was_swallowed_still_leaves_no_recording(
    tmp_path: Path, more_frames: bool
) -> None:
    """A signal's stop raised where library code caught it (and went on) still stops the
    recording: at the next frame written, or at the end of the ``with`` block. Nothing is
    moved into place and no temporary folder is left."""
    frames = random_frames(4, color=False)
    try:
        with (
            pytest.raises(Interrupted, match="interrupted by SIGHUP"),
            RecordingWriter(tmp_path / "rec", 64, 48, fps=30.0) as w,
        ):
            w.write(frames[0][0])
            with contextlib.suppress(Interrupted):  # caught on its way: too broad an `except`
                raise_stop("synth interrupted by SIGHUP", signal.SIGHUP)
            if more_frames:
                w.write(frames[0][1])
                pytest.fail("the frame after the stop was written")
    finally:
        clear_stop()
    assert list(tmp_path.iterdir()) == []
