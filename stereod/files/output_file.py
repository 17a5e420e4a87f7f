"""Output files: one rule for every file a command writes (``--jsonl``, ``--mcap``, a
calibration), so that writing an output never destroys what was at its path.

* A symbolic link is written through: the file it points to is the output (a dangling link's
  file is created) and the link stays a link.
* A regular file there, or nothing, is written to a temporary file beside it
  (``.<name>.<random>.part``) and renamed over it only when the run commits it, so a run that
  fails or is interrupted leaves an existing file untouched and no partial file behind.
* A character device or a FIFO (``/dev/null`` to discard, ``/dev/full``, a named pipe with a
  reader) is written in place, as a shell's ``>`` would, and so is a path that names one of
  a process's file descriptors (``/dev/stdout``, ``/proc/self/fd/N``): such a file is never
  replaced by a regular one nor removed. Opening a FIFO waits for its reader, as ``>`` does.
* A regular file that this process may not write (write-protected) is refused, as a shell's
  ``>`` would refuse it, although renaming over it would succeed.
* Anything else there (a directory, a block device, a socket) is refused in one line.

An output that is one of the files the command reads (its config, calibration, the driver's
videos, timestamp CSVs and recording folder, a plot's run and truth) is refused before anything
is written, symbolic and hard links seen through (:func:`check_outputs`, exit 64). A run that a
signal stopped before its end commits no output; it ends with :class:`Interrupted`.

An output written in place is written only when it can take the bytes without blocking (a
pipe whose reader stops reading would otherwise hold its writer, and the thread that waits for
it, for good): once a stop is asked for, :func:`give_up_writing` bounds that wait, and a
reader still not reading then counts as gone (:class:`ReaderGone`).
"""

from __future__ import annotations

import contextlib
import errno
import io
import os
import select
import signal
import stat
import tempfile
import time
import weakref
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from types import TracebackType
from typing import IO, Any

from stereod.errors import (
    Interrupted,
    MissingInputError,
    OutputError,
    ReaderGone,
    StdoutWriteError,
    UsageError,
)
from stereod.files.paths import file_kind, shown
from stereod.files.stop import check_stop, clear_stop, pending_stop, raise_stop

__all__ = [
    "AtomicOutput",
    "Interrupted",
    "ReaderGone",
    "check_outputs",
    "follow_links",
    "is_stdout",
    "output_target",
    "signal_name",
    "stopped_by_signals",
    "written_in_place",
]

_MAX_LINKS = 40
"""Symbolic links followed before a path is taken for a loop (the kernel's limit)."""


def signal_name(signum: int) -> str:
    """``SIGINT`` for 2: how messages name a signal."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _in_proc(path: Path) -> bool:
    """Whether ``path`` lies in /proc once its folder is resolved: a process's file descriptor
    (``/dev/stdout`` leads to ``/proc/self/fd/1``), whose link text is no path to write."""
    folder = os.path.realpath(path.parent)
    return folder == "/proc" or folder.startswith("/proc/")


def _follow(path: Path) -> tuple[Path, bool]:
    """The file ``path`` leads to, symbolic links followed one at a time, and whether the way
    went through a process's file descriptors (written in place, never resolved)."""
    current = path
    for _ in range(_MAX_LINKS):
        if _in_proc(current):
            return current, True
        try:
            link = os.readlink(current)
        except OSError:  # not a link, or nothing there
            return current, False
        current = current.parent / link  # an absolute link replaces the whole path
    raise OutputError(
        f"{path}: too many levels of symbolic links (a loop?); give the path of a file"
    )


def follow_links(path: Path) -> Path:
    """Where an output named ``path`` goes when it is a symbolic link: the path it leads to
    (``path`` itself when it is no link). A recording directory is written there too."""
    return _follow(path)[0]


