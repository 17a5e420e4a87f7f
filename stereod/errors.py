"""The one exception hierarchy of stereod.

::

    StereodError                  anything stereod reports to a user (one line, names the thing)
    ├── UsageError                a command line is invalid (exit 64)
    ├── ConfigError               a configuration file, field or flag is invalid (exit 78)
    ├── InputError                an input file or stream is missing, unreadable or inconsistent
    │   └── TruncatedInputError   a video ended before its header said it would
    ├── OutputError               an output file cannot be created or written (exit 73)
    ├── CalibrationError          a calibration file is missing, ill-shaped or does not fit
    ├── DeviceError               a camera device failed (open, ioctl)
    │   └── DeviceLost            a camera went away while in use (the source retries)
    ├── NotInstalledError         an optional dependency is missing; names the install (exit 69)
    ├── UnavailableError          a service cannot be reached (no Zenoh router; exit 69)
    ├── InternalError             a bug: an unexpected exception, logged in full (exit 70)
    └── Interrupted               a signal stopped a run before its end (exit 128 + signal)

Foreign errors (OSError, cv2.error, pydantic.ValidationError) are translated into these at the
boundary with ``raise ... from exc`` so callers only ever catch ``StereodError``.
"""

from __future__ import annotations

import difflib
import errno
import socket
import typing
from collections.abc import Sequence
from typing import Any

from pydantic import ValidationError

EX_USAGE = 64
"""Exit code for a bad command line (sysexits.h EX_USAGE)."""
EX_DATAERR = 65
"""Exit code for bad input data (sysexits.h EX_DATAERR)."""
EX_NOINPUT = 66
"""Exit code for a missing or unreadable input file (sysexits.h EX_NOINPUT)."""
EX_UNAVAILABLE = 69
"""Exit code for a device or service that cannot be reached (sysexits.h EX_UNAVAILABLE)."""
EX_SOFTWARE = 70
"""Exit code for an internal error, a bug (sysexits.h EX_SOFTWARE); the log has the details."""
EX_CANTCREAT = 73
"""Exit code for an output that cannot be created (sysexits.h EX_CANTCREAT)."""
EX_IOERR = 74
"""Exit code for standard output that failed while being written, a full disk or a device
error (sysexits.h EX_IOERR)."""
EX_CONFIG = 78
"""Exit code for bad configuration (sysexits.h EX_CONFIG); systemd does not restart on it."""


class StereodError(Exception):
    """Base of every error stereod reports; ``str()`` is one line meant for a user (a newline
    or other control character quoted from a file or a name is escaped)."""

    exit_code: int = 1

    def __str__(self) -> str:
        return one_line(super().__str__())


class UsageError(StereodError):
    """A command line is invalid in a way its parser cannot see (flags that contradict each
    other, a value only the command can check); the message names the flag."""

    exit_code = EX_USAGE


class ConfigError(StereodError):
    """A configuration value is invalid; the message names the field, value and what is allowed."""

    exit_code = EX_CONFIG


class InputError(StereodError):
    """An input file or stream is missing, unreadable or inconsistent."""

    exit_code = EX_DATAERR


class MissingInputError(InputError):
    """An input file does not exist or cannot be opened."""

    exit_code = EX_NOINPUT


class TruncatedInputError(InputError):
    """A video decoded fewer frames than its header announced; what decoded was processed."""


class OutputError(StereodError):
    """An output path cannot be written."""

    exit_code = EX_CANTCREAT


class StdoutWriteError(OutputError):
    """This process's standard output, given as an output file (``--jsonl -`` or
    ``/dev/stdout``), failed while being written: a full disk or a device error."""

    exit_code = EX_IOERR


class ReaderGone(OutputError):
    """An output written in place (stdout, a named pipe) whose reader closed it. When it is
    the process's stdout (``--jsonl /dev/stdout | head``) a command ends quietly with 0, as
    when the reader of its stdout goes away; a named pipe's reader that went away is an error
    (73). A daemon keeps running without that output and says so on its status key."""

    def __init__(self, message: str, *, stdout: bool) -> None:
        super().__init__(message)
        self.stdout = stdout


class CalibrationError(StereodError):
    """A calibration is missing, ill-shaped, non-finite or does not fit the stream."""

    exit_code = EX_CONFIG


class DeviceError(StereodError):
    """A camera device failed to open, configure or stream."""

    exit_code = EX_UNAVAILABLE


class DeviceLost(DeviceError):
    """A camera went away while in use (unplugged, reset); its source retries by itself, the
    daemon reports the eye down and keeps running."""


class NotInstalledError(StereodError):
    """An optional dependency (an extra such as ``stereod[plot]``) is not installed; the message
    says how to install it."""

    exit_code = EX_UNAVAILABLE


class UnavailableError(StereodError):
    """A service the run needs cannot be reached now (a Zenoh router in client mode); unlike
    a bad configuration, trying again later may work."""

    exit_code = EX_UNAVAILABLE


class InternalError(StereodError):
    """Something unexpected failed (a bug); the full traceback is in the log."""

    exit_code = EX_SOFTWARE


