"""``stereod fuse --mcap``: the room's tracks as ROS 2 messages, every rig's frame in TF.

Two rig message generators and the fusion node run as processes through a router on loopback;
the MCAP file is read back with rosbags (its own Humble types) and with the mcap library. The
odometry is checked against the walkers' true positions, ``/tf_static`` against the room file's
poses turned into matrices here (Rz Ry Rx written out in the test, not stereod's).
"""

from __future__ import annotations

import json
import signal
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from scipy.spatial.transform import Rotation

from stereod_fakes.room_messages import Walker, walkers_from_json

from .fuse_procs import ROOM, fuse_procs, stop
from .test_room_calibration import rot

pytestmark = pytest.mark.slow

TYPESTORE = get_typestore(Stores.ROS2_HUMBLE)
# The room file's poses (ROOM of test_fuse_cli), as numbers: name -> (t m, (rx, ry, rz) deg).
POSES = {
    "a": ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
    "b": ((4.0, 0.0, 10.0), (0.0, 180.0, 0.0)),
    "c": ((4.0, 0.0, 4.0), (0.0, -90.0, 0.0)),
}


def matrix(tf: object) -> np.ndarray:
    """The 4x4 of a geometry_msgs Transform (parent <- child)."""
    t, q = tf.translation, tf.rotation  # type: ignore[attr-defined]
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    m[:3, 3] = (t.x, t.y, t.z)
    return m


def test_room_tracks_and_rig_frames_in_the_mcap(tmp_path: Path) -> None:
    """Object 1 stands in rigs a and c's overlap: its room odometry is within 4 sigma + 2 cm
    of the truth in the room frame; /tf_static chains the room frame to each rig's optical
    frame as R p + t of the room file (1e-9); both readers see the same messages, and the
    String topic carries the JSONL lines."""
    room = tmp_path / "room.toml"
    room.write_text(ROOM)
    walkers = json.dumps([{"id": 1, "start_m": [0.6, 0.0, 3.0], "velocity_mps": [0.0, 0.0, 0.05]}])
    out, jsonl = tmp_path / "room.mcap", tmp_path / "room.jsonl"
    with fuse_procs() as run:
        fuse = run.start_fuse(room, "--mcap", str(out), "--jsonl", str(jsonl))
        gens = [run.generator(room, rig, walkers, seed) for seed, rig in enumerate("ac")]
        t0 = run.go(gens)
        deadline = time.monotonic() + 120  # a guard against a hang, not a measurement
        while time.monotonic() < deadline and time.time_ns() < t0 + 2_000_000_000:
            time.sleep(0.1)
        for g in gens:
            stop(g)
        fuse.send_signal(signal.SIGTERM)
        _, err = fuse.communicate(timeout=60)
    assert fuse.returncode == 0, err
    truth = [Walker(w.truth_id, w.start_m, w.velocity_mps, t0) for w in walkers_from_json(walkers)]

    topics: dict[str, list] = defaultdict(list)
    with AnyReader([out]) as reader:
        for c, _, raw in reader.messages():
            topics[c.topic].append(TYPESTORE.deserialize_cdr(raw, c.msgtype))

    (static,) = topics["/tf_static"]
    tfs = {(t.header.frame_id, t.child_frame_id): matrix(t.transform) for t in static.transforms}
    for name, (t, angles) in POSES.items():
        chain = (
            tfs[("stereod_lab_optical", f"stereod_{name}")]
            @ tfs[(f"stereod_{name}", f"stereod_{name}_optical")]
        )
        assert np.abs(chain[:3, :3] - rot(*angles)).max() < 1e-9, name
        assert np.abs(chain[:3, 3] - np.array(t)).max() < 1e-9, name
    assert ("stereod_lab", "stereod_lab_optical") in tfs

    odom = topics["/stereod/lab/tracks/odom"]
    assert len(odom) > 10
    ids = set()
    for o in odom:
        assert o.header.frame_id == "stereod_lab_optical"
        stamp = o.header.stamp.sec * 1_000_000_000 + o.header.stamp.nanosec
        if stamp < t0:
            continue
        p = o.pose.pose.position
        sigma = np.sqrt(np.diag(np.reshape(o.pose.covariance, (6, 6)))[:3])
        err = np.abs(np.array([p.x, p.y, p.z]) - truth[0].position(stamp))
        assert np.all(err < 4 * sigma + 0.02), (err, sigma)
        ids.add(o.child_frame_id)
    assert len(ids) == 1, ids
    lines = jsonl.read_text().splitlines()
    assert [m.data for m in topics["/stereod/lab/objects"]] == lines

    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts: dict[str, int] = defaultdict(int)
    with out.open("rb") as fh:
        for _, channel, _, _ in make_reader(
            fh, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            counts[channel.topic] += 1
    assert dict(counts) == {k: len(v) for k, v in topics.items()}
