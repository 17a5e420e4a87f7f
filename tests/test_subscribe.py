"""Readable rendering of wire messages."""

from __future__ import annotations

import json
from pathlib import Path

from stereod.bus.subscribe import format_sample, json_line
from stereod.fusion.room import RigPose

EXAMPLE = Path(__file__).parent / "golden" / "objects_example.json"


def test_objects_message_is_one_header_and_one_line_per_object() -> None:
    msg = json.loads(EXAMPLE.read_text())
    text = format_sample("stereod/minoru/objects", json.dumps(msg).encode())
    lines = text.splitlines()
    assert lines[0].startswith(
        f"stereod/minoru/objects: seq {msg['seq']}  t {msg['t_ns'] / 1e9:.3f} s"
    )
    assert len(lines) == 1 + len(msg["objects"])
    x, y, z = msg["objects"][0]["position_m"]
    assert f"pos ({x:+.3f}, {y:+.3f}, {z:+.3f}) m" in lines[1]


def test_valid_velocity_shows_speed_and_heading() -> None:
    obj = json.loads(EXAMPLE.read_text())["objects"][0]
    obj.update(
        velocity_valid=True, velocity_mps=[0.5, 0.0, 0.5], speed_mps=0.7071, heading_deg=45.0
    )
    text = format_sample("stereod/minoru/objects/1", json.dumps(obj).encode())
    assert "|v| 0.707 m/s" in text and "heading (not yet valid)" in text  # speed known first
    obj.update(heading_valid=True)
    text = format_sample("stereod/minoru/objects/1", json.dumps(obj).encode())
    assert "|v| 0.707 m/s" in text and "heading   45.0 deg" in text


def test_delete_and_non_json() -> None:
    assert format_sample("k/1", b"", deleted=True) == "k/1: DELETE (track ended)"
    assert format_sample("k", b"\xff\x00") == "k: 2 bytes (not JSON)"


def test_json_lines_are_json_whatever_the_payload() -> None:
    """``subscribe --json`` on ``stereod/**`` meets the images' JPEG: each sample is still
    one line that parses, the JPEG said by its size and encoding, never its bytes."""
    jpeg = b"\xff\xd8\xff\xe0\x00\x10JFIF\x00" + bytes(range(256))
    line = json_line("stereod/r/image/left", jpeg, encoding="image/jpeg")
    assert json.loads(line) == {
        "key": "stereod/r/image/left", "bytes": len(jpeg), "encoding": "image/jpeg",
    }  # fmt: skip
    assert json_line("k", b'{"seq": 1}') == '{"seq": 1}'  # JSON as it came
    spread = json_line("k", b'{\n  "seq": 2\n}')
    assert "\n" not in spread and json.loads(spread) == {"seq": 2}
    assert json.loads(json_line("k/1", b"", deleted=True)) == {"key": "k/1", "delete": True}
    assert json.loads(json_line("k", "caf\u00e9 au lait".encode()))["bytes"] == 13  # not JSON


def test_a_fusion_node_s_status_lists_each_rig() -> None:
    """A room's status printed as one 2 kB line of raw JSON (its latency histograms
    included), where the deployment guide promised each rig listed as live with its message
    count, restarts and clock offset; now a line per rig, and the last problem."""
    import time

    from stereod.bus.messages import dump_objects
    from stereod.fusion.wire import decode
    from stereod_fakes.room_messages import RigSim, Walker
    from tests.test_fuse_node import _node

    node = _node(20.0)
    t0 = time.time_ns()
    payload, _ = dump_objects(
        RigSim(RigPose(name="a"), seed=1).message([Walker(1, (0.3, 0, 3), (0.2, 0, 0), t0)], t0)
    )
    node.fuser.ingest_wire(decode(payload))
    node._count([(time.monotonic(), "stereod/a/objects", payload)])
    body = node.status().model_dump_json(by_alias=True).encode()
    text = format_sample("stereod/rooms/lab/status", body)
    head, a, b, problem = text.splitlines()
    assert head.startswith("stereod/rooms/lab/status: running  room lab  rigs 1 of 2 live")
    assert a.split() == ["rig", "a", "live", "messages", "1", "tracks", "1", "restarts", "0",
                         "clock", "offset", "+0.0", "ms"]  # fmt: skip
    assert b.split()[:3] == ["rig", "b", "NOT"]
    assert problem == "  last problem: rig b: no message yet"
    assert format_sample("k", body.replace(b'"room":"lab"', b'"room":7')).startswith("k: {")
