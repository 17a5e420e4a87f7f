"""Bounds on nesting and on the length of numbers, checked before a parser sees a text.

Every parser stereod hands a file or a variable to recurses on nesting: Python's ``json`` and
``tomllib`` raise RecursionError some hundred levels deep (an internal error, exit 70, for
what is bad input), and the native parsers of Zenoh (JSON5) and OpenCV (FileStorage YAML, XML
and JSON) overflow their stack and kill the process (SIGSEGV, exit 139, nothing said; a daemon
restarted into the same file for ever). A number of thousands of digits is as bad: Python
refuses to convert it (ValueError) where a parser does not expect it. So a text is scanned
first, cheaply and without recursion, for how deep it nests (brackets outside strings and
comments, XML elements, YAML indentation) and for its longest number; over a bound it is
refused in one line naming the file, as any other bad content of its kind.

The bounds are far beyond any real file (a stereod config nests 4 levels, a calibration 3, a
Zenoh config about 8) and far below what crashes a parser (OpenCV and Zenoh crash some
thousands of levels deep, Python's parsers near 1000).
"""

from __future__ import annotations

import json
import re
from typing import Any, Literal

import numpy as np

from stereod.errors import StereodError

MAX_DEPTH = 64
"""Deepest nesting accepted in a configuration, calibration, manifest or message text, levels."""
MAX_DIGITS = 1000
"""Longest run of digits accepted in a number, characters (a float64 needs 17, an int64 19;
Python refuses to convert more than 4300)."""

Syntax = Literal["json", "json5", "toml", "yaml", "xml"]

# What hides brackets and digits from a parser: a string or a comment of the syntax. A string
# does not span lines, except TOML's triple-quoted ones.
_STRINGS = r'"(?:[^"\\\n]|\\.)*"' + r"|'(?:[^'\\\n]|\\.)*'"
_COMMENTS = {
    "json": "",
    "json5": r"|/\*[\s\S]*?\*/|//[^\n]*",
    "toml": r"|#[^\n]*",
    "yaml": r"|#[^\n]*",
}
_TRIPLE = r'"""[\s\S]*?"""' + r"|'''[\s\S]*?'''|"
_HIDDEN = {
    syntax: re.compile((_TRIPLE if syntax == "toml" else "") + _STRINGS + comments)
    for syntax, comments in _COMMENTS.items()
}
_TAG = re.compile(r"<!--[\s\S]*?-->|<!\[CDATA\[[\s\S]*?\]\]>|<[^>]*>")
_LINE_START = re.compile(r"^[ -]*", re.M)


def depth_problem(text: str, syntax: Syntax) -> str | None:
    """What is wrong with ``text`` (of ``syntax``) for its parser: nesting deeper than
    :data:`MAX_DEPTH` or a number longer than :data:`MAX_DIGITS` digits; None when fine.
    Linear in the text; never recurses."""
    if syntax == "xml":
        depth = _xml_depth(text)
        if (
            _longest_digits(np.frombuffer(text.encode("utf-8", "surrogatepass"), np.uint8))
            > MAX_DIGITS
        ):
            return f"holds a number of more than {MAX_DIGITS} digits"
    else:
        depth, long_number = _bracket_depth(text, syntax)
        if long_number:
            return f"holds a number of more than {MAX_DIGITS} digits"
        if syntax == "yaml":
            depth += _indent_depth(text)
    if depth > MAX_DEPTH:
        return f"nested deeper than {MAX_DEPTH} levels"
    return None


def check_depth(text: str, syntax: Syntax, where: str, error: type[StereodError]) -> None:
    """Raise ``error`` naming ``where`` (a file, a variable) when ``text`` nests too deep or
    holds too long a number for its parser (see :func:`depth_problem`)."""
    problem = depth_problem(text, syntax)
    if problem is not None:
        raise error(f"{where}: {problem}, far beyond any real one; check that it is the right one")


