"""File names checked before they reach OpenCV, FFmpeg or a message.

A name that is not valid UTF-8 on disk arrives in Python as a string with lone surrogates
(``'r\\udcff'``, PEP 383). Handed to ``cv2.VideoCapture``, ``cv2.imread`` or
``cv2.FileStorage``, such a string crashes the interpreter (SIGSEGV, nothing printed), and a
NUL character cannot be passed to the operating system at all. Every path that goes to OpenCV
passes :func:`text_path` first; configuration fields that hold paths use :data:`TextPath`.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator

from .errors import InputError, StereodError, one_line


def path_problem(text: str) -> str | None:
    """What is wrong with a file name for OpenCV and our messages, or None when it is fine."""
    if "\x00" in text:
        return "contains a NUL character"
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return "is not valid UTF-8; rename the file or folder"
    return None


def shown(text: str | os.PathLike[str]) -> str:
    """A path as it can be printed on one line: bytes that are not UTF-8 as ``\\udcff``
    escapes, control characters (a newline in a name) escaped too."""
    return one_line(os.fspath(text).encode("utf-8", "backslashreplace").decode("utf-8"))


def text_path(
    path: str | os.PathLike[str], what: str = "file", error: type[StereodError] = InputError
) -> str:
    """``path`` as the string to give OpenCV; a name it cannot take raises ``error`` naming
    the path and ``what`` it is (``"video"``, ``"calibration image"``)."""
    text = os.fspath(path)
    problem = path_problem(text)
    if problem is not None:
        raise error(f"'{shown(text)}': the name of this {what} {problem}")
    return text


def _check_path(value: Path) -> Path:
    problem = path_problem(os.fspath(value))
    if problem is not None:
        raise ValueError(f"the path {problem}")
    return value


def _check_name(value: str) -> str:
    problem = path_problem(value)
    if problem is not None:
        raise ValueError(f"the path {problem}")
    return value


TextPath = Annotated[Path, AfterValidator(_check_path)]
"""A configuration field holding a path: valid UTF-8, no NUL (refused with the field's name)."""

TextPathStr = Annotated[str, AfterValidator(_check_name)]
"""The same for a path kept as a string (device nodes)."""