def output_target(path: Path) -> tuple[Path, bool]:
    """Where an output named ``path`` is written by the module's rule: the file (symbolic links
    followed) and whether it is written in place (a device, a FIFO, a file descriptor) rather
    than replaced by rename. Raises :class:`OutputError` for what cannot be an output."""
    target, descriptor = _follow(path)
    if descriptor:
        return target, True
    try:
        mode = os.stat(target).st_mode
    except FileNotFoundError:
        folder = target.parent
        if not folder.is_dir():
            raise OutputError(
                f"{path}: cannot create the output file: folder {folder} does not exist; "
                "create it first"
            ) from None
        return target, False
    except OSError as exc:
        raise OutputError(f"{path}: cannot use as an output: {exc.strerror}") from exc
    if stat.S_ISREG(mode):
        if not os.access(target, os.W_OK):
            raise OutputError(
                f"{path}: this user may not write the file (write-protected, or on a "
                "read-only file system); choose another output file"
            )
        return target, False
    if stat.S_ISCHR(mode) or stat.S_ISFIFO(mode):
        return target, True
    if stat.S_ISDIR(mode):
        raise OutputError(f"{path}: is a directory; give the name of a file in it")
    raise OutputError(
        f"{path}: is {file_kind(mode)}, not a file an output can go to; give the path "
        "of a regular file, or /dev/null to discard the output"
    )


def is_stdout(path: Path) -> bool:
    """Whether ``path`` is this process's stdout (``/dev/stdout``, or the file, pipe or
    terminal that stdout is): what else the process prints there would land in the output."""
    try:
        a, b = os.stat(path), os.fstat(1)
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (b.st_dev, b.st_ino)


def written_in_place(path: Path) -> bool:
    """Whether an output at ``path`` is written in place (see :func:`output_target`): what a
    run wrote there stays even when the run fails. False when ``path`` cannot be an output."""
    try:
        return output_target(path)[1]
    except OutputError:
        return False


def same_file(a: Path, b: Path) -> bool:
    """Whether paths ``a`` and ``b`` name one file: the same path once symbolic links are
    resolved (``realpath``: also for a file not made yet), or the same inode on the same
    device (``st_dev``/``st_ino``: a hard link, a bind mount)."""
    try:
        if os.path.realpath(a) == os.path.realpath(b):
            return True
        sa, sb = os.stat(a), os.stat(b)
    except (OSError, ValueError):
        return False
    return (sa.st_dev, sa.st_ino) == (sb.st_dev, sb.st_ino)


def _with_contents(inputs: Iterable[Path | str | None]) -> list[Path]:
    """``inputs`` with each folder's files after it (a recording folder is read whole)."""
    out: list[Path] = []
    for item in inputs:
        if item is None:
            continue
        path = Path(item)
        out.append(path)
        try:
            folder = path.is_dir()
        except OSError:  # cannot even be looked at: its reader says so
            continue
        if folder:
            try:
                out += sorted(path.iterdir())
            except OSError as exc:  # an output could be any of its files: none is checked
                raise MissingInputError(
                    f"{shown(path)}: cannot list the recording: {exc.strerror}"
                ) from exc
    return out


def check_outputs(outputs: Mapping[str, Path | None], inputs: Iterable[Path | str | None]) -> None:
    """The one output rule's check against inputs: refuse (:class:`UsageError`, exit 64)
    before anything is written when an output (``{flag: path}``; None: not given) is one of
    the files the command reads (a folder among ``inputs`` stands for itself and its files),
    or when two outputs are one file. Symbolic links and hard links are seen through."""
    given = [(flag, Path(path)) for flag, path in outputs.items() if path is not None]
    if not given:
        return
    every = _with_contents(inputs)
    for i, (flag, out) in enumerate(given):
        for path in every:
            if same_file(out, path):
                raise UsageError(
                    f"{flag} {shown(out)}: that is an input of this run ({shown(path)}); "
                    "writing it would destroy it: choose another output file"
                )
        for other_flag, other in given[i + 1 :]:
            if same_file(out, other):
                raise UsageError(
                    f"{flag} {shown(out)} and {other_flag} {shown(other)} are the same file; "
                    "give two names"
                )


