"""The one place every V4L2 system call goes through: open, close, ioctl, mmap, select.

:class:`SystemIO` is the real kernel; tests substitute an object with the same five methods.
Every ioctl is logged at DEBUG with its name; EINTR is retried; other errors are raised as
``OSError`` with the errno, for the device layer to translate.
"""

from __future__ import annotations

import ctypes
import errno
import fcntl
import logging
import mmap
import os
import select
from typing import Any, Protocol

from . import raw

log = logging.getLogger(__name__)

_NAMES = {v: k for k, v in raw.REQUESTS.items()}


class IO(Protocol):
    """The system calls a device needs."""

    def open(self, path: str) -> int: ...
    def close(self, fd: int) -> None: ...
    def ioctl(self, fd: int, request: int, arg: Any) -> None: ...
    def mmap(self, fd: int, length: int, offset: int) -> Any: ...
    def wait_readable(self, fd: int, timeout_s: float) -> bool: ...


class SystemIO:
    """The real kernel."""

    def open(self, path: str) -> int:
        return os.open(path, os.O_RDWR | os.O_NONBLOCK | os.O_CLOEXEC)

    def close(self, fd: int) -> None:
        os.close(fd)

    def ioctl(self, fd: int, request: int, arg: Any) -> None:
        while True:
            try:
                fcntl.ioctl(fd, request, arg)
                return
            except InterruptedError:
                continue

    def mmap(self, fd: int, length: int, offset: int) -> Any:
        return mmap.mmap(
            fd, length, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE, offset=offset
        )

    def wait_readable(self, fd: int, timeout_s: float) -> bool:
        readable, _, errs = select.select([fd], [], [fd], timeout_s)
        return bool(readable or errs)


def xioctl(io: IO, fd: int, request: int, arg: ctypes.Structure | ctypes.c_int) -> None:
    """One ioctl through ``io``, logged at DEBUG by name."""
    name = _NAMES.get(request, hex(request))
    try:
        io.ioctl(fd, request, arg)
    except OSError as exc:
        log.debug("%s on fd %d: %s", name, fd, errno.errorcode.get(exc.errno or 0, exc.errno))
        raise
    log.debug("%s on fd %d", name, fd)
