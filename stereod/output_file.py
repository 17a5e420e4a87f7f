"""Output files that never destroy what was there before a run failed.

A regular output file is written to a temporary file beside it and renamed over the target
only when the run commits it, so a run that fails (bad input, a full disk) leaves an existing
file untouched and no partial file behind. A target that exists and is not a regular file
(``/dev/stdout``, a FIFO, ``/dev/full``) is written in place, since renaming over it would
replace the device. An output that is one of the run's inputs is refused.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from types import TracebackType
from typing import IO

from .errors import OutputError


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_not_input(output: Path, inputs: list[Path], flag: str) -> None:
    """Refuse an output path that is one of the inputs (it would destroy it)."""
    for path in inputs:
        with contextlib.suppress(OSError):
            if output.exists() and os.path.samefile(output, path):
                raise OutputError(
                    f"{flag} {output}: that is an input of this run ({path}); "
                    "choose another output file"
                )


class AtomicOutput:
    """A binary output file committed by rename; use as a context manager or call
    :meth:`commit` / :meth:`discard`. Write errors become :class:`OutputError` (exit 73)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._tmp: Path | None = None
        in_place = path.exists() and not path.is_file()
        try:
            if in_place:
                self._fh: IO[bytes] = path.open("wb")
            else:
                fd, tmp = tempfile.mkstemp(
                    prefix=f".{path.name}.", suffix=".part", dir=path.parent or Path(".")
                )
                self._tmp = Path(tmp)
                os.fchmod(fd, 0o666 & ~_umask())
                self._fh = os.fdopen(fd, "wb")
        except OSError as exc:
            raise OutputError(f"{path}: cannot create the output file: {exc.strerror}") from exc

    def write(self, data: bytes) -> None:
        if self._fh.closed:
            raise OutputError(f"{self.path}: already closed")
        try:
            self._fh.write(data)
        except OSError as exc:
            raise OutputError(f"{self.path}: writing failed: {exc.strerror}") from exc

    def commit(self) -> None:
        """Flush, close and move the file into place (once; later calls do nothing)."""
        if self._fh.closed:
            return
        try:
            self._fh.flush()
            if self._tmp is not None:
                os.fsync(self._fh.fileno())
            self._fh.close()
            if self._tmp is not None:
                os.replace(self._tmp, self.path)
                self._tmp = None
        except OSError as exc:
            self.discard()
            raise OutputError(f"{self.path}: writing failed: {exc.strerror}") from exc

    def discard(self) -> None:
        """Close and remove the temporary file; the target stays as it was."""
        with contextlib.suppress(OSError):
            self._fh.close()
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
