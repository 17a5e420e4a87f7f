"""Wire messages: the contract fields, and golden JSON Schemas that pin every field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from stereod.bus.messages import ObjectsMessage, ObjectState, dump, dump_objects, object_state
from stereod.cli.schema import wire_messages
from stereod.tracking.types import Observation, TrackLifecycle, TrackState
from stereod.vision.grouping import extent_m

GOLDEN = Path(__file__).parent / "golden" / "schemas.json"


def test_contract_fields_read_by_outside_programs() -> None:
    """design.md sec. 4: these names are read by other programs and must never change."""
    objects = ObjectsMessage.model_json_schema(by_alias=True)["properties"]
    for name in ("schema", "rig", "seq", "t_ns", "stamp_utc_ns", "skew_ns", "geometry", "objects"):
        assert name in objects, name
    state = ObjectState.model_json_schema(by_alias=True)["properties"]
    for name in (
        "track_id",
        "position_m",
        "velocity_mps",
        "speed_mps",
        "heading_deg",
        "velocity_valid",
    ):
        assert name in state, name


@pytest.mark.parametrize("schema", sorted(wire_messages()))
def test_schemas_match_golden(schema: str) -> None:
    """Fields may only be added within a version: bump the version (and this file) otherwise.
    Regenerate with `stereod schema > tests/golden/schemas.json` after a deliberate addition."""
    golden = json.loads(GOLDEN.read_text())
    current = wire_messages()[schema].model_json_schema(by_alias=True)
    old_fields = set(golden[schema]["properties"])
    new_fields = set(current["properties"])
    assert old_fields <= new_fields, f"{schema} lost fields {old_fields - new_fields}"
    assert current == golden[schema], f"{schema} changed: regenerate the golden file if deliberate"


def test_schema_string_is_on_the_wire() -> None:
    sample = json.loads((Path(__file__).parent / "golden" / "objects_example.json").read_text())
    msg = ObjectsMessage.model_validate(sample)
    assert json.loads(msg.model_dump_json(by_alias=True)) == sample
    assert sample["schema"] == "stereod.objects/1"


def test_an_older_reader_ignores_fields_it_does_not_know() -> None:
    """Fields are only ever added within a version: a reader built against today's models
    parses a newer daemon's message that carries extra fields, at every level."""
    sample = json.loads((Path(__file__).parent / "golden" / "objects_example.json").read_text())
    newer = {**sample, "added_in_a_later_release": {"x": 1}}
    newer["objects"] = [{**o, "acceleration_mps2": [0.0, 0.0, 0.0]} for o in sample["objects"]]
    newer["latency"] = {**sample["latency"], "encode_ms": 0.1}
    msg = ObjectsMessage.model_validate_json(json.dumps(newer))
    assert msg.seq == sample["seq"]
    assert msg.objects[0].position_m == tuple(sample["objects"][0]["position_m"])
    assert json.loads(msg.model_dump_json(by_alias=True)) == sample


def test_a_message_from_an_older_daemon_has_no_valid_heading() -> None:
    """``heading_valid`` was added to ``stereod.object/1``: a daemon that predates it sends
    none, and a reader takes the heading as not known rather than refusing the message."""
    sample = json.loads((Path(__file__).parent / "golden" / "objects_example.json").read_text())
    sample["objects"][0]["velocity_valid"] = True
    del sample["objects"][0]["heading_valid"]
    msg = ObjectsMessage.model_validate_json(json.dumps(sample))
    assert msg.objects[0].velocity_valid and not msg.objects[0].heading_valid


def test_writers_stay_strict() -> None:
    """The producer validates what it emits: a wrong type or a missing field is refused."""
    from pydantic import ValidationError

    sample = json.loads((Path(__file__).parent / "golden" / "objects_example.json").read_text())
    with pytest.raises(ValidationError):
        ObjectsMessage.model_validate({**sample, "seq": "many"})
    del sample["objects"][0]["track_id"]
    with pytest.raises(ValidationError):
        ObjectsMessage.model_validate(sample)


@pytest.mark.parametrize("count", [0, 1, 3])
def test_the_objects_payload_is_dumps_to_the_byte_with_each_object_serialised_once(
    count: int,
) -> None:
    """``dump_objects`` splices each object's JSON into the message's: the payload must be
    what serialising the whole message gives, and each object's that of the object alone,
    with fields left out (None) and numbers of every kind."""
    sample = json.loads((Path(__file__).parent / "golden" / "objects_example.json").read_text())
    one = sample["objects"][0]
    objects = [
        {**one, "track_id": k + 1, "velocity_sigma_mps": None if k == 1 else [0.1, 1e-9, 3.0]}
        for k in range(count)
    ]
    msg = ObjectsMessage.model_validate({**sample, "objects": objects, "calibration_id": None})
    payload, states = dump_objects(msg)
    assert payload == dump(msg)
    assert states == [(o.track_id, dump(o)) for o in msg.objects]


def test_an_objects_extent_is_its_boxes_seen_at_the_published_depth() -> None:
    """A blob box 30 x 60 px seen at 12 m (a mismatch's disparity) while the track's filter
    holds the object at 4 m: the published box is 30 x 60 px at 4 m (f = 600 px: 0.2 x 0.4 m),
    around the published position, not the 0.6 x 1.2 m the boxes make at 12 m."""
    f, z_seen, z = 600.0, 12.0, 4.0
    box = np.array([300, 200, 30, 60])
    centroid = np.array([315.0, 230.0])
    seen = np.array([0.3, 0.1, z_seen])
    lo, hi = extent_m(seen, box, box, centroid, f)
    z2 = np.zeros(2)
    ob = Observation(
        seen, np.eye(3), z2, z2, centroid, centroid, box, box, 1800, 1800, 50.0, 0.6,
        extent_m=(lo - seen, hi - seen),
    )  # fmt: skip
    at = np.array([0.1, 0.03, z])
    state = TrackState(
        7, TrackLifecycle.CONFIRMED, 0, ob, at, np.eye(3), np.zeros(3), np.eye(3), False,
        False, 0.0, 1.0, 0.0, 180.0, None, 1.0, False,
    )  # fmt: skip
    wire = object_state(state, 0, 0)
    assert wire.extent_min_m is not None and wire.extent_max_m is not None
    size = np.subtract(wire.extent_max_m, wire.extent_min_m)
    assert size == pytest.approx([30 * z / f, 60 * z / f, 30 * z / f])
    assert all(a < p < b for a, p, b in zip(wire.extent_min_m, at, wire.extent_max_m))
