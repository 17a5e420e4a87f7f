"""Human-readable rendering of what stereod publishes (``stereod subscribe``, the demo)."""

from __future__ import annotations

import json
from collections.abc import Sequence

from stereod.bus.messages import ObjectsMessage, ObjectState, StatusMessage
from stereod.client import parse_payload
from stereod.fusion.status import FUSE_STATUS_SCHEMA, FuseStatus


def _v(vec: Sequence[float] | None, fmt: str = "{:+.3f}") -> str:
    if vec is None:
        return "-"
    return "(" + ", ".join(fmt.format(x) for x in vec) + ")"


def format_object(o: ObjectState) -> str:
    """One object as one line: id, state, position (m), velocity (m/s), speed, heading."""
    heading = f"{o.heading_deg:6.1f} deg" if o.heading_valid else "(not yet valid)"
    motion = (
        f"v {_v(o.velocity_mps)} m/s  |v| {o.speed_mps:.3f} m/s  heading {heading}"
        if o.velocity_valid
        else "v (not yet valid)"
    )
    return f"  #{o.track_id:<4} {o.state.value:<10} pos {_v(o.position_m)} m  {motion}"


def json_line(key: str, payload: bytes, deleted: bool = False, encoding: str = "") -> str:
    """One sample as one line of JSON (``subscribe --json``): a JSON payload as it came (made
    compact if it spans lines), a DELETE as ``{"key", "delete": true}``, and anything else
    (an image's JPEG) as ``{"key", "bytes", "encoding"}``, never its bytes in a text line."""
    if deleted:
        return json.dumps({"key": key, "delete": True})
    try:
        text = payload.decode("utf-8")
        value = json.loads(text)
    except (ValueError, RecursionError):  # not UTF-8, not JSON, or nested past the parser
        return json.dumps({"key": key, "bytes": len(payload), "encoding": encoding})
    return json.dumps(value) if "\n" in text or "\r" in text else text


def format_sample(key: str, payload: bytes, deleted: bool = False) -> str:
    """A readable block for one sample on any stereod key."""
    if deleted:
        return f"{key}: DELETE (track ended)"
    msg = parse_payload(payload)
    if isinstance(msg, ObjectsMessage):
        head = (
            f"{key}: seq {msg.seq}  t {msg.t_ns / 1e9:.3f} s  skew {msg.skew_ns / 1e6:+.1f} ms"
            f"  {len(msg.objects)} object(s)  {msg.latency.pipeline_ms:.1f} ms"
        )
        return "\n".join([head] + [format_object(o) for o in msg.objects])
    if isinstance(msg, ObjectState):
        return f"{key}:\n" + format_object(msg)
    if isinstance(msg, StatusMessage):
        drops = ", ".join(f"{k} {v}" for k, v in msg.drops.items()) or "none"
        line = (
            f"{key}: {msg.state.value}  left {msg.left.state.value} {msg.left.fps:.1f} fps  "
            f"right {msg.right.state.value} {msg.right.fps:.1f} fps  pairs {msg.pairs}  "
            f"drops {drops}"
        )
        if msg.problems:
            line += f"\n  last problem: {msg.problems[-1]}"
        return line
    if msg is None:
        return f"{key}: {len(payload)} bytes (not JSON)"
    if isinstance(msg, dict) and msg.get("schema") == FUSE_STATUS_SCHEMA:
        try:
            return format_fuse_status(key, FuseStatus.model_validate(msg))
        except ValueError:  # a newer node's, or a broken one: as it came
            pass
    return f"{key}: {json.dumps(msg)}"


def format_fuse_status(key: str, st: FuseStatus) -> str:
    """A fusion node's status as a block: the room's line, one line per rig (live or not,
    messages, tracks, restarts, clock offset), and its last problem."""
    live = sum(r.live for r in st.rigs.values())
    added = "-" if st.added_ms_p50 is None else f"{st.added_ms_p50:.1f}/{st.added_ms_p99:.1f} ms"
    lines = [
        f"{key}: {st.state}  room {st.room}  rigs {live} of {len(st.rigs)} live  tracks "
        f"{st.tracks}  steps {st.steps_per_s:.1f}/s  added p50/p99 {added}"
    ]
    for name, r in st.rigs.items():
        clock = "-" if r.clock_offset_ms is None else f"{r.clock_offset_ms:+.1f} ms"
        lines.append(
            f"  rig {name:<12} {'live' if r.live else 'NOT LIVE':<8} messages {r.messages}  "
            f"tracks {r.tracks}  restarts {r.restarts}  clock offset {clock}"
        )
    if st.problems:
        lines.append(f"  last problem: {st.problems[-1]}")
    return "\n".join(lines)