def loads_json(text: str | bytes, where: str, error: type[StereodError]) -> Any:
    """``json.loads`` of ``text`` after :func:`check_depth`; ValueError (not JSON) is left to
    the caller, whose words for it differ."""
    if isinstance(text, bytes):
        text = text.decode("utf-8")
    check_depth(text, "json", where, error)
    return json.loads(text)


def _bracket_depth(text: str, syntax: Syntax) -> tuple[int, bool]:
    """The deepest bracket nesting outside strings and comments, and whether a run of digits
    there is too long: strings and comments blanked by a regular expression, the rest
    looked at as an array of bytes (no per-character Python loop)."""
    bare = np.frombuffer(_HIDDEN[syntax].sub(" ", text).encode("utf-8", "surrogatepass"), np.uint8)
    return _max_depth(bare), _longest_digits(bare) > MAX_DIGITS


def _max_depth(chars: np.ndarray) -> int:
    """The deepest nesting of the brackets ``[]{}`` among ``chars`` (bytes), a closer with
    no opener ignored."""
    opens = (chars == ord("[")) | (chars == ord("{"))
    closes = (chars == ord("]")) | (chars == ord("}"))
    steps = opens[opens | closes].astype(np.int64) * 2 - 1
    if steps.size == 0:
        return 0
    level = np.cumsum(steps)
    floor = np.minimum.accumulate(np.minimum(level, 0))
    return int((level - floor).max())


def _longest_digits(chars: np.ndarray) -> int:
    """The longest run of ASCII digits among ``chars`` (bytes)."""
    digit = np.concatenate(([False], (chars >= ord("0")) & (chars <= ord("9")), [False]))
    edges = np.flatnonzero(digit[1:] != digit[:-1])
    return int((edges[1::2] - edges[::2]).max()) if edges.size else 0


def _xml_depth(text: str) -> int:
    """The deepest element nesting of an XML text (comments, CDATA, declarations skipped)."""
    depth = deepest = 0
    for m in _TAG.finditer(text):
        tag = m.group()
        if tag.startswith(("<!", "<?")):
            continue
        if tag.startswith("</"):
            depth = max(depth - 1, 0)
        elif not tag.endswith("/>"):
            depth += 1
            deepest = max(deepest, depth)
    return deepest


def _indent_depth(text: str) -> int:
    """The deepest block nesting of a YAML text below its top level: the stack of
    indentation columns, each ``- `` of a sequence entry one level more (``- - - x`` is
    three deep)."""
    prefixes = set(_LINE_START.findall(text))
    if len(prefixes) <= MAX_DEPTH and max(map(len, prefixes), default=0) <= MAX_DEPTH:
        return max(len(prefixes) - 1, 0)  # no deeper than its distinct indentations: most files
    stack: list[int] = []
    deepest = 0
    for line in text.splitlines():
        rest = line.lstrip(" ")
        if not rest or rest.startswith(("#", "%", "---", "...")):
            continue
        col = len(line) - len(rest)
        levels = [col]
        while rest == "-" or rest.startswith("- "):
            stripped = rest[1:].lstrip(" ")
            col += len(rest) - len(stripped)
            rest = stripped
            levels.append(col)
        while stack and stack[-1] >= levels[0]:
            stack.pop()
        stack += levels
        deepest = max(deepest, len(stack))
    return max(deepest - 1, 0)


def check_data_depth(data: object, where: str, error: type[StereodError]) -> None:
    """Raise ``error`` naming ``where`` when parsed ``data`` (dicts and lists) nests deeper
    than :data:`MAX_DEPTH`: what brackets do not show (TOML's dotted keys ``a.b.c = 1``),
    before code that recurses on it. Walks it with a stack, never recursing."""
    stack: list[tuple[object, int]] = [(data, 0)]
    while stack:
        node, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise error(
                f"{where}: nested deeper than {MAX_DEPTH} levels, far beyond any real one; "
                "check that it is the right one"
            )
        if isinstance(node, dict):
            stack += [(v, depth + 1) for v in node.values()]
        elif isinstance(node, list):
            stack += [(v, depth + 1) for v in node]
