"""The reference pages, generated from the code when the site is built, so they cannot drift.

- ``reference/cli.md``: every command's ``--help``, from the argparse parser ``stereod`` runs;
- ``reference/configuration.md``: every section and field of the configuration (type, default,
  what is allowed, its ``STEREOD_<SECTION>__<FIELD>`` variable, description) from the pydantic
  models, the drivers' options and the table of physical bounds;
- ``reference/wire.md``: the Zenoh keys and every message's fields from its JSON Schema, as
  ``stereod schema`` prints it;
- ``reference/exit-codes.md``: the sysexits codes and the exception hierarchy;
- on the Concepts page, which modules cite each of the paper's equations; on the Python API
  page, what ``stereod`` and ``stereod.client`` export.

MkDocs runs this file as a hook (``hooks:`` in mkdocs.yml): :func:`on_files` adds the pages to
the site without writing them into docs/. ``tests/test_docs.py`` imports it to check that the
pages cover every command and every field. Everything it reads from stereod is imported in the
block below: when a module moves, its path changes there and nowhere else.
"""

from __future__ import annotations

import argparse
import ast
import enum
import inspect
import json
import os
import re
import signal
import types
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from pydantic import BaseModel
from pydantic.fields import FieldInfo

# --- what this module reads from stereod: the one place to change when a module moves ---
import stereod
import stereod.client
from stereod import errors
from stereod.bus import keys
from stereod.cli import build_parser
from stereod.cli.schema import wire_messages
from stereod.daemon.config import StereodConfig
from stereod.files.bounds import BOUNDS, Bound
from stereod.files.bounds import markdown_table as bounds_table
from stereod.files.config_input import ENV_OTHER, ENV_PREFIX
from stereod_fakes.replay import ReplayOptions
from stereod_v4l2_minoru.driver import MinoruOptions

DRIVER_OPTIONS: dict[str, type[BaseModel]] = {
    "v4l2_minoru": MinoruOptions,
    "replay": ReplayOptions,
}
"""The drivers whose ``[driver.options]`` are documented field by field."""

HELP_COLUMNS = 100
"""The width ``--help`` is wrapped to on the CLI page, characters."""


ROLE = re.compile(r":[a-z]+:`(~?)([^`]+)`")
"""A Sphinx cross-reference in a docstring: ``:class:`~stereod.sources.frames.Frame```."""


def _rst(text: str) -> str:
    """A docstring's Sphinx roles as inline code (``~`` keeping the last name only)."""
    return ROLE.sub(
        lambda m: f"`{m.group(2).rsplit('.', 1)[-1] if m.group(1) else m.group(2)}`", text
    )


def _cell(text: object) -> str:
    """``text`` fit for one markdown table cell: one line, pipes escaped, roles as code."""
    return _rst(" ".join(str(text).split())).replace("|", "\\|")


# ------------------------------------------------------------------------------------ CLI


def command_parsers() -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """Every (sub)command's name (``stereod calibration show``) and parser, in ``--help``
    order, the top-level ``stereod`` first."""

    def walk(name: str, parser: argparse.ArgumentParser) -> Iterator[tuple[str, Any]]:
        yield name, parser
        seen: set[int] = set()
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for sub_name, sub in action.choices.items():
                    if id(sub) not in seen:  # an alias names the same parser again
                        seen.add(id(sub))
                        yield from walk(f"{name} {sub_name}", sub)

    yield from walk("stereod", build_parser())


def cli_page() -> str:
    """The CLI reference: each command's ``--help`` as ``stereod`` prints it."""
    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_COLUMNS)
    try:
        parts = [
            "# Command reference",
            "Generated from the command's own parser: each section is what `--help` prints. "
            "How the commands fit together is in [Commands](../cli.md); what a command's "
            "exit code means is in [Exit codes](exit-codes.md).",
        ]
        for name, parser in command_parsers():
            level = "##" if name.count(" ") <= 1 else "###"
            parts.append(f"{level} `{name}`")
            parts.append("```text\n" + parser.format_help().rstrip() + "\n```")
        return "\n\n".join(parts) + "\n"
    finally:
        if saved is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved


# ------------------------------------------------------------------------- configuration


