"""Readable rendering of wire messages."""

from __future__ import annotations

import json
from pathlib import Path

from stereod.bus.subscribe import format_sample, json_line

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
