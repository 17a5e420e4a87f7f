"""MCAP export: read back with independent readers and checked against the run it came from.

A small synthetic run (two balls crossing, 10 ms skew between the eyes) is rendered and replayed
with the real commands; its JSONL and recording are exported. The file is read with rosbags,
deserialising with rosbags' own ROS 2 Humble definitions (not the file's schemas), and once with
the ``mcap`` reader and mcap-ros2-support's decoder. Every number is compared with the JSONL,
the timestamp files or the calibration.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import shutil
import signal
import subprocess
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import cv2
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from stereod.bus.messages import ObjectsMessage
from stereod.errors import InputError, MissingInputError, OutputError
from stereod.ros.export_mcap import export_run
from stereod.ros.mapping import RosMessages
from stereod.ros.mcap_writer import ExportSummary, McapRunWriter
from stereod.ros.names import T_ODOM
from stereod.sources.frames import Eye, Frame
from stereod.vision.calibration import Calibration, canonical, from_arrays

from .conftest import ROOT, stereod
from .processes import start_stereod
from .test_replay import FifoReader, mcap_messages, temporaries, wait_for

pytestmark = pytest.mark.xdist_group("export_mcap")
"""One worker records the run these tests read (``recorded``) once."""

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
GOLDEN = ROOT / "tests" / "golden" / "objects_example.json"
BASELINE_M = 0.06
HFOV_DEG = 60.0
W, H = 320, 240
RIG = "/stereod/minoru"


@dataclass
class Bag:
    """Messages by topic, in file order: (log_time ns, message deserialised by rosbags)."""

    topics: dict[str, list[tuple[int, Any]]]
    types: dict[str, str]
    qos: dict[str, list[Any]]

    def msgs(self, topic: str) -> list[Any]:
        return [m for _, m in self.topics.get(topic, [])]

    def counts(self) -> dict[str, int]:
        return {t: len(v) for t, v in self.topics.items()}


def read_bag(path: Path) -> Bag:
    """Read with rosbags; deserialise with its bundled Humble types and check that serialising
    the result again gives back the exact bytes (the CDR is canonical)."""
    topics: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    types: dict[str, str] = {}
    qos: dict[str, list[Any]] = {}
    with AnyReader([path]) as reader:
        for c in reader.connections:
            types[c.topic] = c.msgtype
            qos[c.topic] = list(getattr(c.ext, "offered_qos_profiles", []))
            official, _ = TYPESTORE.generate_msgdef(c.msgtype, ros_version=2)
            assert c.msgdef.data == official, f"{c.topic}: schema is not the Humble definition"
        for c, t, raw in reader.messages():
            msg = TYPESTORE.deserialize_cdr(raw, c.msgtype)
            again = bytes(TYPESTORE.serialize_cdr(msg, c.msgtype))
            assert again == bytes(raw), f"{c.topic}: CDR does not round-trip"
            topics[c.topic].append((t, msg))
    return Bag(dict(topics), types, qos)


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def xyz(v: Any) -> tuple[float, float, float]:
    return (v.x, v.y, v.z)


def quat(q: Any) -> Rotation:
    return Rotation.from_quat([q.x, q.y, q.z, q.w])


@dataclass
class Recorded:
    """A synthetic run: its recording, its JSONL, and the MCAP its replay wrote (--mcap)."""

    rec: Path
    jsonl: Path
    lines: list[str]
    messages: list[dict[str, Any]]
    replay_mcap: Path

    @property
    def offset_ns(self) -> int:
        return self.messages[0]["stamp_utc_ns"] - self.messages[0]["t_ns"]

    def frame_times(self, eye: str) -> tuple[np.ndarray, np.ndarray]:
        return frame_times(self.rec, eye)


def frame_times(rec: Path, eye: str) -> tuple[np.ndarray, np.ndarray]:
    """(t_ns, seq) of every frame of one eye of a recording, from its timestamp file."""
    rows = np.loadtxt(rec / f"{eye}.csv", delimiter=",", skiprows=1, dtype=np.int64)
    return rows[:, 0], rows[:, 1]


@dataclass
class Run(Recorded):
    """One MCAP file of the run, read back; ``summary`` is there when it came from the API."""

    mcap: Path
    summary: ExportSummary | None
    bag: Bag


def run_ok(*args: str) -> str:
    res = stereod(*args)
    assert res.returncode == 0, res.stderr
    return res.stdout


GEOMETRY = ["--baseline", str(BASELINE_M), "--hfov", str(HFOV_DEG)]


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Recorded:
    base = tmp_path_factory.mktemp("mcap")
    rec = base / "rec"
    run_ok(
        "synth", str(rec), "--size", f"{W}x{H}", "--fps", "15", "--duration", "4",
        "--lead-in", "1", "--travel", "1.2", "--skew-ms", "10", *GEOMETRY,
        "--ball", "heading=60,speed=0.7,z=1.8", "--ball", "heading=270,speed=0.4,y=-0.2,z=2.5",
    )  # fmt: skip
    jsonl = base / "run.jsonl"
    replay_mcap = base / "replay.mcap"
    out = run_ok(
        "replay", str(rec), "--rate", "0", "--jsonl", str(jsonl), "--mcap", str(replay_mcap),
        *GEOMETRY,
    )  # fmt: skip
    assert f"wrote {replay_mcap}:" in out
    lines = jsonl.read_text().splitlines()
    return Recorded(rec, jsonl, lines, [json.loads(x) for x in lines], replay_mcap)


HOW = ("export_run", "stereod export", "stereod replay --mcap")


@pytest.fixture(scope="module", params=HOW)
def run(request: pytest.FixtureRequest, recorded: Recorded) -> Run:
    """The run's MCAP three ways: the API, the export command, written during the replay."""
    r = recorded
    out = r.rec.parent / f"{HOW.index(request.param)}.mcap"
    summary = None
    if request.param == "export_run":
        summary = export_run(
            out, jsonl=r.jsonl, recording=r.rec, baseline_m=BASELINE_M, hfov_deg=HFOV_DEG
        )
    elif request.param == "stereod export":
        printed = run_ok(
            "export", str(r.rec), "--jsonl", str(r.jsonl), "--mcap", str(out), *GEOMETRY
        )
        assert printed.startswith(f"wrote {out}:") and "clock from jsonl" in printed
    else:
        out = r.replay_mcap
    return Run(r.rec, r.jsonl, r.lines, r.messages, r.replay_mcap, out, summary, read_bag(out))