def describe_validation_error(exc: ValidationError, prefix: str = "", model: Any = None) -> str:
    """One line naming every field a pydantic model refused, the value given and what is
    allowed: ``driver.options.fps = -15: Input should be greater than 0``. ``prefix`` is the
    section the model sits in (``driver.options``), if any; ``model``, the model's class, lets
    a misspelt field be answered with the nearest real one."""
    return "; ".join(describe_error(e, prefix, model) for e in exc.errors(include_url=False))


def serve_hint(exc: BaseException, host_flag: str, port_flag: str) -> str:
    """What to change when a server cannot bind: the host flag for a name that does not
    resolve or an address that is not this machine's, else the port flag."""
    if isinstance(exc, socket.gaierror) or getattr(exc, "errno", None) == errno.EADDRNOTAVAIL:
        return f"check {host_flag}: a name or address of this machine"
    return f"pick another with {port_flag}, or {port_flag} 0 for any free one"


def one_line(text: str) -> str:
    """``text`` with every character that is not printable (a newline, NUL) escaped, so that
    a message quoting a file's content stays one line."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def describe_error(e: Any, prefix: str = "", model: Any = None) -> str:
    """One of a ValidationError's ``errors()`` as ``field = value: what is wrong``; an unknown
    field of ``model`` (a pydantic model class) close to a real one names it."""
    loc = ".".join(str(p) for p in (prefix.split(".") if prefix else []) + list(e["loc"]))
    loc = one_line(loc or "(top level)")
    msg = one_line(str(e["msg"]).removeprefix("Value error, "))
    if e["type"] == "json_invalid":
        return f"not valid JSON ({msg.removeprefix('Invalid JSON: ')})"
    if e["type"] == "extra_forbidden":
        near = nearest_field(model, e["loc"]) if model is not None else None
        hint = f"did you mean {near}?" if near else "check its spelling"
        return f"{loc}: unknown field ({hint})"
    if e["type"] == "missing":
        return f"{loc}: required field is missing"
    if e["type"] == "string_pattern_mismatch":
        msg = _PATTERNS.get(str(e.get("ctx", {}).get("pattern")), msg)
    elif e["type"] == "too_short" and "min_length" in e.get("ctx", {}):
        n = e["ctx"]["min_length"]
        msg = f"needs at least {n} item{'s' if n != 1 else ''}"
    if "input" in e and not isinstance(e["input"], dict | list):
        return f"{loc} = {_shown(e['input'])}: {msg}"
    return f"{loc}: {msg}"


_PATTERNS = {
    r"^[A-Za-z0-9_\-]+$": "use ASCII letters, digits, '_' and '-' only (one Zenoh key chunk)",
    r"^[A-Za-z0-9_\-]+(/[A-Za-z0-9_\-]+)*$": (
        "use ASCII letters, digits, '_' and '-', in parts split by '/' (no wildcards)"
    ),
    r"^/?([A-Za-z][A-Za-z0-9_]*(/[A-Za-z][A-Za-z0-9_]*)*)?/?$": (
        "a ROS name: ASCII letters, digits and '_', parts split by '/', each starting with a letter"
    ),
}
"""What each name pattern of the configuration and room files means, said instead of the
regular expression (the patterns of ``stereod.bus.keys`` and the ROS 2 namespace)."""


def nearest_field(model: Any, loc: Sequence[int | str]) -> str | None:
    """The field of the pydantic ``model`` class (followed through its nested models along
    ``loc``, a list's items included) whose name is nearest the last part of ``loc``, if one
    is near enough to be a misspelling of it: the same letters in another order (``fsp`` for
    ``fps``), or a difflib ratio of 0.75 (``treshold`` for ``threshold``)."""
    for part in loc[:-1]:
        if isinstance(part, int):  # an item of a list: the list's model goes on
            continue
        field = getattr(model, "model_fields", {}).get(str(part))
        model = _model_in(getattr(field, "annotation", None))
        if model is None:
            return None
    names = list(getattr(model, "model_fields", {}))
    if not loc:
        return None
    typo = str(loc[-1])
    swapped = [n for n in names if sorted(n) == sorted(typo)]
    found = swapped or difflib.get_close_matches(typo, names, n=1, cutoff=0.75)
    return found[0] if found else None


def _model_in(annotation: Any) -> Any:
    """The pydantic model an annotation holds: itself, or the one model among its arguments
    (``list[Rig]``, ``Rig | None``), else None."""
    if hasattr(annotation, "model_fields"):
        return annotation
    found = [m for m in (_model_in(a) for a in typing.get_args(annotation)) if m is not None]
    return found[0] if len(found) == 1 else None


def _shown(value: object, limit: int = 60) -> str:
    text = one_line(repr(value))
    return text if len(text) <= limit else text[: limit - 3] + "..."


class Interrupted(StereodError):
    """A run stopped by a signal (Ctrl-C, SIGTERM) before its end; its outputs were not
    replaced. The exit code is 128 plus the signal's number (130 for SIGINT, 143 for SIGTERM),
    what a shell reports for a process the signal ended."""

    def __init__(self, message: str, signum: int) -> None:
        super().__init__(message)
        self.signum = signum
        self.exit_code = 128 + signum
