"""The Foxglove layout's user script (``foxglove/stereod-layout.json``), run as Foxglove runs it.

The script is TypeScript; Node (20, no type stripping of its own) runs it once its type
declarations and annotations are removed. Its input is what a Foxglove client decodes: stereod's
Odometry, CDR-encoded as the file and the live servers send it and decoded with rosbags' own
Jazzy definitions. The expected slots, speeds and headings follow from the track states fed in
(eq. 22, 23), not from the script.
"""

from __future__ import annotations

import json
import math
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from stereod.bus.messages import ObjectsMessage
from stereod.ros.mapping import RosMessages
from stereod.ros.names import cdr_encoder
from stereod.tracking.types import TrackLifecycle
from stereod.vision.calibration import canonical

from .conftest import ROOT

NODE = shutil.which("node")
pytestmark = pytest.mark.skipif(NODE is None, reason="Node.js runs the layout's script")

T0 = 1_795_242_018_000_000_000
HARNESS = """
import script from "./script.mjs";
const messages = JSON.parse(await (await import("node:fs/promises")).readFile(process.argv[2]));
const out = messages.map((message) => script({ message }) ?? null);
console.log(JSON.stringify(out));
"""


def layout_script() -> str:
    """The script's TypeScript source, the layout's only user script."""
    layout = json.loads((ROOT / "foxglove" / "stereod-layout.json").read_text())
    (node,) = layout["userNodes"].values()
    return str(node["sourceCode"])


def strip_types(ts: str) -> str:
    """The script as JavaScript: its ``type`` declarations, generic arguments and annotations
    removed (the script's own, few constructs; a new one makes Node fail the test)."""
    js = re.sub(r"^type \w+ = \{.*?\};\n", "", ts, flags=re.S | re.M)
    js = re.sub(r"new Map<[^()]*>\(", "new Map(", js)
    js = re.sub(r"\(event: \{ message: any \}\): [\w |]+ \{", "(event) {", js)
    assert not re.search(r"\btype \w+ =|: (number|string|any)\b", js), js
    return js


def run_script(tmp_path: Path, messages: list[dict[str, Any]]) -> list[dict[str, Any] | None]:
    """Each message through the script in order, in one module instance (its state kept)."""
    (tmp_path / "script.mjs").write_text(strip_types(layout_script()))
    (tmp_path / "run.mjs").write_text(HARNESS)
    (tmp_path / "in.json").write_text(json.dumps(messages))
    assert NODE is not None
    res = subprocess.run(
        [NODE, "run.mjs", "in.json"], cwd=tmp_path, capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr
    out: list[dict[str, Any] | None] = json.loads(res.stdout)
    return out


def plain(value: Any) -> Any:
    """A rosbags message as the JSON object a Foxglove script receives."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    if hasattr(value, "__dataclass_fields__"):
        return {k: plain(getattr(value, k)) for k in value.__dataclass_fields__}
    return value


def odometry(states: list[tuple[float, int, tuple[float, float, float] | None]]) -> list[dict]:
    """Odometry, decoded as a client does, of track states (time s, track id, velocity m/s or
    None while not valid), each alone in its message."""
    golden = ObjectsMessage.model_validate_json(
        (ROOT / "tests/golden/objects_example.json").read_text()
    )
    (template,) = golden.objects
    ros = RosMessages("minoru", calibration=canonical(0.06, 60.0, 640, 480))
    jazzy = get_typestore(Stores.ROS2_JAZZY)
    encode = cdr_encoder("nav_msgs/msg/Odometry")
    out = []
    for n, (t, track, v) in enumerate(states):
        stamp = T0 + round(t * 1e9)
        obj = template.model_copy(
            update={
                "track_id": track,
                "stamp_utc_ns": stamp,
                "state": TrackLifecycle.CONFIRMED,
                "velocity_mps": v or (0.0, 0.0, 0.0),
                "velocity_valid": v is not None,
                "velocity_sigma_mps": (0.1, 0.1, 0.1) if v is not None else None,
            }
        )
        msg = golden.model_copy(update={"seq": n, "stamp_utc_ns": stamp, "objects": [obj]})
        (body,) = [m.body for m in ros.objects(msg) if m.topic.endswith("/tracks/odom")]
        out.append(plain(jazzy.deserialize_cdr(encode(body), "nav_msgs/msg/Odometry")))
    return out


def test_slots_follow_whatever_tracks_there_are(tmp_path: Path) -> None:
    """A track takes the lowest free slot at its first state and keeps it; a slot frees 1 s
    after its track's last state; a fifth track at once gets none; no output until the
    velocity is valid, but the slot is taken."""
    v1, v2 = (0.3, -0.1, 0.4), (-0.5, 0.2, 0.5)
    states: list[tuple[float, int, tuple[float, float, float] | None]] = [
        (0.0, 7, None),  # track 7: slot 1, velocity not valid yet: nothing
        (0.1, 7, v1),
        (0.1, 12, v2),  # track 12: slot 2
        (0.5, 12, v2),  # track 7 last seen at 0.1
        (1.0, 30, v1),  # 0.9 s after 7's last: slot 1 still taken, slot 3
        (1.2, 31, v2),  # 7 forgotten (1.1 s): slot 1
        (1.3, 32, v1),  # slots 2, 3, 1 taken: slot 4
        (1.3, 33, v1),  # a fifth at once: no slot, no output
    ]
    got = run_script(tmp_path, odometry(states))
    slots = [None if o is None else (o["track_id"], o["slot"]) for o in got]
    assert slots == [None, (7, 1), (12, 2), (12, 2), (30, 3), (31, 1), (32, 4), None]
    for (t, _, v), o in zip(states, got, strict=True):
        if o is None or v is None:
            continue
        vx, vy, vz = v
        assert o["speed_mps"] == pytest.approx(math.hypot(vx, vy, vz), rel=1e-12)
        assert o["heading_deg"] == pytest.approx(math.degrees(math.atan2(vx, vz)) % 360)
        assert o["climb_mps"] == pytest.approx(-vy)
        sec, nsec = divmod(T0 + round(t * 1e9), 10**9)
        assert o["header"]["stamp"] == {"sec": sec, "nsec": nsec}
