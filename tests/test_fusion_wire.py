"""The fusion's own reader of rig messages (``wire.decode``) against the wire model: it takes
and refuses the payloads ``ObjectsMessage.model_validate_json`` takes and refuses, and gives
the same arrays as the model's message does (``wire.from_message``)."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stereod.bus.messages import ObjectsMessage, dump_objects
from stereod.files.bounds import UTC_NS_MAX
from stereod.fusion.room import RigPose
from stereod.fusion.wire import RigWire, _fast, decode, from_message
from stereod_fakes.room_messages import RigSim, Walker

T0 = 1_700_000_000_000_000_000


def payloads() -> list[bytes]:
    """A rig's messages about walkers in and out of its view, as a daemon writes them."""
    sim = RigSim(RigPose(name="a", rotation_deg=(0.0, 10.0, 0.0)), seed=3)
    walkers = [
        Walker(k, (-3.0 + k, 0.1 * k, 2.0 + 0.5 * k), (0.4, 0.0, -0.1 * k), T0) for k in range(8)
    ]
    return [dump_objects(sim.message(walkers, T0 + k * 33_333_333))[0] for k in range(0, 90, 9)]


PAYLOADS = payloads()


def same(a: RigWire, b: RigWire) -> None:
    for name in RigWire.__dataclass_fields__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape, name
            assert np.array_equal(x, y, equal_nan=True), name
        else:
            assert x == y, name


def verdict(payload: bytes) -> RigWire | None:
    """The model's reading of ``payload`` (None: refused)."""
    try:
        return from_message(ObjectsMessage.model_validate_json(payload))
    except ValueError:
        return None


def test_generated_messages_read_fast_and_as_the_model_reads_them() -> None:
    assert any(b'"objects":[{' in p for p in PAYLOADS)
    for p in PAYLOADS:
        fast = _fast(p)
        assert fast is not None  # the plain case never goes through the model
        model = verdict(p)
        assert model is not None
        same(fast, model)
        same(decode(p), model)


VALUES = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=False, allow_infinity=False),
    st.text(max_size=4),
    st.sampled_from(["confirmed", "coasting", "tentative", "stereod.objects/1", "canonical"]),
    st.lists(st.one_of(st.integers(-5, 5), st.floats(-5, 5), st.booleans()), max_size=5),
    st.dictionaries(st.sampled_from(["centroid_px", "bbox_px", "area_px"]), st.integers(0, 9)),
)
"""What a field may be replaced by: JSON of every kind, and of the right kind but wrong size."""

TOP = ["schema", "schema_", "rig", "seq", "t_ns", "stamp_utc_ns", "skew_ns", "left_seq",
       "right_seq", "geometry", "calibration_id", "latency", "objects", "extra"]  # fmt: skip
OBJECT = ["schema", "schema_", "track_id", "state", "t_ns", "stamp_utc_ns", "skew_ns",
          "position_m", "position_sigma_m", "velocity_mps", "velocity_sigma_mps",
          "velocity_valid", "heading_valid", "speed_mps", "speed_sigma_mps", "heading_deg",
          "heading_sigma_deg", "raw_velocity_mps", "left", "right", "disparity_px", "size_m",
          "age_s", "extent_min_m", "extent_max_m", "extra"]  # fmt: skip
BLOB = ["centroid_px", "bbox_px", "area_px"]


@st.composite
def malformed(draw: st.DrawFn) -> bytes:
    """A generated message with one to three fields (of the message, an object, a blob, or
    one element of a vector) replaced by another value or deleted, or the text cut, or a
    number written beyond what a float holds."""
    msg: dict[str, Any] = json.loads(draw(st.sampled_from(PAYLOADS[1:])))
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from(["top", "object", "blob", "element"]))
        target: Any = msg
        keys = TOP
        if where != "top" and msg.get("objects") and isinstance(msg["objects"], list):
            obj = draw(st.sampled_from(msg["objects"]))
            if not isinstance(obj, dict):
                continue
            target, keys = obj, OBJECT
            blobs = [k for k in ("left", "right") if isinstance(obj.get(k), dict)]
            if where == "blob" and blobs:
                target, keys = obj[draw(st.sampled_from(blobs))], BLOB
            elif where == "element":
                vec = obj.get(draw(st.sampled_from(["position_m", "velocity_sigma_mps"])))
                if isinstance(vec, list) and vec:
                    vec[draw(st.integers(0, len(vec) - 1))] = draw(VALUES)
                    continue
        if not isinstance(target, dict):
            continue
        key = draw(st.sampled_from(keys))
        if draw(st.booleans()) and key in target:
            del target[key]
        else:
            target[key] = draw(VALUES)
    text = json.dumps(msg)
    form = draw(st.sampled_from(["plain", "cut", "huge"]))
    if form == "cut":
        text = text[: draw(st.integers(0, len(text) - 1))]
    elif form == "huge":
        text = text.replace('"size_m": ', '"size_m": 1e400, "x": ', 1)
    return text.encode()


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(malformed())
def test_malformed_messages_taken_and_refused_as_the_model_does(payload: bytes) -> None:
    model = verdict(payload)
    try:
        fast = _fast(payload)
    except Exception:
        fast = None
    if fast is not None:  # what the fast path takes, the model takes, and reads the same
        assert model is not None, payload
        same(fast, model)
    stamps = [] if model is None else [model.stamp_utc_ns, *model.stamps_ns.tolist()]
    if model is None or not all(0 <= t <= UTC_NS_MAX for t in stamps):
        with pytest.raises(ValueError):  # refused, or stamped where the room's clock overflows
            decode(payload)
    else:
        same(decode(payload), model)


