"""Fuzzing the recording format: timestamp CSVs and ``recording.json`` manifests, read alone
and as the replay driver opens a recording. Whatever they hold: read, or one line and a
sysexits code; the files never change."""

from __future__ import annotations

import csv
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from stereod.errors import StereodError
from stereod.sources.recording import MANIFEST, read_manifest, read_timestamps
from stereod_fakes.replay import ReplayDriver
from stereod_fakes.synth import Ball, Scene, write_scene

from .fuzz import EXAMPLES, FUZZ, accepted_or_refused, digest, json_values

cells = st.one_of(
    st.integers(min_value=-(2**65), max_value=2**65).map(str),
    st.sampled_from(["", " 5", "1e9", "nan", "0x10", "١٢", "9223372036854775807", "-0"]),
    st.text(max_size=6),
)
rows = st.lists(st.lists(cells, min_size=0, max_size=3).map(",".join), max_size=8)
headers = st.sampled_from(["t_ns", "t_ns,seq", "t_ns, seq", "seq,t_ns", "", "T_NS"])


def _csv_lines(text: str) -> list[str]:
    """The lines of a CSV text as CSV ends them (\r\n, \r or \n; a form feed or another of
    ``str.splitlines``' separators inside a cell ends nothing), without the blank ones at the
    end: nothing but white space in its cells (``,`` too, as a spreadsheet writes an empty
    row), which are no rows."""
    lines = re.split(r"\r\n|\r|\n", text)
    while lines and not "".join(next(csv.reader([lines[-1]]), [])).strip():
        lines.pop()
    return lines


def check_csv(path: Path) -> None:
    before = digest(path)
    result = accepted_or_refused(read_timestamps, path)
    if not isinstance(result, StereodError):
        t, seq = result
        text = path.read_bytes().decode("utf-8-sig")
        assert t.dtype == np.int64 and seq.dtype == np.int64 and len(t) == len(seq)
        assert np.all(np.diff(t) > 0), "accepted timestamps that do not increase"
        assert len(t) == len(_csv_lines(text)) - 1  # one per data row
    assert digest(path) == before


@FUZZ
@given(header=headers, body=rows, newline=st.sampled_from(["\n", "\r\n"]))
@example(header="t_ns,seq", body=["1,0", "99999999999999999999,1"], newline="\n")
@example(header="t_ns", body=["1", "-5"], newline="\n")
@example(header="t_ns", body=["0,\x0c"], newline="\n")  # an extra cell of a form feed
@example(header="t_ns", body=[","], newline="\n")  # a spreadsheet's empty row at the end
def test_timestamp_csv(tmp_path_factory, header: str, body: list[str], newline: str) -> None:
    path = tmp_path_factory.mktemp("csv") / "left.csv"
    path.write_bytes(newline.join([header, *body]).encode() + newline.encode())
    check_csv(path)


@FUZZ
@given(data=st.binary(max_size=200))
@example(data=b"t_ns,seq\n\xff\xfe,1\n")
@example(data=b't_ns\n"1\n')
def test_timestamp_csv_any_bytes(tmp_path_factory, data: bytes) -> None:
    path = tmp_path_factory.mktemp("csv") / "left.csv"
    path.write_bytes(data)
    check_csv(path)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real four-frame recording (FFV1) to corrupt copies of."""
    scene = Scene(width_px=32, height_px=24, fps=10, duration_s=0.4, balls=[Ball()])
    return write_scene(scene, tmp_path_factory.mktemp("rec") / "rec")


PLAUSIBLE = {
    "format": st.sampled_from(["stereod.recording/1", "stereod.recording/2"]),
    "width": st.integers(-1, 200) | st.sampled_from([32, 64, 2**63]),
    "height": st.integers(-1, 200) | st.sampled_from([24, 48, 2**63]),
    "fps": st.none() | st.floats(allow_nan=True, allow_infinity=True) | st.just(10.0),
    "codec": st.sampled_from(["ffv1", "mjpg", "h264"]),
    "color": st.booleans(),
    "utc_offset_ns": st.none() | st.integers(-(2**64), 2**64),
    "extra": st.just(1),
    "video": st.sampled_from(["left.mkv", "right.mkv", "left.csv", "../left.mkv", "/dev/zero", ""]),
    "timestamps": st.sampled_from(["left.csv", "right.csv", "left.mkv", "nope.csv", "r\udcff"]),
    "frames": st.integers(-1, 8) | st.just(10**10),
}
"""Values each field may take: mostly close to the real ones, so that many manifests pass
validation and the replay driver opens the videos they name."""


@st.composite
def manifests(draw: st.DrawFn) -> dict:
    """The recording's manifest with one to three fields replaced by a plausible value, or now
    and then by any JSON value."""
    man = {
        "format": "stereod.recording/1",
        "width": 32,
        "height": 24,
        "fps": 10.0,
        "codec": "ffv1",
        "color": False,
        "left": {"video": "left.mkv", "timestamps": "left.csv", "frames": 4},
        "right": {"video": "right.mkv", "timestamps": "right.csv", "frames": 4},
    }
    for _ in range(draw(st.integers(1, 3))):
        key = draw(st.sampled_from([*PLAUSIBLE, "left", "right"]))
        if key in ("left", "right", "video", "timestamps", "frames"):
            eye = key if key in ("left", "right") else draw(st.sampled_from(["left", "right"]))
            field = draw(st.sampled_from(["video", "timestamps", "frames"]))
            man[eye][field] = draw(PLAUSIBLE[field] | json_values)
        else:
            man[key] = draw(PLAUSIBLE[key]) if draw(st.integers(0, 4)) else draw(json_values)
    return man


@settings(FUZZ, max_examples=max(EXAMPLES * 2 // 3, 1))  # each example copies and opens a recording
@given(man=manifests())
@example(
    man={
        "width": 64,
        "height": 24,
        "left": {"video": "left.mkv", "timestamps": "left.csv", "frames": 4},
        "right": {"video": "right.mkv", "timestamps": "right.csv", "frames": 4},
    }
)
def test_manifest_as_replay_opens_it(tmp_path_factory, recording: Path, man: dict) -> None:
    rec = tmp_path_factory.mktemp("m") / "rec"
    shutil.copytree(recording, rec)
    path = rec / MANIFEST
    path.write_text(json.dumps(man))  # NaN and infinity as Python writes them
    files = {p: digest(p) for p in rec.iterdir()}
    result = accepted_or_refused(read_manifest, rec)
    if not isinstance(result, StereodError):
        opened = accepted_or_refused(ReplayDriver({"path": rec}).open)
        if not isinstance(opened, StereodError):
            with opened as src:
                assert (src.info.width, src.info.height) == (32, 24)
    assert {p: digest(p) for p in rec.iterdir()} == files


@FUZZ
@given(data=st.binary(max_size=300))
def test_manifest_any_bytes(tmp_path_factory, data: bytes) -> None:
    rec = tmp_path_factory.mktemp("m")
    (rec / MANIFEST).write_bytes(data)
    accepted_or_refused(read_manifest, rec)