def test_topics_types_and_counts_match_the_run(run: Run) -> None:
    bag, msgs = run.bag, run.messages
    states = [o for m in msgs for o in m["objects"]]
    assert len(states) >= 30 and any(o["velocity_valid"] for o in states)
    n_left = len(run.frame_times("left")[0])
    n_right = len(run.frame_times("right")[0])
    expected = {
        "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
        f"{RIG}/left/image/compressed": ("sensor_msgs/msg/CompressedImage", n_left),
        f"{RIG}/right/image/compressed": ("sensor_msgs/msg/CompressedImage", n_right),
        f"{RIG}/left/camera_info": ("sensor_msgs/msg/CameraInfo", n_left),
        f"{RIG}/right/camera_info": ("sensor_msgs/msg/CameraInfo", n_right),
        f"{RIG}/tracks/odom": ("nav_msgs/msg/Odometry", len(states)),
        f"{RIG}/tracks/markers": ("visualization_msgs/msg/MarkerArray", len(msgs)),
        f"{RIG}/objects": ("std_msgs/msg/String", len(msgs)),
    }
    valid: dict[int, int] = defaultdict(int)
    for o in states:
        if o["velocity_valid"]:
            valid[o["track_id"]] += 1
    for tid, n in valid.items():
        expected[f"{RIG}/tracks/track_{tid}/speed_heading"] = (
            "geometry_msgs/msg/Vector3Stamped",
            n,
        )
    assert {t: (bag.types[t], n) for t, n in bag.counts().items()} == expected
    if run.summary is not None:
        assert run.summary.messages == bag.counts()
        assert run.summary.clock == "jsonl"
        assert run.summary.problems == []


def test_tracks_equal_the_jsonl(run: Run) -> None:
    odom = {(stamp_ns(m.header), m.child_frame_id): m for m in run.bag.msgs(f"{RIG}/tracks/odom")}
    seen_null_heading_sigma = False
    seen_invalid_velocity = False
    for m in run.messages:
        for o in m["objects"]:
            od = odom[(o["stamp_utc_ns"], f"stereod_minoru_track_{o['track_id']}")]
            assert o["stamp_utc_ns"] == m["stamp_utc_ns"]
            assert od.header.frame_id == "stereod_minoru_optical"
            np.testing.assert_allclose(xyz(od.pose.pose.position), o["position_m"], atol=1e-9)
            np.testing.assert_allclose(xyz(od.twist.twist.linear), o["velocity_mps"], atol=1e-9)
            np.testing.assert_allclose(xyz(od.twist.twist.angular), 0.0, atol=0)
            pc = np.asarray(od.pose.covariance).reshape(6, 6)
            np.testing.assert_allclose(
                np.diag(pc)[:3], np.square(o["position_sigma_m"]), rtol=1e-12
            )
            if o["heading_sigma_deg"] is None:
                seen_null_heading_sigma = True
            if o["heading_valid"] and o["heading_sigma_deg"] is not None:
                assert pc[4, 4] == pytest.approx(math.radians(o["heading_sigma_deg"]) ** 2)
            else:
                assert pc[4, 4] == -1.0  # ROS: not estimated, "unknown"
            tc = np.asarray(od.twist.covariance).reshape(6, 6)
            if o["velocity_valid"] and o["velocity_sigma_mps"] is not None:
                np.testing.assert_allclose(np.diag(tc)[:3], np.square(o["velocity_sigma_mps"]))
                assert list(np.diag(tc)[3:]) == [-1.0, -1.0, -1.0]  # angular: not estimated
            else:  # no valid velocity: the whole twist is "unknown", explicitly
                seen_invalid_velocity = True
                assert tc[0, 0] == -1.0 and np.count_nonzero(tc) == 1
            # The orientation is the heading: body +X along (sin h, 0, cos h), body +Z up (-Y).
            h = math.radians(o["heading_deg"])
            rot = quat(od.pose.pose.orientation)
            np.testing.assert_allclose(
                rot.apply([1, 0, 0]), [math.sin(h), 0, math.cos(h)], atol=1e-9
            )
            np.testing.assert_allclose(rot.apply([0, 0, 1]), [0, -1, 0], atol=1e-9)
            # Speed and heading follow from the twist (eq. 22, 23).
            vx, _, vz = o["velocity_mps"]
            speed = math.hypot(*xyz(od.twist.twist.linear))
            assert speed == pytest.approx(o["speed_mps"], rel=1e-9, abs=1e-12)
            if o["velocity_valid"]:
                heading = math.degrees(math.atan2(vx, vz)) % 360.0
                assert (heading - o["heading_deg"] + 180) % 360 - 180 == pytest.approx(0, abs=1e-6)
    assert not seen_null_heading_sigma  # the null case is covered by the golden message test
    assert seen_invalid_velocity  # a track's first states, before its velocity is valid