@pytest.mark.parametrize(
    "payload",
    [b"", b"[]", b"null", b'{"rig": "a"}', b"\xff\xfe", b"[" * 100_000, PAYLOADS[0][:-1]],
)
def test_not_a_message_is_refused_with_the_models_error(payload: bytes) -> None:
    with pytest.raises(ValueError) as fast:
        decode(payload)
    with pytest.raises(ValueError) as model:
        ObjectsMessage.model_validate_json(payload)
    assert str(fast.value) == str(model.value)


@pytest.mark.parametrize("where", ["message", "object"])
@pytest.mark.parametrize("stamp", [-1, UTC_NS_MAX + 1, 2**63 - 1])
def test_a_stamp_outside_1970_to_2116_is_refused_naming_the_rig(where: str, stamp: int) -> None:
    """A message (or one of its objects) stamped before 1970 or past 2**62 ns is refused by
    both readers: at 64 bits' end, the room's step overflowed and the node died (exit 70).
    The last instant within is taken."""
    msg = json.loads(PAYLOADS[-1])
    target = msg if where == "message" else msg["objects"][0]
    target["stamp_utc_ns"] = stamp
    with pytest.raises(ValueError, match=r"rig 'a': a stamp outside 1970\.\.2116"):
        decode(json.dumps(msg).encode())
    target["stamp_utc_ns"] = UTC_NS_MAX
    assert decode(json.dumps(msg).encode()).rig == "a"


@pytest.mark.parametrize("field", ["track_id", "stamp_utc_ns"])
def test_an_integer_beyond_64_bits_is_refused_as_a_bad_message(field: str) -> None:
    """The model takes any JSON integer; the arrays fusion reads hold 64 bits. A rig message
    whose track id or stamp does not fit is refused like any other bad message (a
    ``ValueError`` naming the fields), not an ``OverflowError`` out of the subscriber."""
    msg = json.loads(PAYLOADS[-1])
    assert msg["objects"], "the generated message has objects"
    msg["objects"][0][field] = 2**63
    with pytest.raises(ValueError, match="beyond 64 bits"):
        decode(json.dumps(msg).encode())


@pytest.mark.parametrize(
    ("field", "value"),
    [("position_sigma_m", 1e200), ("position_sigma_m", 0.0), ("velocity_sigma_mps", 1e200),
     ("position_m", 1e200)],
)  # fmt: skip
def test_a_rigs_finite_but_absurd_numbers_leave_the_room_tracks_finite(
    field: str, value: float
) -> None:
    """Two rigs see one walker; from halfway, rig b's messages carry a sigma of 1e200 or 0 (no
    error at all), or a position of 1e200 m. Both readers take such a message (every number
    is finite), but squared in a covariance 1e200 is an infinity, and 0 makes the fusion's
    matrices singular: before, the room track turned NaN within a step. Now the sigma is taken
    as missing and the absurd position dropped, and the room track stays on the walker."""
    from stereod.fusion.fuser import Fuser
    from stereod.fusion.room import Room

    t0 = 1_700_000_000_000_000_000
    room = Room(name="lab", rigs=[RigPose(name="a"), RigPose(name="b")])
    fuser = Fuser(room)
    sims = {r.name: RigSim(r, seed=k) for k, r in enumerate(room.rigs)}
    walker = Walker(1, (0.0, 0.0, 2.5), (0.6, 0.0, 0.3), t0)
    for k in range(60):
        t = t0 + k * 33_333_333
        for rig in ("a", "b"):
            payload = dump_objects(sims[rig].message([walker], t))[0]
            if rig == "b" and k >= 30:
                m = json.loads(payload)
                for o in m["objects"]:
                    o[field] = [value, value, value]
                payload = json.dumps(m).encode()
            fuser.ingest_wire(decode(payload))
            fuser.fuse(max(fuser.rig_stamp(rig), 0), [rig])
        tracks = fuser.tracks()
        assert tracks, k
        for tr in tracks:
            assert np.isfinite(tr.position).all() and np.isfinite(tr.position_cov).all(), k
            assert np.isfinite(tr.velocity).all(), k
    (tr,) = fuser.tracks()
    assert np.linalg.norm(tr.position - walker.position(fuser.rig_stamp("a"))) < 0.1
