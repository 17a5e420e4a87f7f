"""``stereod schema``: the JSON Schema of the wire messages, for programs in other languages."""

from __future__ import annotations

import argparse
import json

from stereod.errors import UsageError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("schema", help="print the JSON Schema of the wire messages")
    p.add_argument("name", nargs="?", help="one schema, e.g. stereod.objects/1 (default: all)")
    p.set_defaults(func=run)


def run(a: argparse.Namespace) -> int:
    from stereod.bus.messages import ALL_MESSAGES

    if a.name is not None:
        if a.name not in ALL_MESSAGES:
            raise UsageError(f"schema {a.name!r}: unknown; known: {', '.join(ALL_MESSAGES)}")
        models = {a.name: ALL_MESSAGES[a.name]}
    else:
        models = ALL_MESSAGES
    out = {name: m.model_json_schema(by_alias=True) for name, m in models.items()}
    print(json.dumps(out if a.name is None else out[a.name], indent=2))
    return 0
