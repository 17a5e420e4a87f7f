"""Recording format: lossless round trip, timestamp files, manifest validation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stereod.errors import InputError, MissingInputError
from stereod.frames import Eye, Frame
from stereod.recording import Codec, RecordingWriter, read_manifest, read_timestamps
from stereod_fakes.replay import ReplayDriver


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


def test_manifest_errors(tmp_path: Path) -> None:
    with pytest.raises(MissingInputError, match="no such recording directory"):
        read_manifest(tmp_path / "missing")
    with pytest.raises(MissingInputError, match=r"recording\.json missing"):
        read_manifest(tmp_path)
    (tmp_path / "recording.json").write_text('{"width": -1}')
    with pytest.raises(
        InputError, match=r"recording\.json: width = -1: Input should be greater than 0"
    ):
        read_manifest(tmp_path)
