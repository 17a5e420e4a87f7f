"""Wire messages: the contract fields, and golden JSON Schemas that pin every field."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from stereod.messages import ALL_MESSAGES, ObjectsMessage, ObjectState

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


@pytest.mark.parametrize("schema", sorted(ALL_MESSAGES))
def test_schemas_match_golden(schema: str) -> None:
    """Fields may only be added within a version: bump the version (and this file) otherwise.
    Regenerate with `stereod schema > tests/golden/schemas.json` after a deliberate addition."""
    golden = json.loads(GOLDEN.read_text())
    current = ALL_MESSAGES[schema].model_json_schema(by_alias=True)
    old_fields = set(golden[schema]["properties"])
    new_fields = set(current["properties"])
    assert old_fields <= new_fields, f"{schema} lost fields {old_fields - new_fields}"
    assert current == golden[schema], f"{schema} changed: regenerate the golden file if deliberate"


def test_schema_string_is_on_the_wire() -> None:
    sample = json.loads((Path(__file__).parent / "golden" / "objects_example.json").read_text())
    msg = ObjectsMessage.model_validate(sample)
    assert json.loads(msg.model_dump_json(by_alias=True)) == sample
    assert sample["schema"] == "stereod.objects/1"
