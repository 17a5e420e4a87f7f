"""The one exception hierarchy of stereod.

::

    StereodError                  anything stereod reports to a user (one line, names the thing)
    ├── ConfigError               a configuration file, field or flag is invalid (exit 78)
    ├── InputError                an input file or stream is missing, unreadable or inconsistent
    │   └── TruncatedInputError   a video ended before its header said it would
    ├── CalibrationError          a calibration file is missing, ill-shaped or does not fit
    └── DeviceError               a camera device failed (open, ioctl)
        └── DeviceLost            a camera went away while in use (the source retries)

Foreign errors (OSError, cv2.error, pydantic.ValidationError) are translated into these at the
boundary with ``raise ... from exc`` so callers only ever catch ``StereodError``.
"""

from __future__ import annotations

EX_DATAERR = 65
"""Exit code for bad input data (sysexits.h EX_DATAERR)."""
EX_NOINPUT = 66
"""Exit code for a missing or unreadable input file (sysexits.h EX_NOINPUT)."""
EX_UNAVAILABLE = 69
"""Exit code for a device or service that cannot be reached (sysexits.h EX_UNAVAILABLE)."""
EX_CANTCREAT = 73
"""Exit code for an output that cannot be created (sysexits.h EX_CANTCREAT)."""
EX_CONFIG = 78
"""Exit code for bad configuration (sysexits.h EX_CONFIG); systemd does not restart on it."""


class StereodError(Exception):
    """Base of every error stereod reports; ``str()`` is one line meant for a user."""

    exit_code: int = 1


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


class CalibrationError(StereodError):
    """A calibration is missing, ill-shaped, non-finite or does not fit the stream."""

    exit_code = EX_CONFIG


class DeviceError(StereodError):
    """A camera device failed to open, configure or stream."""

    exit_code = EX_UNAVAILABLE


class DeviceLost(DeviceError):
    """A camera went away while in use (unplugged, reset); its source retries by itself, the
    daemon reports the eye down and keeps running."""