def test_speed_heading_topics(run: Run) -> None:
    for m in run.messages:
        for o in m["objects"]:
            if not o["velocity_valid"]:
                continue
            topic = f"{RIG}/tracks/track_{o['track_id']}/speed_heading"
            hits = [v for v in run.bag.msgs(topic) if stamp_ns(v.header) == o["stamp_utc_ns"]]
            assert len(hits) == 1
            assert xyz(hits[0].vector) == (o["speed_mps"], o["heading_deg"], -o["velocity_mps"][1])
            assert hits[0].header.frame_id == "stereod_minoru_optical"


def test_stamps_are_capture_instants(run: Run) -> None:
    bag = run.bag
    for topic, items in bag.topics.items():
        for log_time, msg in items:
            header = getattr(msg, "header", None)
            if header is not None:
                assert stamp_ns(header) == log_time, topic
    objects = bag.topics[f"{RIG}/objects"]
    assert [t for t, _ in objects] == [m["stamp_utc_ns"] for m in run.messages]
    stamps = {}
    for eye in ("left", "right"):
        t, seq = run.frame_times(eye)
        for topic in (f"{RIG}/{eye}/image/compressed", f"{RIG}/{eye}/camera_info"):
            got = [stamp_ns(m.header) for m in bag.msgs(topic)]
            assert got == (t + run.offset_ns).tolist(), topic
            assert {m.header.frame_id for m in bag.msgs(topic)} == {f"stereod_minoru_{eye}_optical"}
        stamps[eye] = dict(zip(seq.tolist(), (t + run.offset_ns).tolist()))
    # Frames and tracks share one clock: a pair's stamp lies between its two frames' stamps
    # (the later eye's instant with skew compensation, the midpoint without).
    for m in run.messages:
        pair = (stamps["left"][m["left_seq"]], stamps["right"][m["right_seq"]])
        assert min(pair) <= m["stamp_utc_ns"] <= max(pair)
        assert m["stamp_utc_ns"] - m["t_ns"] == run.offset_ns
    # Written in stamp order, /tf_static first.
    first = min(t for items in bag.topics.values() for t, _ in items)
    assert bag.topics["/tf_static"][0][0] == first
    if run.summary is not None:
        assert first == run.summary.start_ns


