"""``stereod schema``: the JSON Schema of the wire messages, for programs in other languages."""

from __future__ import annotations

import argparse
import json
from typing import TYPE_CHECKING

from stereod.errors import UsageError

if TYPE_CHECKING:
    from pydantic import BaseModel


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "schema",
        help="print the JSON Schema of the wire messages",
        description="Print the JSON Schema (draft 2020-12, as pydantic writes it) of every "
        "message stereod publishes, keyed by its schema string (the 'schema' field of each "
        "message): a rig's objects, object, status, stats and image messages, and the fusion "
        "node's status. Programs in other languages generate their readers from it.",
    )
    p.add_argument("name", nargs="?", help="one schema, e.g. stereod.objects/1 (default: all)")
    p.set_defaults(func=run)


def wire_messages() -> dict[str, type[BaseModel]]:
    """Every message on the wire by its schema string: a rig daemon's, then the fusion
    node's status."""
    from stereod.bus.messages import ALL_MESSAGES
    from stereod.fusion.status import FUSE_STATUS_SCHEMA, FuseStatus

    return {**ALL_MESSAGES, FUSE_STATUS_SCHEMA: FuseStatus}


def run(a: argparse.Namespace) -> int:
    messages = wire_messages()
    if a.name is not None:
        if a.name not in messages:
            raise UsageError(f"schema {a.name!r}: unknown; known: {', '.join(messages)}")
        models = {a.name: messages[a.name]}
    else:
        models = messages
    out = {name: m.model_json_schema(by_alias=True) for name, m in models.items()}
    print(json.dumps(out if a.name is None else out[a.name], indent=2))
    return 0