def _open_in_place(target: Path) -> int:
    """A descriptor writing ``target`` in place. One of this process's own descriptors
    (``/dev/stdout``) is duplicated, so that it shares the position of what else the process
    writes there; any other is opened without truncating or creating anything. A FIFO is
    opened without waiting: one with no reader is refused (waiting for one could not be
    interrupted), then written as any pipe is."""
    if os.path.realpath(target.parent) == f"/proc/{os.getpid()}/fd":
        with contextlib.suppress(ValueError):
            return os.dup(int(target.name))
    flags = os.O_WRONLY | (os.O_APPEND if _in_proc(target) else 0)
    try:
        fd = os.open(target, flags | os.O_NONBLOCK)
    except OSError as exc:
        if exc.errno == errno.ENXIO:
            raise OutputError(
                f"{target}: a named pipe with no reader; start its reader first"
            ) from exc
        raise
    os.set_blocking(fd, True)
    return fd


_CHUNK = select.PIPE_BUF
"""Bytes written at a time in place: a pipe that polls writable takes this many at once."""
_POLL_MS = 200


class _InPlaceWriter(io.RawIOBase):
    """Writes a descriptor written in place without ever blocking in ``write``: each chunk of
    at most ``PIPE_BUF`` bytes waits until the descriptor polls writable, and that wait ends
    with ``ETIMEDOUT`` once :attr:`deadline` (monotonic s) has passed, or once it has lasted
    :attr:`stall_s` (s) where that is set."""

    def __init__(self, fd: int) -> None:
        super().__init__()
        self._fd = fd
        self.deadline: float | None = None
        self.stall_s: float | None = None
        self._poll = select.poll()
        self._poll.register(fd, select.POLLOUT)

    def writable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._fd

    def write(self, b: Any) -> int:
        started = time.monotonic()
        while not self._poll.poll(_POLL_MS):
            now, deadline, stall = time.monotonic(), self.deadline, self.stall_s
            if deadline is not None and now >= deadline:
                raise OSError(errno.ETIMEDOUT, "its reader stopped reading")
            if stall is not None and now - started >= stall:
                self.deadline = now  # given up: what is still buffered is not waited for
                raise OSError(errno.ETIMEDOUT, f"its reader took nothing for {stall:g} s")
        return os.write(self._fd, memoryview(b)[:_CHUNK])

    def close(self) -> None:
        if not self.closed:
            with contextlib.suppress(OSError):
                os.close(self._fd)
        super().close()


_IN_PLACE: weakref.WeakSet[_InPlaceWriter] = weakref.WeakSet()


def give_up_writing(after_s: float) -> None:
    """Let every output written in place wait at most ``after_s`` more seconds for its reader
    (a stop was asked for: what is queued still goes out to a reader that reads). Safe to call
    from a signal handler."""
    deadline = time.monotonic() + after_s
    for w in list(_IN_PLACE):
        if w.deadline is None or w.deadline > deadline:
            w.deadline = deadline


