"""What every fuzz test checks, and the strategies they share.

The property, for any input a user could type or a file could hold: the code either accepts it
or refuses it with one :class:`~stereod.errors.StereodError` whose message is one non-empty
line and whose exit code is a sysexits code; never another exception (a traceback), and the
input file is left as it was.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from hypothesis import HealthCheck, event, settings
from hypothesis import strategies as st

from stereod.errors import StereodError

SYSEXITS = {64, 65, 66, 69, 70, 73, 78}
"""The exit codes a refusal may carry (70 only for a bug, which the fuzz tests would report)."""

EXAMPLES = int(os.environ.get("FUZZ_EXAMPLES", "60"))
"""Examples per fuzz test; ``FUZZ_EXAMPLES=2000 make test`` searches deeper."""

FUZZ = settings(
    max_examples=EXAMPLES,
    deadline=2000,  # ms per example: a parser that takes this long is a finding
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
"""Hypothesis settings of the in-process parser fuzz tests (about a second each)."""

T = TypeVar("T")


def accepted_or_refused(fn: Callable[..., T], *args: Any, **kw: Any) -> T | StereodError:
    """Call ``fn``; return its result, or the :class:`StereodError` it raised after checking
    that it is one line with a sysexits code other than 70. Anything else propagates and
    fails the test with its traceback, which is the finding."""
    try:
        result = fn(*args, **kw)
    except StereodError as exc:
        text = str(exc)
        assert text.strip() and "\n" not in text, f"not one line: {text!r}"
        assert exc.exit_code in SYSEXITS - {70}, (exc.exit_code, text)
        event(f"{getattr(fn, '__name__', 'call')}: refused, exit {exc.exit_code}")
        return exc
    event(f"{getattr(fn, '__name__', 'call')}: accepted")
    return result


def digest(path: Path) -> str:
    """A file's content hash (to show an input was not modified)."""
    return hashlib.sha256(path.read_bytes()).hexdigest()


scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=24),
    st.sampled_from(["", "0", "-1", "1e400", "nan", "tcp/127.0.0.1:0", "/dev/null", "a//b"]),
)
"""Values of every TOML/JSON scalar kind, with the edge cases that broke things before."""

toml_values = st.recursive(
    scalars,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=8,
)
"""Any TOML value."""

json_values = st.recursive(
    st.none() | scalars,
    lambda inner: (
        st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
"""Any JSON document (floats may be NaN or infinite, as Python's json writes them)."""


def toml_value(v: Any) -> str:
    """One value in TOML syntax (strings as basic strings, tables inline)."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def toml_document(tables: dict[str, dict[str, Any]]) -> str:
    """A TOML document of tables of key = value lines."""
    out = []
    for name, table in tables.items():
        out.append(f"[{json.dumps(name)}]")
        out += [f"{json.dumps(k)} = {toml_value(v)}" for k, v in table.items() if v is not None]
    return "\n".join(out) + "\n"


depths = st.one_of(st.integers(1, 80), st.integers(500, 3000), st.integers(50_000, 200_000))
"""How deep a text nests: shallow (accepted), past Python's recursion limit, past the stack
of a native parser (Zenoh's JSON5, OpenCV's FileStorage: SIGSEGV before the bounds)."""

huge_numbers = st.one_of(
    st.integers(1001, 6000).map(lambda n: "9" * n),
    st.integers(-(2**300), 2**300).map(str),
    st.sampled_from(
        ["1e308", "-1e308", "1e400", "2147483648", "9223372036854775808", "1" + "0" * 4301]
    ),
)
"""Numbers as text: past int32 and int64, past float64, past Python's 4300-digit limit."""


def nested(depth: int, open_: str, close: str, inner: str = "1") -> str:
    """``inner`` inside ``depth`` pairs of ``open_`` and ``close`` (built without recursion)."""
    return open_ * depth + inner + close * depth


@st.composite
def deep_toml(draw: st.DrawFn) -> str:
    """A TOML document nesting ``depths`` deep: arrays, inline tables, dotted keys or a
    table header, in a field of the config."""
    n = draw(depths)
    kind = draw(st.sampled_from(["array", "inline", "dotted", "header"]))
    if kind == "array":
        return f"[zenoh]\nconnect = {nested(n, '[', ']', draw(huge_numbers))}\n"
    if kind == "inline":
        return f"[driver.options]\na = {nested(n, '{a = ', '}', draw(huge_numbers))}\n"
    keys = ".".join(["a"] * min(n, 5000))
    if kind == "dotted":
        return f"[driver.options]\n{keys} = 1\n"
    return f"[driver.options.{keys}]\nb = 1\n"


@st.composite
def deep_json(draw: st.DrawFn) -> str:
    """A JSON (or JSON5) text nesting ``depths`` deep in arrays or objects."""
    n = draw(depths)
    inner = draw(huge_numbers)
    if draw(st.booleans()):
        return nested(n, "[", "]", inner)
    return '{"mode": "peer", "a": ' + nested(n, '{"a": ', "}", inner) + "}"


@st.composite
def deep_storage(draw: st.DrawFn) -> tuple[str, str]:
    """An OpenCV FileStorage text (suffix, text) nesting ``depths`` deep: YAML flow
    sequences, YAML indentation or ``- - -`` sequences, XML elements or JSON arrays."""
    n = draw(depths)
    number = draw(huge_numbers)
    kind = draw(st.sampled_from(["yaml-flow", "yaml-block", "yaml-dash", "xml", "json"]))
    if kind == "yaml-flow":
        return ".yml", f"%YAML:1.0\n---\nM1: {nested(n, '[', ']', number)}\n"
    if kind == "yaml-block":
        n = min(n, 3000)  # lines of up to n spaces: the file stays below its size bound
        body = "".join(" " * i + f"a{i}:\n" for i in range(n))
        return ".yml", f"%YAML:1.0\n---\nM1:\n{body}{' ' * n}x: {number}\n"
    if kind == "yaml-dash":
        return ".yml", f"%YAML:1.0\n---\nM1:\n  {'- ' * n}{number}\n"
    if kind == "xml":
        body = nested(n, "<a>", "</a>", number)
        return ".xml", f'<?xml version="1.0"?>\n<opencv_storage>{body}</opencv_storage>\n'
    return ".json", '{"M1": ' + nested(n, "[", "]", number) + "}"


def not_killed(returncode: int, what: str = "") -> None:
    """Assert that a process ended by itself: not by a signal (a negative return code from
    subprocess, or 128 + n from a shell: 139 is SIGSEGV), whatever it was given."""
    assert returncode >= 0, f"killed by signal {-returncode} {what}"
    assert not 128 < returncode <= 128 + 64, f"exit {returncode}: a signal's code {what}"