def type_name(annotation: Any) -> str:
    """A readable name of a field's type: ``float``, ``"peer" | "client"``, ``list[str]``."""
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin is typing.Annotated:
        return type_name(args[0])
    if origin is typing.Literal:
        return " \\| ".join(json.dumps(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " \\| ".join(type_name(a) for a in args)
    if origin in (list, tuple, dict):
        inner = ", ".join("..." if a is Ellipsis else type_name(a) for a in args)
        return f"{origin.__name__}[{inner}]"
    if annotation is type(None):
        return "none"
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return " \\| ".join(json.dumps(m.value) for m in annotation)
    if isinstance(annotation, type):
        return "path" if annotation.__name__ in ("Path", "TextPath") else annotation.__name__
    name = getattr(annotation, "__name__", None)
    return "path" if name == "TextPath" else str(name or annotation).replace("typing.", "")


def toml_value(value: Any) -> str:
    """``value`` written as TOML writes it."""
    if isinstance(value, enum.Enum):
        value = value.value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str | Path):
        return json.dumps(str(value))
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"
    return repr(value)


def default_of(field: FieldInfo) -> Any:
    """A field's default value (its factory called), or None when it has none."""
    if field.default_factory is not None:
        return field.default_factory()  # type: ignore[call-arg]
    return None if field.is_required() else field.default


def allowed(field: FieldInfo) -> str:
    """What a field allows beyond its type: its bounds, range and pattern."""
    found: list[str] = []
    for m in field.metadata:
        for attr, sign in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
            if getattr(m, attr, None) is not None:
                found.append(f"{sign} {getattr(m, attr):g}")
        if getattr(m, "pattern", None):
            found.append(f"matches `{m.pattern}`")
        bound = getattr(getattr(m, "func", None), "__self__", None)
        if isinstance(bound, Bound):
            found.append(bound.range_text())
    return ", ".join(found)


def field_rows(model: type[BaseModel], env_prefix: str) -> list[str]:
    """The table of one model's fields: name, type, default, allowed, variable, description."""
    rows = [
        "| field | type | default | allowed | environment variable | description |",
        "|---|---|---|---|---|---|",
    ]
    for name, field in model.model_fields.items():
        default = default_of(field)
        shown = "unset" if default is None else f"`{_cell(toml_value(default))}`"
        rows.append(
            f"| `{name}` | {type_name(field.annotation)} | {shown} | {_cell(allowed(field))} "
            f"| `{env_prefix}{name.upper()}` | {_cell(field.description or '')} |"
        )
    return rows


def config_sections() -> dict[str, type[BaseModel]]:
    """Every section of the configuration file: its TOML table name and model."""
    return {
        name: typing.cast(type[BaseModel], field.annotation)
        for name, field in StereodConfig.model_fields.items()
    }


def example_toml() -> str:
    """Every section with every field at its default: a complete configuration file."""
    lines: list[str] = []
    for section, model in config_sections().items():
        lines.append(f"[{section}]")
        for name, field in model.model_fields.items():
            default = default_of(field)
            text = f"{name} = {toml_value(default)}" if default is not None else f"# {name} ="
            lines.append(text)
        lines.append("")
    return "\n".join(lines).rstrip()


def config_page() -> str:
    """The configuration reference: every section and field of :class:`StereodConfig`."""
    parts = [
        "# Configuration reference",
        "Generated from the configuration's models. One TOML file (`--config FILE`, by default "
        "`/etc/stereod/stereod.toml`); a variable "
        f"`{ENV_PREFIX}<SECTION>__<FIELD>` overrides a field (a list or table as JSON, "
        f"`{ENV_PREFIX}DRIVER__OPTIONS__<OPTION>` reaches into the driver's options), and a "
        "command's flags override both. "
        f"{', '.join(f'`{v}`' for v in ENV_OTHER)} are not fields. A value out of range is one "
        "line naming where it came from and exit 78 (64 for a flag); see "
        "[Configuration](../configuration.md) for how to use them.",
        "## Every default, as a file",
        "```toml\n" + example_toml() + "\n```",
    ]
    for section, model in config_sections().items():
        parts.append(f"## `[{section}]`")
        doc = inspect.getdoc(model)
        if doc:
            parts.append(_rst(" ".join(doc.split())))
        env = f"{ENV_PREFIX}{section.upper()}__"
        parts.append("\n".join(field_rows(model, env)))
    for driver, model in DRIVER_OPTIONS.items():
        parts.append(f"## `[driver.options]` of `{driver}`")
        doc = inspect.getdoc(model)
        if doc:
            parts.append(_rst(" ".join(doc.split())))
        parts.append("\n".join(field_rows(model, f"{ENV_PREFIX}DRIVER__OPTIONS__")))
    parts.append("## Bounds")
    parts.append(
        "Every number with a physical meaning is held to what a real rig can be, wherever it "
        "enters: a flag (exit 64), the file or a variable (exit 78), a calibration file or a "
        f"reload (refused, the daemon runs on). {len(BOUNDS)} bounds:"
    )
    parts.append(bounds_table().rstrip())
    return "\n\n".join(parts) + "\n"


# ----------------------------------------------------------------------------- wire format


def _schema_type(prop: dict[str, Any]) -> str:
    """A JSON Schema property's type in a word or two."""
    if "$ref" in prop:
        name = prop["$ref"].rsplit("/", 1)[-1]
        return f"[{name}](#{name.lower()})"
    if "const" in prop:
        return f"`{json.dumps(prop['const'])}`"
    if "enum" in prop:
        return " \\| ".join(f"`{json.dumps(v)}`" for v in prop["enum"])
    if "anyOf" in prop:
        return " \\| ".join(_schema_type(p) for p in prop["anyOf"])
    kind = prop.get("type", "any")
    if kind == "array":
        if "prefixItems" in prop:
            return "[" + ", ".join(_schema_type(p) for p in prop["prefixItems"]) + "]"
        return f"array of {_schema_type(prop.get('items', {}))}"
    if kind == "object" and "additionalProperties" in prop:
        extra = prop["additionalProperties"]
        return f"object of {_schema_type(extra) if isinstance(extra, dict) else 'any'}"
    return str(kind)


def _schema_table(schema: dict[str, Any]) -> str:
    required = set(schema.get("required", []))
    rows = ["| field | type | required | description |", "|---|---|---|---|"]
    for name, prop in schema.get("properties", {}).items():
        rows.append(
            f"| `{name}` | {_schema_type(prop)} | {'yes' if name in required else ''} "
            f"| {_cell(prop.get('description', ''))} |"
        )
    return "\n".join(rows)


def message_schemas() -> dict[str, dict[str, Any]]:
    """Every wire message's JSON Schema, by its ``schema`` name, as ``stereod schema`` prints
    them."""
    return {name: m.model_json_schema(by_alias=True) for name, m in wire_messages().items()}


def wire_page() -> str:
    """The wire reference: the keys, and each message's fields from its JSON Schema."""
    key_doc = (keys.__doc__ or "").split("::", 1)[-1].split("\n\n")[1]
    parts = [
        "# Wire reference",
        "Generated from the message models' JSON Schemas (`stereod schema` prints them; "
        "`tests/golden/schemas.json` pins them). How to read them is in "
        "[Wire format](../wire-format.md).",
        "## Keys",
        f"Everything a daemon says lives under `<prefix>/<rig>/` (default "
        f"`{keys.DEFAULT_PREFIX}/{keys.DEFAULT_RIG}/`):",
        "```text\n" + inspect.cleandoc(key_doc) + "\n```",
    ]
    done: set[str] = set()
    for name, schema in message_schemas().items():
        parts.append(f"## `{name}`")
        if schema.get("description"):
            parts.append(_rst(" ".join(schema["description"].split())))
        parts.append(_schema_table(schema))
        for def_name, sub in schema.get("$defs", {}).items():
            if def_name in done:
                continue
            done.add(def_name)
            parts.append(f"### {def_name}")
            if sub.get("description"):
                parts.append(_rst(" ".join(sub["description"].split())))
            if "properties" in sub:
                parts.append(_schema_table(sub))
            elif "enum" in sub:
                parts.append("One of " + ", ".join(f"`{json.dumps(v)}`" for v in sub["enum"]))
        body = json.dumps(schema, indent=2)
        parts.append(
            f'??? note "JSON Schema of {name}"\n\n    ```json\n' + _indent(body) + "\n    ```"
        )
    return "\n\n".join(parts) + "\n"


def _indent(text: str) -> str:
    return "\n".join("    " + line for line in text.splitlines())


# ------------------------------------------------------------------------------ exit codes


def exit_codes() -> dict[str, tuple[int, str]]:
    """Every ``EX_*`` constant of :mod:`stereod.errors`: its code and its docstring."""
    tree = ast.parse(inspect.getsource(errors))
    found: dict[str, tuple[int, str]] = {}
    body = tree.body
    for node, after in zip(body, [*body[1:], None], strict=True):
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target = node.targets[0]
            if isinstance(target, ast.Name) and target.id.startswith("EX_"):
                doc = ""
                if isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
                    doc = str(after.value.value)
                found[target.id] = (getattr(errors, target.id), doc)
    return found


def error_classes() -> list[type[BaseException]]:
    """:class:`StereodError` and every subclass of it, depth first."""

    def walk(cls: type[BaseException]) -> Iterator[type[BaseException]]:
        yield cls
        for sub in cls.__subclasses__():
            if sub.__module__ == errors.__name__:
                yield from walk(sub)

    return list(walk(errors.StereodError))


SIGNALS = ("SIGHUP", "SIGINT", "SIGPIPE", "SIGTERM")
"""The signals whose 128 + n exit codes a command can end with."""


def exit_codes_page() -> str:
    """The exit codes: the sysexits constants, the error classes and the signals."""
    rows = ["| code | name | meaning |", "|---|---|---|", "| 0 | | success |"]
    for name, (code, doc) in sorted(exit_codes().items(), key=lambda kv: kv[1][0]):
        rows.append(f"| {code} | `{name}` | {_cell(doc)} |")
    classes = [
        "| error | parent | exit code | meaning |",
        "|---|---|---|---|",
    ]
    for cls in error_classes():
        parent = cls.__mro__[1].__name__
        code = getattr(cls, "exit_code", "")
        if cls is errors.Interrupted:
            code = "128 + signal"
        doc = (inspect.getdoc(cls) or "").split("\n\n")[0]
        classes.append(f"| `{cls.__name__}` | `{parent}` | {code} | {_cell(doc)} |")
    sigs = ["| code | signal |", "|---|---|"]
    for name in SIGNALS:
        if hasattr(signal, name):
            sigs.append(f"| {128 + int(getattr(signal, name))} | {name} |")
    hierarchy = (errors.__doc__ or "").split("::", 1)[-1].split("\n\n")[1]
    return (
        "\n\n".join(
            [
                "# Exit codes",
                "Generated from `stereod.errors`. Every command ends with at most one line on "
                "stderr naming the file, field, flag or device, and one of these codes "
                "(sysexits.h). systemd does not restart the service on 65, 66 or 78.",
                "\n".join(rows),
                "## Errors",
                "Every error a user sees is a `StereodError`; the class decides the code:",
                "```text\n" + inspect.cleandoc(hierarchy) + "\n```",
                "\n".join(classes),
                "## Signals",
                "A signal that stops a command before the end of its work gives 128 + its "
                "number; outputs are left as they were, with no partial file. `run` ends "
                "on SIGINT or SIGTERM with 0 and reloads on SIGHUP; `record` and a `--loop` "
                "replay end on a signal with 0.",
                "\n".join(sigs),
            ]
        )
        + "\n"
    )


# ------------------------------------------------------------------------------- equations

EQUATION = re.compile(r"\beqs?\. ?(\d+)(?:-(\d+))?")
"""A citation of the paper's equations in the code: ``eq. 9``, ``eq. 2-5``."""


def equations() -> dict[int, list[str]]:
    """For each of the paper's equations the code cites, the modules that cite it (a range
    such as ``eq. 2-5`` cites each)."""
    root = Path(stereod.__file__).parent
    found: dict[int, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        module = ".".join(path.relative_to(root.parent).with_suffix("").parts)
        for m in EQUATION.finditer(path.read_text()):
            first = int(m.group(1))
            for n in range(first, int(m.group(2) or first) + 1):
                found.setdefault(n, set()).add(module.removesuffix(".__init__"))
    return {n: sorted(mods) for n, mods in sorted(found.items())}


def equations_table() -> str:
    """The table of :func:`equations`."""
    rows = ["| eq. | cited in |", "|---|---|"]
    for n, modules in equations().items():
        rows.append(f"| {n} | {', '.join(f'`{m}`' for m in modules)} |")
    return "\n".join(rows)


def api_table() -> str:
    """Every name ``stereod`` and ``stereod.client`` export, with its docstring's first line."""
    rows = ["| name | what |", "|---|---|"]
    for module in (stereod, stereod.client):
        for name in module.__all__:
            if name.startswith("__"):
                continue
            value = getattr(module, name)
            if isinstance(value, types.UnionType):
                first = "one of " + ", ".join(f"`{t.__name__}`" for t in typing.get_args(value))
            else:
                first = (inspect.getdoc(value) or "").split("\n\n")[0]
            rows.append(f"| `{module.__name__}.{name}` | {_cell(first)} |")
    return "\n".join(rows)


MARKERS: dict[str, Callable[[], str]] = {
    "<!-- gen_ref: equations -->": equations_table,
    "<!-- gen_ref: api -->": api_table,
}
"""Markers in the hand-written pages, and what replaces them."""


# ------------------------------------------------------------------------------- the hook

PAGES: dict[str, Callable[[], str]] = {
    "reference/cli.md": cli_page,
    "reference/configuration.md": config_page,
    "reference/wire.md": wire_page,
    "reference/exit-codes.md": exit_codes_page,
}
"""The generated pages, by their path in the site."""


def on_files(files: Any, config: Any) -> Any:
    """MkDocs hook: add the generated pages to the site's files."""
    from mkdocs.structure.files import File

    for path, make in PAGES.items():
        files.append(File.generated(config, path, content=make()))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """MkDocs hook: replace the :data:`MARKERS` in a page by what they stand for."""
    for marker, make in MARKERS.items():
        if marker in markdown:
            markdown = markdown.replace(marker, make())
    return markdown