def _fsync_dir(directory: Path) -> None:
    """Make a rename in ``directory`` durable (best effort: some file systems refuse)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


_WRITE_HINTS = {
    errno.ENOSPC: "; free space on its file system, or write it elsewhere",
    errno.EDQUOT: "; your disk quota is used up: free some, or write it elsewhere",
    errno.EFBIG: "; too large for its file system: write it elsewhere",
}
"""What to do when a write fails, by errno (nothing added for the others)."""


def write_failed(exc: OSError) -> str:
    """``writing failed: REASON``, and what to do where the reason says (a full disk)."""
    return f"writing failed: {exc.strerror}{_WRITE_HINTS.get(exc.errno or 0, '')}"


class AtomicOutput:
    """A binary output file written by the module's rule; use as a context manager or call
    :meth:`commit` / :meth:`discard`. Write errors become :class:`OutputError` (exit 73).
    :meth:`tell` counts the bytes written, so a writer that records positions (MCAP) can
    write into a FIFO too."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.target, self.in_place = output_target(path)
        self._tmp: Path | None = None
        self._written = 0
        self.stdout = self.in_place and is_stdout(self.target)
        """Whether the output is this process's stdout."""
        try:
            if self.in_place:
                raw = _InPlaceWriter(_open_in_place(self.target))
                _IN_PLACE.add(raw)
                self._fh: IO[bytes] = io.BufferedWriter(raw)
            else:
                fd, tmp = tempfile.mkstemp(
                    prefix=f".{self.target.name}.", suffix=".part", dir=self.target.parent
                )
                self._tmp = Path(tmp)
                self._fh = os.fdopen(fd, "wb")
                os.fchmod(fd, self._mode())
        except OSError as exc:
            self.discard()
            raise OutputError(f"{path}: cannot create the output file: {exc.strerror}") from exc
        except BaseException:  # a signal's exception while it was made: leave nothing behind
            self.discard()
            raise

    def _mode(self) -> int:
        """The permissions of the file replaced, or those of a new file."""
        try:
            return stat.S_IMODE(os.stat(self.target).st_mode)
        except OSError:
            return 0o666 & ~_umask()

    def _failed(self, exc: OSError) -> OutputError:
        """The error a failed write becomes: :class:`ReaderGone` when the reader of a pipe
        written in place closed it, otherwise :class:`OutputError`."""
        if self.in_place and exc.errno == errno.EPIPE:
            return ReaderGone(f"{self.path}: its reader closed it", stdout=self.stdout)
        if self.in_place and exc.errno == errno.ETIMEDOUT:
            return ReaderGone(f"{self.path}: {exc.strerror}", stdout=self.stdout)
        if self.stdout:  # as any command's standard output that fails: 74
            return StdoutWriteError(f"cannot write to standard output: {exc.strerror}")
        return OutputError(f"{self.path}: {write_failed(exc)}")

    def limit_stall(self, seconds: float) -> None:
        """Let a write into a pipe (an output written in place) wait at most ``seconds`` for
        its reader to take data, then fail as :class:`ReaderGone`: a live daemon cannot be
        held by a reader that stays open and stops reading. Nothing changes for a file."""
        raw = getattr(self._fh, "raw", None)
        if isinstance(raw, _InPlaceWriter):
            raw.stall_s = seconds

    def write(self, data: bytes) -> int:
        """Write ``data``; the number of bytes written."""
        if self._fh.closed:
            raise OutputError(f"{self.path}: already closed")
        try:
            n = self._fh.write(data)
        except OSError as exc:
            raise self._failed(exc) from exc
        self._written += n
        return n

    def tell(self) -> int:
        """Bytes written so far."""
        return self._written

    def flush(self) -> None:
        """Hand what is buffered to the operating system."""
        try:
            self._fh.flush()
        except OSError as exc:
            raise self._failed(exc) from exc

    def commit(self) -> None:
        """Flush, close and move the file into place (once; later calls do nothing)."""
        if self._fh.closed:
            return
        stop = pending_stop()  # a stop whose exception was swallowed on its way: keep the old file
        if stop is not None:
            self.discard()
            raise stop
        try:
            self._fh.flush()
            if self._tmp is not None:
                os.fsync(self._fh.fileno())
            self._fh.close()
            if self._tmp is not None:
                os.replace(self._tmp, self.target)
                self._tmp = None
                _fsync_dir(self.target.parent)
        except OSError as exc:
            self.discard()
            raise self._failed(exc) from exc

    def discard(self) -> None:
        """Close and remove the temporary file; the target stays as it was."""
        fh = getattr(self, "_fh", None)
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()
        if self._tmp is not None:
            with contextlib.suppress(OSError):
                self._tmp.unlink()
            self._tmp = None

    def __enter__(self) -> AtomicOutput:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()


@contextlib.contextmanager
def stopped_by_signals(command: str, out: Path) -> Iterator[None]:
    """Within: Ctrl-C and SIGTERM raise :class:`Interrupted` where ``command`` is, so that the
    output it is writing to ``out`` removes its temporary file (SIGTERM would otherwise end
    the process and leave it behind) and ``out`` stays as it was. Once the new file is in
    place the command is done: a signal then lets it finish and say so."""
    in_place = written_in_place(out)
    text = "" if in_place else f"; {out} left as it was"
    target = follow_links(out)

    def identity() -> tuple[int, int] | None:
        try:
            st = os.stat(target)
        except OSError:
            return None
        return st.st_ino, st.st_mtime_ns

    before = identity()

    def on_signal(signum: int, _frame: Any) -> None:
        if not in_place and identity() != before:
            return
        raise_stop(f"{command} interrupted by {signal_name(signum)}{text}", signum)

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
        check_stop()  # a signal whose exception library code swallowed still stops the command
    finally:
        clear_stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