def test_images_are_the_recorded_frames(run: Run) -> None:
    for eye in ("left", "right"):
        images = run.bag.msgs(f"{RIG}/{eye}/image/compressed")
        assert {m.format for m in images} == {"jpeg"}
        cap = cv2.VideoCapture(str(run.rec / f"{eye}.mkv"), cv2.CAP_FFMPEG)
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        for i in (0, len(images) // 2):
            cap.set(cv2.CAP_PROP_POS_FRAMES, i)
            ok, ref = cap.read()
            assert ok and ref is not None
            ref = ref[..., 0] if ref.ndim == 3 else ref
            img = cv2.imdecode(np.frombuffer(bytes(images[i].data), np.uint8), cv2.IMREAD_UNCHANGED)
            assert img is not None and img.shape == (H, W)
            assert np.abs(img.astype(int) - ref.astype(int)).mean() < 2.0
        cap.release()


def test_camera_info_is_the_calibration(run: Run) -> None:
    cal = canonical(BASELINE_M, HFOV_DEG, W, H)
    f = W / (2 * math.tan(math.radians(HFOV_DEG) / 2))
    for eye, (k, d, r, p) in {
        "left": ("K1", "D1", "R1", "P1"),
        "right": ("K2", "D2", "R2", "P2"),
    }.items():
        infos = run.bag.msgs(f"{RIG}/{eye}/camera_info")
        for info in (infos[0], infos[-1]):
            assert (info.width, info.height) == (W, H)
            assert info.distortion_model == "plumb_bob"
            np.testing.assert_allclose(np.reshape(info.k, (3, 3)), cal.array(k), atol=1e-12)
            np.testing.assert_allclose(np.reshape(info.p, (3, 4)), cal.array(p), atol=1e-12)
            np.testing.assert_allclose(np.reshape(info.r, (3, 3)), cal.array(r), atol=1e-12)
            np.testing.assert_allclose(info.d, cal.array(d).ravel(), atol=1e-12)
            assert info.k[0] == pytest.approx(f, rel=1e-12)
            pr = np.reshape(info.p, (3, 4))
            assert pr[0, 3] == pytest.approx(0.0 if eye == "left" else -pr[0, 0] * BASELINE_M)


def test_tf_static_maps_the_rig_frame_to_the_body_frame(run: Run) -> None:
    (tf,) = run.bag.msgs("/tf_static")
    by_child = {t.child_frame_id: t for t in tf.transforms}
    assert set(by_child) == {
        "stereod_minoru_optical",
        "stereod_minoru_left_optical",
        "stereod_minoru_right_optical",
    }
    body = by_child["stereod_minoru_optical"]
    assert body.header.frame_id == "stereod_minoru"
    rot = quat(body.transform.rotation)
    np.testing.assert_allclose(rot.apply([0, 0, 1]), [1, 0, 0], atol=1e-12)  # forward
    np.testing.assert_allclose(rot.apply([1, 0, 0]), [0, -1, 0], atol=1e-12)  # right
    np.testing.assert_allclose(rot.apply([0, 1, 0]), [0, 0, -1], atol=1e-12)  # down
    assert xyz(body.transform.translation) == (0, 0, 0)
    for eye, x in (("left", -BASELINE_M / 2), ("right", BASELINE_M / 2)):
        t = by_child[f"stereod_minoru_{eye}_optical"]
        assert t.header.frame_id == "stereod_minoru_optical"
        np.testing.assert_allclose(xyz(t.transform.translation), [x, 0, 0], atol=1e-12)
        np.testing.assert_allclose(quat(t.transform.rotation).as_matrix(), np.eye(3), atol=1e-12)
    # Latched for `ros2 bag play`: reliable, transient local (rosbag2's QoS metadata).
    (qos,) = run.bag.qos["/tf_static"]
    assert qos.durability.name == "TRANSIENT_LOCAL" and qos.reliability.name == "RELIABLE"


def test_markers_follow_the_tracks_and_delete_ended_ones(run: Run) -> None:
    arrays = run.bag.msgs(f"{RIG}/tracks/markers")
    prev: set[int] = set()
    deletes_seen = 0
    for m, arr in zip(run.messages, arrays, strict=True):
        ids = {o["track_id"] for o in m["objects"]}
        adds = {(k.ns, k.id): k for k in arr.markers if k.action == 0}
        deletes = {(k.ns, k.id) for k in arr.markers if k.action == 2}
        assert {i for ns, i in deletes if ns == "tracks"} == prev - ids
        deletes_seen += len(prev - ids)
        for o in m["objects"]:
            sphere = adds[("tracks", o["track_id"])]
            assert sphere.type == 2 and sphere.header.frame_id == "stereod_minoru_optical"
            np.testing.assert_allclose(xyz(sphere.pose.position), o["position_m"], atol=1e-12)
            np.testing.assert_allclose(xyz(sphere.scale), [o["size_m"]] * 3, atol=1e-12)
            assert str(o["track_id"]) in adds[("labels", o["track_id"])].text
            if o["velocity_valid"]:
                arrow = adds[("velocity", o["track_id"])]
                tail, tip = (np.array(xyz(p)) for p in arrow.points)
                np.testing.assert_allclose(tip - tail, o["velocity_mps"], atol=1e-12)
            else:
                assert ("velocity", o["track_id"]) not in adds
        prev = ids
    assert deletes_seen >= 2, "the run should end two tracks"


def test_markers_expire_after_three_frame_periods(run: Run) -> None:
    """Every added marker lives 3 periods of the recording's 15 fps (0.2 s), so a run that
    stops mid-track leaves no marker behind in a 3D panel."""
    added = [k for arr in run.bag.msgs(f"{RIG}/tracks/markers") for k in arr.markers]
    added = [k for k in added if k.action == 0]
    assert len(added) >= 30
    for k in added:
        lifetime_s = k.lifetime.sec + k.lifetime.nanosec * 1e-9
        assert lifetime_s == pytest.approx(3 / 15, abs=1e-6), (k.ns, k.id, lifetime_s)


def test_objects_topic_carries_the_jsonl_lines(run: Run) -> None:
    assert [m.data for m in run.bag.msgs(f"{RIG}/objects")] == run.lines


def test_second_reader_mcap_ros2(run: Run) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts: dict[str, int] = defaultdict(int)
    positions = []
    with run.mcap.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["rosbag2"]["ROS_DISTRO"] == "humble"
        for _, channel, _, decoded in reader.iter_decoded_messages(log_time_order=True):
            counts[channel.topic] += 1
            if channel.topic.endswith("/odom"):
                positions.append(xyz(decoded.pose.pose.position))
    assert dict(counts) == run.bag.counts()
    expected = [tuple(o["position_m"]) for m in run.messages for o in m["objects"]]
    assert sorted(positions) == sorted(expected)


def test_recording_only_without_images(recorded: Recorded, tmp_path: Path) -> None:
    out = tmp_path / "cam.mcap"
    summary = export_run(out, jsonl=None, recording=recorded.rec, include_images=False)
    bag = read_bag(out)
    n_left = len(recorded.frame_times("left")[0])
    assert bag.counts() == {
        "/tf_static": 1,
        f"{RIG}/left/camera_info": n_left,
        f"{RIG}/right/camera_info": len(recorded.frame_times("right")[0]),
    }
    # No JSONL, no offset in the manifest: estimated from the manifest's creation time.
    manifest = json.loads((recorded.rec / "recording.json").read_text())
    assert manifest["utc_offset_ns"] is None
    assert summary.clock == "created_utc"
    t, _ = recorded.frame_times("left")
    got = [stamp_ns(m.header) for m in bag.msgs(f"{RIG}/left/camera_info")]
    assert np.all(np.diff(got) == np.diff(t))
    assert summary.utc_offset_ns is not None and got[0] == t[0] + summary.utc_offset_ns


# -- atomicity and errors ---------------------------------------------------------------------


def assert_untouched(out: Path, before: bytes) -> None:
    assert out.read_bytes() == before
    assert temporaries(out.parent) == []


def one_line(exc: pytest.ExceptionInfo[BaseException], *names: str) -> None:
    text = str(exc.value)
    assert "\n" not in text
    for n in names:
        assert n in text, text


@pytest.fixture
def previous(tmp_path: Path) -> tuple[Path, bytes]:
    out = tmp_path / "out" / "run.mcap"
    out.parent.mkdir()
    before = b"previous export, must survive"
    out.write_bytes(before)
    return out, before


def test_missing_jsonl_leaves_output_untouched(
    recorded: Recorded, previous: tuple[Path, bytes]
) -> None:
    out, before = previous
    missing = out.parent / "nope.jsonl"
    with pytest.raises(MissingInputError) as exc:
        export_run(out, jsonl=missing, recording=recorded.rec)
    one_line(exc, str(missing), "--jsonl")
    assert_untouched(out, before)


def test_a_damaged_line_is_skipped_said_and_the_rest_exported(
    recorded: Recorded, tmp_path: Path
) -> None:
    """A line cut short, one that is no message at all, one that is not UTF-8 and one at
    the end cut mid-line: the file holds every other message (those beside the bytes that
    are not UTF-8 too), each damaged line is named on the one line of stderr with its own
    number, and the exit is 65, as for a truncated video."""
    bad = tmp_path / "bad.jsonl"
    lines = list(recorded.lines)
    lines[4] = lines[4][: len(lines[4]) // 2]
    lines[7] = '{"bad": 1}'
    lines[-1] = lines[-1][:40]
    data = [x.encode() for x in lines]
    data[9] = data[9][:30] + b"\xff\xfe" + data[9][30:]
    bad.write_bytes(b"\n".join(data) + b"\n")
    out = tmp_path / "out.mcap"
    res = stereod("export", str(recorded.rec), "--jsonl", str(bad), "--mcap", str(out), *GEOMETRY)
    assert res.returncode == 65, res.stderr
    (err,) = res.stderr.splitlines()
    assert err.startswith(f"stereod: {bad} line 5: not a stereod.objects/1 message"), err
    assert f"{bad} line 8: not a stereod.objects/1 message" in err
    assert f"{bad} line 10: not UTF-8 text" in err and "; and 1 more" in err
    assert err.count("; skipped") == 3  # the fourth is counted
    kept = [x for k, x in enumerate(recorded.lines) if k not in (4, 7, 9, len(lines) - 1)]
    assert [m.data for m in read_bag(out).msgs(f"{RIG}/objects")] == kept
    assert temporaries(out.parent) == []


def test_a_jsonl_with_no_message_at_all_leaves_output_untouched(
    recorded: Recorded, previous: tuple[Path, bytes], tmp_path: Path
) -> None:
    """Every line damaged: no run's JSONL, so nothing is exported and nothing replaced."""
    out, before = previous
    bad = tmp_path / "bad.jsonl"
    bad.write_text("".join(x[: len(x) // 2] + "\n" for x in recorded.lines))
    with pytest.raises(InputError) as exc:
        export_run(out, jsonl=bad, recording=recorded.rec)
    one_line(exc, f"{bad} line 1")
    assert "skipped" not in str(exc.value)
    assert_untouched(out, before)


@pytest.mark.parametrize("track_id", [2**31, 2**40, -1])
def test_track_id_beyond_int32_is_one_line_65(
    recorded: Recorded, tmp_path: Path, track_id: int
) -> None:
    """A track id a ROS marker (int32) cannot carry: exit 65 naming the file, line and id
    (it was struct.error deep in the CDR writer: an internal error, 70); its message is
    left out, every other one exported."""
    out = tmp_path / "out.mcap"
    bad = tmp_path / "big.jsonl"
    messages = [json.loads(x) for x in recorded.lines]
    n = next(i for i, m in enumerate(messages) if m["objects"])
    messages[n]["objects"][0]["track_id"] = track_id
    bad.write_text("".join(json.dumps(m) + "\n" for m in messages))
    res = stereod("export", "--jsonl", str(bad), "--mcap", str(out), *GEOMETRY)
    assert res.returncode == 65, res.stderr
    assert res.stderr.splitlines() == [
        f"stereod: {bad} line {n + 1}: track_id {track_id} is outside 0..2147483647, the ids "
        "a ROS marker (int32) can carry; regenerate the file with `stereod replay --jsonl`; "
        "skipped"
    ]
    assert len(read_bag(out).msgs(f"{RIG}/objects")) == len(messages) - 1


def test_failure_while_writing_removes_the_temporary(
    recorded: Recorded, previous: tuple[Path, bytes], tmp_path: Path
) -> None:
    out, before = previous
    rec = tmp_path / "broken"
    shutil.copytree(recorded.rec, rec)
    (rec / "right.mkv").write_bytes(b"not a video at all" * 100)
    with pytest.raises(InputError) as exc:
        export_run(out, jsonl=recorded.jsonl, recording=rec)
    one_line(exc, str(rec / "right.mkv"))
    assert_untouched(out, before)


def test_writer_aborts_on_exception(previous: tuple[Path, bytes]) -> None:
    out, before = previous
    with pytest.raises(RuntimeError, match="boom"), McapRunWriter(out, baseline_m=0.06) as w:
        w.write_objects(ObjectsMessage.model_validate_json(GOLDEN.read_text()))
        raise RuntimeError("boom")
    assert_untouched(out, before)


def test_output_folder_must_exist(recorded: Recorded, tmp_path: Path) -> None:
    out = tmp_path / "missing" / "recorded.mcap"
    with pytest.raises(OutputError) as exc:
        export_run(out, jsonl=recorded.jsonl, recording=None)
    one_line(exc, str(tmp_path / "missing"))
    assert not out.parent.exists()


def test_jsonl_of_another_run_is_refused(recorded: Recorded, tmp_path: Path) -> None:
    other = tmp_path / "other.jsonl"
    msg = json.loads(recorded.lines[0])
    msg["t_ns"] += 10**12
    other.write_text(json.dumps(msg) + "\n")
    with pytest.raises(InputError) as exc:
        export_run(tmp_path / "x.mcap", jsonl=other, recording=recorded.rec)
    one_line(exc, str(other), "another run")
    assert list(tmp_path.iterdir()) == [other]


@pytest.mark.parametrize("text", ["", "\n\n"])
def test_a_jsonl_without_a_message_is_refused_and_nothing_is_written(
    recorded: Recorded, tmp_path: Path, text: str
) -> None:
    """An empty file given as the run's messages is the wrong file (a run's has one message a
    pair, objects or none): refused, as `stereod plot` refuses it, not an MCAP of frames with no
    tracks and exit 0."""
    empty = tmp_path / "empty.jsonl"
    empty.write_text(text)
    with pytest.raises(InputError) as exc:
        export_run(tmp_path / "x.mcap", jsonl=empty, recording=recorded.rec)
    one_line(exc, str(empty), "no objects messages in the file")
    assert list(tmp_path.iterdir()) == [empty]


# -- the writer on its own: unknown sigmas, calibrated rigs ----------------------------------


def test_golden_message_with_unknown_velocity_sigma(tmp_path: Path) -> None:
    golden = ObjectsMessage.model_validate_json(GOLDEN.read_text())
    (o,) = golden.objects
    assert o.velocity_sigma_mps is None and not o.velocity_valid
    out = tmp_path / "g.mcap"
    with McapRunWriter(out, rig="minoru", calibration=canonical(0.06, 60, 640, 480)) as w:
        img = np.zeros((480, 640), np.uint8)
        w.write_frame(Frame(Eye.LEFT, img, golden.t_ns, 21), golden.stamp_utc_ns)
        w.write_frame(Frame(Eye.RIGHT, img, golden.t_ns, 21), golden.stamp_utc_ns, image=False)
        w.write_objects(golden)
        with pytest.raises(InputError, match="rig 'other'"):
            w.write_objects(golden.model_copy(update={"rig": "other"}))
    bag = read_bag(out)
    assert f"{RIG}/right/image/compressed" not in bag.topics
    assert len(bag.msgs(f"{RIG}/right/camera_info")) == 1
    (od,) = bag.msgs(f"{RIG}/tracks/odom")
    tc = np.asarray(od.twist.covariance)
    assert tc[0] == -1.0 and np.all(tc[1:] == 0)  # ROS: unknown covariance
    assert stamp_ns(od.header) == golden.stamp_utc_ns == 1795242018024792763
    np.testing.assert_allclose(
        quat(od.pose.pose.orientation).apply([1, 0, 0]), [0, 0, 1], atol=1e-12
    )
    assert not any(t.endswith("speed_heading") for t in bag.topics)
    (arr,) = bag.msgs(f"{RIG}/tracks/markers")
    assert sorted(k.ns for k in arr.markers) == ["labels", "tracks"]
    assert "tentative" in next(k.text for k in arr.markers if k.ns == "labels")


def rotated_calibration() -> Calibration:
    k1 = np.array([[300.0, 0, 158.0], [0, 301.0, 121.0], [0, 0, 1]])
    k2 = np.array([[303.0, 0, 162.0], [0, 303.5, 118.0], [0, 0, 1]])
    r, _ = cv2.Rodrigues(np.array([0.002, 0.0157, -0.003]))
    return from_arrays(
        (W, H),
        {
            "K1": k1,
            "D1": np.array([-0.1, 0.02, 0.001, -0.0005, 0.0]),
            "K2": k2,
            "D2": np.array([-0.12, 0.03, -0.001, 0.0004, 0.0]),
            "R": r,
            "T": np.array([-0.06, 0.0008, 0.0012]),
        },
    )


def test_calibrated_rig_frames_and_camera_info(tmp_path: Path) -> None:
    cal = rotated_calibration()
    out = tmp_path / "cal.mcap"
    with McapRunWriter(out, rig="lab rig", calibration=cal) as w:
        for eye in Eye:
            w.write_frame(Frame(eye, np.full((H, W, 3), 128, np.uint8), 5, 0), 10**18)
        with pytest.raises(InputError, match="640x480"):
            w.write_frame(Frame(Eye.LEFT, np.zeros((480, 640), np.uint8), 6, 1), 10**18)
    bag = read_bag(out)
    (tf,) = bag.msgs("/tf_static")
    by_child = {t.child_frame_id: t for t in tf.transforms}
    p2 = cal.array("P2")
    b = -p2[0, 3] / p2[0, 0]
    for side, rname, pname, x in (("left", "R1", "P1", -b / 2), ("right", "R2", "P2", b / 2)):
        t = by_child[f"stereod_lab_rig_{side}_optical"]
        rot = quat(t.transform.rotation).as_matrix()
        np.testing.assert_allclose(rot, cal.array(rname), atol=1e-9)
        np.testing.assert_allclose(xyz(t.transform.translation), [x, 0, 0], atol=1e-12)
        (info,) = bag.msgs(f"/stereod/lab_rig/{side}/camera_info")
        np.testing.assert_allclose(np.reshape(info.p, (3, 4)), cal.array(pname), atol=1e-12)
        np.testing.assert_allclose(np.reshape(info.r, (3, 3)), cal.array(rname), atol=1e-12)
        (img,) = bag.msgs(f"/stereod/lab_rig/{side}/image/compressed")
        decoded = cv2.imdecode(np.frombuffer(bytes(img.data), np.uint8), cv2.IMREAD_UNCHANGED)
        assert decoded is not None and decoded.shape == (H, W, 3)
    right = bag.msgs("/stereod/lab_rig/right/camera_info")[0]
    np.testing.assert_allclose(right.d, cal.array("D2").ravel(), atol=1e-15)
    assert right.p[3] == pytest.approx(-right.p[0] * b)


def test_export_checks_the_calibration_the_run_used(tmp_path: Path) -> None:
    cal = rotated_calibration()
    golden = json.loads(GOLDEN.read_text())
    canonical_jsonl = tmp_path / "canonical.jsonl"
    canonical_jsonl.write_text(json.dumps(golden) + "\n")
    with pytest.raises(InputError, match="canonical rig"):
        export_run(tmp_path / "a.mcap", jsonl=canonical_jsonl, recording=None, calibration=cal)

    calibrated = tmp_path / "calibrated.jsonl"
    calibrated.write_text(
        json.dumps({**golden, "geometry": "calibrated", "calibration_id": cal.id}) + "\n"
    )
    with pytest.raises(MissingInputError, match=cal.id):
        export_run(tmp_path / "b.mcap", jsonl=calibrated, recording=None)
    other = canonical(0.06, 60, W, H)
    with pytest.raises(InputError, match=other.id):
        export_run(tmp_path / "c.mcap", jsonl=calibrated, recording=None, calibration=other)
    summary = export_run(tmp_path / "d.mcap", jsonl=calibrated, recording=None, calibration=cal)
    assert summary.messages["/stereod/minoru/tracks/odom"] == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "calibrated.jsonl",
        "canonical.jsonl",
        "d.mcap",
    ]


def test_nothing_to_export(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="nothing to export"):
        export_run(tmp_path / "x.mcap", jsonl=None, recording=None)


def test_foxglove_layout_refers_to_exported_topics(run: Run) -> None:
    layout = json.loads((ROOT / "foxglove" / "stereod-layout.json").read_text())
    panels = layout["configById"]
    assert {k.split("!")[0] for k in panels} == {"Image", "3D", "Plot"}

    def leaves(node: Any) -> set[str]:
        return {node} if isinstance(node, str) else leaves(node["first"]) | leaves(node["second"])

    assert leaves(layout["layout"]) == set(panels)
    referenced = set()
    for cfg in panels.values():
        referenced |= set(cfg.get("topics", {}))
        referenced |= {v for k, v in cfg.get("imageMode", {}).items() if k.endswith("Topic")}
        referenced |= {p["value"].split(".")[0].split("{")[0] for p in cfg.get("paths", [])}
    scripts = {}  # the layout's user scripts: output topic -> its inputs
    for node in layout["userNodes"].values():
        output = re.search(r'export const output = "([^"]+)";', node["sourceCode"])
        inputs = re.search(r"export const inputs = \[([^\]]*)\];", node["sourceCode"])
        assert output and inputs
        scripts[output.group(1)] = set(re.findall(r'"([^"]+)"', inputs.group(1)))
    for topic, inputs in scripts.items():
        referenced = referenced - {topic} | inputs
    assert referenced <= set(run.bag.topics), referenced - set(run.bag.topics)
    # the plots follow whatever tracks there are: slots, not track ids
    plots = [p["value"] for k, c in panels.items() if k.startswith("Plot") for p in c["paths"]]
    assert plots and not any("track_" in p for p in plots)
    assert panels["3D!stereod-scene"]["followTf"] == "stereod_minoru"


# -- written during a run: replay --mcap against export, record --mcap ------------------------


def test_replay_mcap_equals_the_export_of_the_same_run(recorded: Recorded, tmp_path: Path) -> None:
    exported = tmp_path / "exported.mcap"
    export_run(exported, jsonl=recorded.jsonl, recording=recorded.rec, baseline_m=BASELINE_M)
    a, b = read_bag(recorded.replay_mcap), read_bag(exported)
    assert a.counts() == b.counts()
    n_left = len(recorded.frame_times("left")[0])
    assert a.counts()[f"{RIG}/left/image/compressed"] == n_left  # every frame made a pair
    for topic in a.topics:
        assert [t for t, _ in a.topics[topic]] == [t for t, _ in b.topics[topic]], topic
    for x, y in zip(a.msgs(f"{RIG}/tracks/odom"), b.msgs(f"{RIG}/tracks/odom"), strict=True):
        assert x.child_frame_id == y.child_frame_id
        assert xyz(x.pose.pose.position) == xyz(y.pose.pose.position)
        assert xyz(x.twist.twist.linear) == xyz(y.twist.twist.linear)
        assert list(x.pose.covariance) == list(y.pose.covariance)
    for topic in a.topics:
        if topic.endswith("speed_heading"):
            assert [xyz(m.vector) for m in a.msgs(topic)] == [xyz(m.vector) for m in b.msgs(topic)]
    assert [m.data for m in a.msgs(f"{RIG}/objects")] == recorded.lines


def test_record_mcap_has_every_frame_of_the_recording(recorded: Recorded, tmp_path: Path) -> None:
    cfg = tmp_path / "c.toml"
    cfg.write_text(
        f"[rig]\nbaseline_m = {BASELINE_M}\nhfov_deg = {HFOV_DEG}\n"
        f'[driver]\nname = "replay"\n[driver.options]\npath = "{recorded.rec}"\n'
    )
    out, mcap = tmp_path / "again", tmp_path / "rec.mcap"
    printed = run_ok("record", str(out), "--config", str(cfg), "--mcap", str(mcap))
    assert f"wrote {mcap}:" in printed
    bag = read_bag(mcap)
    n = {}
    for eye in ("left", "right"):
        t, _ = frame_times(out, eye)
        n[eye] = len(t)
        infos = bag.msgs(f"{RIG}/{eye}/camera_info")
        assert len(bag.msgs(f"{RIG}/{eye}/image/compressed")) == len(infos) == len(t)
        stamps = np.array([stamp_ns(m.header) for m in infos])
        assert np.array_equal(np.diff(stamps), np.diff(t)), "stamps are not the capture clock"
        assert infos[0].k[0] == pytest.approx(W / (2 * math.tan(math.radians(HFOV_DEG) / 2)))
    assert n["left"] == len(recorded.frame_times("left")[0])
    assert set(bag.topics) == {
        "/tf_static",
        *(f"{RIG}/{e}/{k}" for e in ("left", "right") for k in ("image/compressed", "camera_info")),
    }


def test_replay_mcap_into_a_missing_folder_fails_the_run(
    recorded: Recorded, tmp_path: Path
) -> None:
    """The output is refused before the run: exit 73 and one line, and the JSONL of the failed
    run does not replace the previous one."""
    jsonl = tmp_path / "run.jsonl"
    before = b"previous run, must survive\n"
    jsonl.write_bytes(before)
    bad = tmp_path / "missing" / "run.mcap"
    res = stereod("replay", str(recorded.rec), "--rate", "0", "--jsonl", str(jsonl),
                  "--mcap", str(bad), *GEOMETRY)  # fmt: skip
    assert res.returncode == 73, res.stderr
    (line,) = res.stderr.strip().splitlines()[-1:]
    assert str(tmp_path / "missing") in line and line.startswith("stereod: ")
    assert_untouched(jsonl, before)
    assert not bad.parent.exists()


def test_output_that_is_an_input_is_refused(recorded: Recorded) -> None:
    video = recorded.rec / "left.mkv"
    before = video.read_bytes()
    for cmd in (
        ["export", str(recorded.rec), "--jsonl", str(recorded.jsonl), "--mcap", str(video)],
        ["replay", str(recorded.rec), "--rate", "0", "--mcap", str(video)],
    ):
        res = stereod(*cmd)
        assert res.returncode == 64, res.stderr  # a usage error, as every output that is an input
        assert "--mcap" in res.stderr and "input" in res.stderr
    assert video.read_bytes() == before


# -- where the file goes: through a symbolic link, into a FIFO; an export a signal stops ------


def test_export_through_a_symlink_replaces_its_target_and_keeps_the_link(
    recorded: Recorded, previous: tuple[Path, bytes], tmp_path: Path
) -> None:
    target, _ = previous
    link = tmp_path / "latest.mcap"
    link.symlink_to(target)
    run_ok("export", "--jsonl", str(recorded.jsonl), "--mcap", str(link), "--no-images")
    assert link.is_symlink() and link.resolve() == target, "the symbolic link was replaced"
    assert len(read_bag(target).msgs(f"{RIG}/objects")) == len(recorded.lines)
    assert temporaries(link.parent) == temporaries(target.parent) == []


def test_export_into_a_fifo_streams_the_file_to_its_reader(
    recorded: Recorded, tmp_path: Path
) -> None:
    fifo = FifoReader(tmp_path / "run.mcap")
    res = stereod("export", "--jsonl", str(recorded.jsonl), "--mcap", str(fifo.path))
    assert fifo.is_fifo(), "the FIFO was replaced by a regular file"
    assert res.returncode == 0, res.stderr
    assert mcap_messages(fifo.data(), f"{RIG}/objects") == len(recorded.lines)


def fifo_writer(fifo: Path, proc: subprocess.Popen, timeout_s: float = 60.0) -> IO[bytes]:
    """The FIFO opened for writing once ``proc`` opens it for reading; a failure, not a hang,
    when the process ends or never gets there."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        except OSError as exc:
            if exc.errno != errno.ENXIO:
                raise
            assert proc.poll() is None, f"export ended (rc {proc.returncode}) before reading"
            assert time.monotonic() < deadline, "export never opened its input"
            time.sleep(0.02)
            continue
        os.set_blocking(fd, True)
        return os.fdopen(fd, "wb", buffering=0)


def test_export_stopped_by_sigterm_leaves_the_file_and_no_temporary(
    recorded: Recorded, previous: tuple[Path, bytes], tmp_path: Path
) -> None:
    """The JSONL comes through a FIFO, read twice (a scan, then the messages): the test holds
    the second pass open after a quarter of it, so the export is mid-way, its temporary file
    made, when SIGTERM comes."""
    out, before = previous
    jsonl = tmp_path / "run.jsonl"
    os.mkfifo(jsonl)
    proc = start_stereod("export", "--jsonl", str(jsonl), "--mcap", str(out))
    text = "".join(line + "\n" for line in recorded.lines).encode()
    with fifo_writer(jsonl, proc) as fh:  # the scan: all of it
        fh.write(text)
    wait_for(proc, lambda: bool(temporaries(out.parent)))  # the scan is over, the writer made
    with fifo_writer(jsonl, proc) as fh:  # the messages: the export opens it again
        fh.write(text[: len(text) // 4])
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert err == f"stereod: export interrupted by SIGTERM; {out} left as it was\n"
    assert_untouched(out, before)


def test_a_sigma_whose_square_overflows_is_an_infinite_variance() -> None:
    """A run edited to a position sigma of 1e300 made ``export`` end in an internal error
    (``** 2`` raised OverflowError); its Odometry's variance is infinite instead, the other
    entries as they were."""
    msg = ObjectsMessage.model_validate_json(
        (Path(__file__).parent / "golden" / "objects_example.json").read_text()
    )
    obj = msg.objects[0]
    huge = obj.model_copy(update={"position_sigma_m": (1e300, 0.01, 0.02)})
    ros = RosMessages("minoru", calibration=canonical(0.06, 60.0, 640, 480))
    odom = [
        m for m in ros.objects(msg.model_copy(update={"objects": [huge]})) if m.typename == T_ODOM
    ]
    cov = odom[0].body["pose"]["covariance"]
    assert math.isinf(cov[0]) and cov[7] == pytest.approx(1e-4) and cov[14] == pytest.approx(4e-4)


def test_a_line_with_a_position_not_finite_or_absurd_is_skipped_and_said(
    recorded: Recorded, tmp_path: Path
) -> None:
    """A NaN, an infinity (JSON as Python writes it) or a 1e308 position was written into the
    MCAP as it came, where ``plot`` refuses the same file; the line is now skipped and named
    like any damaged one, the rest exported, exit 65."""
    lines = list(recorded.lines)
    with_objects = [k for k, x in enumerate(lines) if json.loads(x)["objects"]][:3]
    for k, value in zip(with_objects, ("NaN", "Infinity", "1e308"), strict=True):
        msg = json.loads(lines[k])
        msg["objects"][0]["position_m"][0] = "@"
        lines[k] = json.dumps(msg).replace('"@"', value)
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.mcap"
    res = stereod("export", str(recorded.rec), "--jsonl", str(bad), "--mcap", str(out), *GEOMETRY)
    assert res.returncode == 65, res.stderr
    (err,) = res.stderr.splitlines()
    first = with_objects[0] + 1
    assert err.startswith(f"stereod: {bad} line {first}: track "), err
    assert "position or velocity is not finite, or beyond 1e+06 m or m/s" in err
    assert err.count("; skipped") == 3
    kept = [x for k, x in enumerate(recorded.lines) if k not in with_objects]
    assert [m.data for m in read_bag(out).msgs(f"{RIG}/objects")] == kept
