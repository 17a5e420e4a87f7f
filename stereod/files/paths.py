"""File names checked before they reach OpenCV, FFmpeg or a message.

A name that is not valid UTF-8 on disk arrives in Python as a string with lone surrogates
(``'r\\udcff'``, PEP 383). Handed to ``cv2.VideoCapture``, ``cv2.imread`` or
``cv2.FileStorage``, such a string crashes the interpreter (SIGSEGV, nothing printed), and a
NUL character cannot be passed to the operating system at all. Every path that goes to OpenCV
passes :func:`text_path` first; configuration fields that hold paths use :data:`TextPath`.

Small input files (a config, a calibration, a manifest, a timestamp CSV) are read through
:func:`read_input_file`: a device such as /dev/zero, a named pipe or a directory is refused
by name, and no more than a bound is read.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Annotated

from pydantic import AfterValidator, BeforeValidator

from stereod.errors import InputError, MissingInputError, StereodError, one_line

MAX_TEXT_BYTES = 16 * 2**20
"""The largest configuration, calibration, manifest or Zenoh config file read, bytes (such
files hold a few kB)."""
MAX_TIMESTAMP_BYTES = 256 * 2**20
"""The largest timestamp CSV read, bytes: about nine million frames, three days at 30 Hz."""


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


def _not_empty(value: object) -> object:
    if isinstance(value, str) and not value.strip():
        raise ValueError("is empty: give a path, or leave the key out")
    return value


TextPath = Annotated[Path, BeforeValidator(_not_empty), AfterValidator(_check_path)]
"""A configuration field holding a path: not empty (which would name the folder the command
runs in), valid UTF-8, no NUL (refused with the field's name)."""

TextPathStr = Annotated[str, BeforeValidator(_not_empty), AfterValidator(_check_name)]
"""The same for a path kept as a string (device nodes)."""


def file_kind(mode: int) -> str:
    """What a file that is not a regular one is, from its ``st_mode``, with its article."""
    for test, name in (
        (stat.S_ISDIR, "a directory"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a named pipe"),
        (stat.S_ISSOCK, "a socket"),
    ):
        if test(mode):
            return name
    return "a special file"


def _check_file(
    path: str | os.PathLike[str],
    st: os.stat_result,
    what: str,
    limit: int,
    too_large: type[StereodError],
) -> None:
    if not stat.S_ISREG(st.st_mode):
        raise MissingInputError(
            f"{shown(path)}: is {file_kind(st.st_mode)}, not {what}; give the path of a file"
        )
    if st.st_size > limit:
        raise too_large(_too_large(path, what, limit))


def _too_large(path: str | os.PathLike[str], what: str, limit: int) -> str:
    return (
        f"{shown(path)}: larger than {limit / 2**20:g} MiB, too large for {what}; is it the "
        "right file?"
    )


def check_input_file(
    path: str | os.PathLike[str],
    what: str,
    *,
    limit: int = MAX_TEXT_BYTES,
    too_large: type[StereodError] = InputError,
) -> None:
    """Refuse an input that another reader opens by name (Zenoh's config file) when it is not
    a regular file (a device, a named pipe, a directory: :class:`MissingInputError`, 66) or
    holds more than ``limit`` bytes (``too_large``). OSError (no such file) is left to the
    caller, whose words for it differ."""
    _check_file(path, os.stat(path), what, limit, too_large)


def read_input_file(
    path: str | os.PathLike[str],
    what: str,
    *,
    limit: int = MAX_TEXT_BYTES,
    too_large: type[StereodError] = InputError,
) -> bytes:
    """The bytes of a small input file (a config, a calibration, a manifest, a timestamp CSV),
    read whole but never more than ``limit`` bytes: a device such as /dev/zero, a named pipe
    or a directory is refused (:class:`MissingInputError`, 66) without reading it, and so is
    a file larger than ``limit`` (``too_large``: the error its other content errors use).
    ``what`` names the file in messages, with its article (``"a config file"``). OSError from
    opening or reading (no such file, no permission) is left to the caller, whose words for it
    differ."""
    # Not even opened unless a regular file (opening a device can act on it: a serial port
    # resets what hangs on it); checked again once open, in case it was swapped meanwhile.
    # O_NONBLOCK: opening a named pipe with no writer would wait for one.
    check_input_file(path, what, limit=limit, too_large=too_large)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    try:
        _check_file(path, os.fstat(fd), what, limit, too_large)
        chunks: list[bytes] = []
        size = 0
        while size <= limit:  # a file that grows while it is read stops at the limit too
            chunk = os.read(fd, min(2**20, limit + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
    finally:
        os.close(fd)
    if size > limit:
        raise too_large(_too_large(path, what, limit))
    return b"".join(chunks)
